"""Small numpy/scipy geometry helpers for the claim checks (no optimisation backend).

Maxima of linear functions over a polytope are taken at its vertices (Qhull via
:func:`amcp_drake.model.polytope.vertices`); when the polytope has (numerically) empty interior, which
happens when Θ_k collapses onto θ* under vertex disturbances, vertex enumeration is impossible
and the maxima are computed by one HiGHS LP per direction instead.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection, QhullError

from amcp_drake.model import polytope

#: Below this Chebyshev radius Qhull cannot enumerate vertices reliably; use LPs instead.
MIN_RADIUS_FOR_VERTICES = 1e-7


class PolytopeMaxima:
    """max_{θ ∈ {H θ <= h}} c·θ for many directions c, by vertices or by LPs (see module doc).

    ``empty`` is True when the set is empty (then every maximum is -inf); ``method`` says how
    maxima are computed ("vertices", "LP" or "empty"). Build with :func:`maxima` (cached).
    """

    def __init__(self, H: np.ndarray, h: np.ndarray) -> None:
        self.H = np.asarray(H, float)
        self.h = np.asarray(h, float)
        self.vertices = _vertices_1d(self.H, self.h) if self.H.shape[1] == 1 else _vertices_nd(self.H, self.h)
        # emptiness is decided by HiGHS itself (a Chebyshev radius of -1e-8 is within its
        # feasibility tolerance and does not mean that the set is empty)
        self.empty = self.vertices is None and self._lp(np.zeros(self.H.shape[1])).status == 2
        self.method = "empty" if self.empty else ("vertices" if self.vertices is not None else "LP")

    def _lp(self, c: np.ndarray):
        return linprog(-c, A_ub=self.H, b_ub=self.h, bounds=[(None, None)] * len(c), method="highs")

    def max(self, directions: np.ndarray) -> np.ndarray:
        """Maxima for each row of ``directions`` (shape (k, p)) -> (k,)."""
        C = np.atleast_2d(np.asarray(directions, float))
        if self.empty:
            return np.full(len(C), -np.inf)
        if self.vertices is not None:
            return np.max(C @ self.vertices.T, axis=1)
        out = np.empty(len(C))
        for i, c in enumerate(C):
            res = self._lp(c)
            out[i] = -res.fun if res.status == 0 else (np.inf if res.status == 3 else np.nan)
        return out


def _vertices_1d(H: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    """Endpoints of an interval {a θ <= b}, in closed form; None when empty or unbounded."""
    a = H[:, 0]
    upper = np.min(h[a > 0] / a[a > 0]) if np.any(a > 0) else np.inf
    lower = np.max(h[a < 0] / a[a < 0]) if np.any(a < 0) else -np.inf
    if np.any((a == 0) & (h < 0)) or not (np.isfinite(lower) and np.isfinite(upper)) or lower > upper:
        return None
    return np.array([[lower], [upper]])


def _vertices_nd(H: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    """Vertices by Qhull from the Chebyshev centre; None when the radius is too small for Qhull."""
    center, radius = polytope.chebyshev_center(H, h)
    if not (np.isfinite(radius) and radius > MIN_RADIUS_FOR_VERTICES):
        return None
    try:
        pts = HalfspaceIntersection(np.hstack([H, -h[:, None]]), center).intersections
    except (ValueError, RuntimeError, QhullError):
        return None
    return np.unique(np.round(pts, 12), axis=0)


_CACHE: OrderedDict[bytes, PolytopeMaxima] = OrderedDict()
#: PolytopeMaxima kept (the same Θ_k is examined by several claims and often for many steps).
CACHE_SIZE = 4096


def maxima(H: np.ndarray, h: np.ndarray) -> PolytopeMaxima:
    """A cached :class:`PolytopeMaxima` for {H θ <= h}."""
    H = np.ascontiguousarray(H, float)
    h = np.ascontiguousarray(h, float)
    key = H.shape[1].to_bytes(2, "little") + H.tobytes() + b"|" + h.tobytes()
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    value = _CACHE[key] = PolytopeMaxima(H, h)
    if len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)
    return value


def vertices(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Vertices of a full-dimensional bounded polytope (cached); ValueError otherwise."""
    result = maxima(H, h)
    if result.vertices is None:
        raise ValueError("vertex enumeration needs a bounded polytope with interior")
    return result.vertices


def signed_chebyshev_radius(H: np.ndarray, h: np.ndarray) -> float:
    """Radius of the largest ball in {H θ <= h} with unit-norm rows; negative when the set is
    empty: then −radius is the distance by which the rows miss a common point (not clamped)."""
    Hn, hn = polytope.normalize_rows(H, h)
    p = Hn.shape[1]
    cost = np.zeros(p + 1)
    cost[-1] = -1.0
    res = linprog(cost, A_ub=np.hstack([Hn, np.ones((len(hn), 1))]), b_ub=hn, bounds=[(None, None)] * (p + 1),
                  method="highs")
    return float(res.x[-1]) if res.status == 0 else (np.inf if res.status == 3 else np.nan)


def regressor(problem, x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """D(x, u) = [A_1 x + B_1 u, ..., A_p x + B_p u] (n, p), written out from its definition (§2)."""
    return np.stack([Ai @ x + Bi @ u for Ai, Bi in zip(problem.A, problem.B)], axis=1)


def delta_set(problem, x: np.ndarray, u: np.ndarray, x_next: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Δ of (6) for the transition (x, u) -> x_next, from its definition
    {θ | H_w (x_next − A(θ) x − B(θ) u) <= 1}: rows −H_w D(x,u) θ <= 1 − H_w (x_next − A0 x − B0 u)."""
    D = regressor(problem, x, u)
    residual = x_next - problem.A0 @ x - problem.B0 @ u
    return -problem.H_w @ D, 1.0 - problem.H_w @ residual


def unit_rows(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows scaled to unit norm, so that margins are Euclidean distances."""
    return polytope.normalize_rows(H, h)
