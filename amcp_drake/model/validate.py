"""Small validators shared by the dataclasses: shapes, finiteness, definiteness.

Each raises :class:`~amcp_drake.model.errors.ProblemError` naming the field, in the style of
python-control ("matrix A has the wrong number of rows; expected 3 instead of 2").
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amcp_drake.model.errors import ProblemError

#: Largest magnitude accepted for an entry of problem data (matrices, vectors, design K, P, x0, θ*).
#: Beyond it the tube QP's coefficients span more than the ~1e-8 relative accuracy of the interior-point
#: and simplex solvers can resolve, and products such as Q x with |x| ~ 1e3 approach the float range
#: (1e308 in cost.Q overflowed in Drake, in W.H in linprog). Rescale units instead. The same bound is
#: in data/problem.schema.json ($defs/entry); a test keeps them equal. docs/decisions.md, "Strict input files".
MAX_ABS_ENTRY = 1e9


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array of shape {value.shape}"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def reject_booleans(field: str, value: Any, what: str) -> None:
    if isinstance(value, (bool, np.bool_)) or (isinstance(value, np.ndarray) and value.dtype == bool):
        raise ProblemError(field, what + " (booleans are not numbers)", _describe(value))
    if isinstance(value, (list, tuple)):
        try:
            raw = np.asarray(value, dtype=object).ravel()
        except ValueError:  # ragged: reported by the caller
            return
        for index, item in enumerate(raw):
            if isinstance(item, (bool, np.bool_)):
                raise ProblemError(field, what + " (booleans are not numbers)", f"{item!r} at flat index {index}")


def as_matrix(field: str, value: Any, rows: int | None = None, cols: int | None = None) -> np.ndarray:
    """Return ``value`` as a finite float64 2-D array with the given shape (None: any)."""
    reject_booleans(field, value, "a matrix of real numbers")
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
    reject_booleans(field, value, "a vector of real numbers")
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
    """Reject NaN, infinity (Drake aborts with SystemExit on non-finite coefficients) and entries of
    magnitude above :data:`MAX_ABS_ENTRY`. The message names the entry, e.g. ``cost.Q[0][1]``."""
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ProblemError(_entry(field, bad), "finite entries", f"{arr[tuple(bad)]}")
    if arr.size and float(np.max(np.abs(arr))) > MAX_ABS_ENTRY:
        bad = np.argwhere(np.abs(arr) > MAX_ABS_ENTRY)[0]
        raise ProblemError(_entry(field, bad), f"entries of magnitude at most {MAX_ABS_ENTRY:g} (rescale the units)",
                           f"{arr[tuple(bad)]:.6g}")


def _entry(field: str, index: Any) -> str:
    return field + "".join(f"[{int(i)}]" for i in index)


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
