"""Small validators shared by the dataclasses: shapes, finiteness, definiteness.

Each raises :class:`~amcp_drake.model.errors.ProblemError` naming the field, in the style of
python-control ("matrix A has the wrong number of rows; expected 3 instead of 2").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amcp_drake.model.errors import ProblemError


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def as_matrix(field: str, value: Any, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """Return ``value`` as a finite float64 2-D array with the given shape (None: any)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ProblemError(field, "a matrix of real numbers", _describe(value)) from None
    if arr.ndim == 1 and cols == 1:
        arr = arr.reshape(-1, 1)
    if arr.ndim == 0 and rows in (None, 1) and cols in (None, 1):
        arr = arr.reshape(1, 1)
    if arr.ndim != 2:
        raise ProblemError(field, "a 2-D matrix", f"an array with {arr.ndim} dimension(s)")
    if rows is not None and arr.shape[0] != rows:
        raise ProblemError(field, f"{rows} rows", f"{arr.shape[0]} rows (shape {arr.shape})")
    if cols is not None and arr.shape[1] != cols:
        raise ProblemError(field, f"{cols} columns", f"{arr.shape[1]} columns (shape {arr.shape})")
    if arr.size == 0 and (rows is None or rows > 0):
        raise ProblemError(field, "a non-empty matrix", f"shape {arr.shape}")
    require_finite(field, arr)
    return arr


def as_vector(field: str, value: Any, size: int | None = None) -> np.ndarray:
    """Return ``value`` as a finite float64 1-D array of the given length (None: any)."""
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ProblemError(field, "a vector of real numbers", _describe(value)) from None
    if arr.ndim == 0:
        arr = arr.reshape(1)
    if arr.ndim == 2 and 1 in arr.shape:
        arr = arr.reshape(-1)
    if arr.ndim != 1:
        raise ProblemError(field, "a vector", f"an array of shape {arr.shape}")
    if size is not None and arr.shape[0] != size:
        raise ProblemError(field, f"a vector of length {size}", f"length {arr.shape[0]}")
    require_finite(field, arr)
    return arr


def require_finite(field: str, arr: np.ndarray) -> None:
    """Reject NaN and infinity (Drake aborts with SystemExit on non-finite coefficients)."""
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ProblemError(field, "finite entries", f"{arr[tuple(bad)]} at index {tuple(int(i) for i in bad)}")


def require_positive_definite(field: str, arr: np.ndarray, strict: bool = True) -> None:
    """Require a symmetric positive (semi)definite matrix."""
    if arr.shape[0] != arr.shape[1]:
        raise ProblemError(field, "a square matrix", f"shape {arr.shape}")
    asym = float(np.max(np.abs(arr - arr.T))) if arr.size else 0.0
    if asym > 1e-9 * max(1.0, float(np.max(np.abs(arr)))):
        raise ProblemError(field, "a symmetric matrix", f"asymmetry {asym:.3g}")
    eig_min = float(np.min(np.linalg.eigvalsh(0.5 * (arr + arr.T))))
    if strict and eig_min <= 0.0:
        raise ProblemError(field, "a positive definite matrix", f"smallest eigenvalue {eig_min:.3g}")


def as_positive_int(field: str, value: Any, minimum: int = 1) -> int:
    """Return ``value`` as an int >= minimum (bools are rejected)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ProblemError(field, f"an integer >= {minimum}", _describe(value))
    if int(value) < minimum:
        raise ProblemError(field, f"an integer >= {minimum}", str(int(value)))
    return int(value)
