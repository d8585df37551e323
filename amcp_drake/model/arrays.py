"""Small array helpers for the online loop's caches (issue 16)."""

from __future__ import annotations

import numpy as np


def same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """True when two float arrays are identical to the bit (same shape, same bytes).

    The online loop reuses work (vertices of Θ_k, the condensed cost, preassembled check rows) while
    its inputs are unchanged *to the bit*; ``np.array_equal`` costs ~3 µs per call, this ~0.3 µs.
    Stricter than ``==``: −0.0 differs from 0.0 (a reuse is then merely missed, never wrong), and a
    NaN equals itself (non-finite inputs are rejected before any cache is consulted).
    """
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


__all__ = ["same_bits"]
