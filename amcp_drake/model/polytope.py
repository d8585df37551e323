"""Polytope helpers in half-space form {x | H x <= h}, with numpy and scipy only.

These helpers are deliberately independent of both optimisation backends: the
certificates (design.md, "Certificates are independent of the solver") re-check claims
with them, so they must not use Drake or cvxpy. LPs are solved with scipy's HiGHS,
vertices are enumerated with Qhull (scipy.spatial.HalfspaceIntersection).

Decision: Drake's ``HPolyhedron``/``VPolytope`` are not used here, because Drake aborts
the interpreter (``SystemExit``) on unbounded or non-finite input and because the
certificate path must not trust the backend that produced a run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection

#: Feasibility tolerance of membership tests (HiGHS' default primal feasibility is 1e-7).
MEMBERSHIP_TOL = 1e-7
#: Redundancy: a row is kept when the other rows allow exceeding it by more than this.
REDUNDANCY_TOL = 1e-9
#: A Chebyshev radius below -this means the set is empty (HiGHS feasibility is ~1e-7; a flat but
#: non-empty set gives a radius of 0 up to round-off).
EMPTY_RADIUS_TOL = 1e-9


@dataclass(frozen=True)
class LPResult:
    """Outcome of a support-function LP: ``value`` is +inf when unbounded, nan when infeasible."""

    value: float
    point: np.ndarray | None
    status: str  # "optimal" | "unbounded" | "infeasible" | "error"


def _linprog_max(direction: np.ndarray, H: np.ndarray, h: np.ndarray, options: dict | None = None) -> LPResult:
    res = linprog(-direction, A_ub=H, b_ub=h, bounds=[(None, None)] * H.shape[1], method="highs", options=options)
    if res.status == 0:
        return LPResult(float(-res.fun), np.asarray(res.x, dtype=float), "optimal")
    if res.status == 3:
        return LPResult(float("inf"), None, "unbounded")
    if res.status == 2:
        return LPResult(float("nan"), None, "infeasible")
    return LPResult(float("nan"), None, "error")


def support(H: np.ndarray, h: np.ndarray, direction: np.ndarray, *, certified: bool = False) -> LPResult:
    """Support function max{direction·x | H x <= h} by LP (HiGHS); ``certified``: at
    :data:`HIGHS_CERTIFIED_OPTIONS` (exact to ~1e-12 where the defaults can be 1e-7 off)."""
    options = HIGHS_CERTIFIED_OPTIONS if certified else None
    return _linprog_max(np.asarray(direction, float), np.asarray(H, float), np.asarray(h, float), options)


def normalize_rows(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Scale each row to unit Euclidean norm (rows of zero norm are left unchanged)."""
    H = np.asarray(H, float)
    h = np.asarray(h, float)
    norms = np.linalg.norm(H, axis=1)
    norms = np.where(norms > 0, norms, 1.0)
    return H / norms[:, None], h / norms


def is_bounded(H: np.ndarray, h: np.ndarray) -> bool:
    """True when {H x <= h} is bounded (checked by 2n support LPs along ±e_i).

    An infeasible set counts as bounded (it is empty); call :func:`chebyshev_center`
    to test non-emptiness.
    """
    n = np.asarray(H).shape[1]
    for i in range(n):
        for sign in (1.0, -1.0):
            e = np.zeros(n)
            e[i] = sign
            if support(H, h, e).status == "unbounded":
                return False
    return True


def chebyshev_center(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre and radius of the largest ball inside {H x <= h}.

    Returns radius ``-inf`` when the set is empty and ``+inf`` when the ball is unbounded.
    """
    H = np.asarray(H, float)
    h = np.asarray(h, float)
    n = H.shape[1]
    norms = np.linalg.norm(H, axis=1)
    c = np.zeros(n + 1)
    c[-1] = -1.0
    A = np.hstack([H, norms[:, None]])
    res = linprog(c, A_ub=A, b_ub=h, bounds=[(None, None)] * n + [(None, None)], method="highs")
    scale = 1.0
    if res.status not in (0, 2, 3):
        # HiGHS gave no answer (status 4, numerical difficulties: seen on sets of size 1e-5 written in
        # rows of size 1e4-1e5 next to a column of size 1): the same LP with unit rows, in
        # y = x / scale with scale the largest offset of the unit rows, has coefficients of order 1
        nz = np.where(norms > 0, norms, 1.0)
        scale = float(np.max(np.abs(h / nz))) or 1.0
        res = linprog(c, A_ub=np.hstack([H / nz[:, None], (norms / nz)[:, None]]), b_ub=h / nz / scale,
                      bounds=[(None, None)] * (n + 1), method="highs")
    if res.status == 2:
        return np.full(n, np.nan), float("-inf")
    if res.status == 3:
        return np.full(n, np.nan), float("inf")
    if res.status != 0:
        return np.full(n, np.nan), float("nan")
    res_x = np.asarray(res.x) * scale
    radius = float(res_x[-1])
    if radius < -EMPTY_RADIUS_TOL:  # the radius is a free variable: negative means no point fits
        return np.full(n, np.nan), float("-inf")
    return res_x[:n], max(radius, 0.0)


def contains(H: np.ndarray, h: np.ndarray, x: np.ndarray, tol: float = MEMBERSHIP_TOL) -> bool:
    """True when H x <= h + tol holds row-wise."""
    return bool(np.all(np.asarray(H) @ np.asarray(x) <= np.asarray(h) + tol))


def max_violation(H: np.ndarray, h: np.ndarray, x: np.ndarray) -> float:
    """max_i (H x - h)_i: negative inside, positive outside (the margin of membership)."""
    return float(np.max(np.asarray(H) @ np.asarray(x) - np.asarray(h)))


def vertices(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Vertices of the bounded, full-dimensional polytope {H x <= h}, shape (v, n).

    Raises ValueError when the set is empty, unbounded or has empty interior.
    """
    H = np.asarray(H, float)
    h = np.asarray(h, float)
    n = H.shape[1]
    center, radius = chebyshev_center(H, h)
    if not np.isfinite(radius) or radius <= 1e-12:
        raise ValueError(f"vertex enumeration needs a bounded polytope with interior; Chebyshev radius {radius}")
    if n == 1:
        lo = support(H, h, np.array([-1.0]))
        hi = support(H, h, np.array([1.0]))
        return np.array([[-lo.value], [hi.value]])
    halfspaces = np.hstack([H, -h[:, None]])
    hs = HalfspaceIntersection(halfspaces, center)
    pts = hs.intersections
    return _unique_rows(pts)


#: Seed of the projection direction of :func:`_unique_rows` (any direction gives the same result).
UNIQUE_ROWS_SEED = 0
#: Candidate pairs :func:`_unique_rows` judges at once (bounds its memory).
UNIQUE_ROWS_CHUNK = 2**20


def _unique_rows(points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """The points with near-duplicates dropped (the first of each group kept, in order): p is a
    duplicate of a kept q when max|p − q| <= tol · max(1, max|q|) (Qhull reports a degenerate
    vertex once per facet through it).

    O(N log N) plus the candidate pairs: two points within R = tol · max(1, max|q|) over all q in the
    ∞-norm have projections on a direction v within R ‖v‖₁, so after sorting the projections on one
    direction (random, seeded by :data:`UNIQUE_ROWS_SEED`: distinct vertices of a box or of a grid
    do not share it) only the pairs in that window are candidates. Each candidate is judged by the
    criterion above with the earlier point's scale, in the order of the points, so the result is that
    of comparing every point with every kept point before it."""
    points = np.asarray(points, float)
    count = len(points)
    if count <= 1:
        return points.copy()
    scale = np.maximum(1.0, np.max(np.abs(points), axis=1))
    direction = np.random.default_rng(UNIQUE_ROWS_SEED).uniform(0.5, 1.5, points.shape[1])
    window = tol * float(np.max(scale)) * float(np.sum(direction)) * (1.0 + 1e-9)
    projection = points @ direction
    order = np.argsort(projection, kind="stable")
    sorted_projection = projection[order]
    ends = np.searchsorted(sorted_projection, sorted_projection + window, side="right")
    widths = ends - np.arange(count) - 1  # candidates after each sorted point
    firsts, seconds = [], []
    start = 0
    while start < count:  # chunks of sorted points with at most UNIQUE_ROWS_CHUNK candidate pairs
        stop = start + 1
        total = int(widths[start])
        while stop < count and total + int(widths[stop]) <= UNIQUE_ROWS_CHUNK:
            total += int(widths[stop])
            stop += 1
        rows = np.repeat(np.arange(start, stop), widths[start:stop])
        if len(rows):
            offsets = np.arange(len(rows)) - np.repeat(np.cumsum(widths[start:stop]) - widths[start:stop],
                                                       widths[start:stop])
            a, b = order[rows], order[rows + 1 + offsets]
            first, second = np.minimum(a, b), np.maximum(a, b)
            close = np.max(np.abs(points[first] - points[second]), axis=1) <= tol * scale[first]
            firsts.append(first[close])
            seconds.append(second[close])
        start = stop
    keep = np.ones(count, dtype=bool)
    if firsts:
        first, second = np.concatenate(firsts), np.concatenate(seconds)
        by_later = np.lexsort((first, second))  # by the later point: its earlier neighbours are settled
        for i, j in zip(first[by_later].tolist(), second[by_later].tolist()):
            if keep[i]:
                keep[j] = False
    return points[keep].copy()


def remove_redundant(H: np.ndarray, h: np.ndarray, tol: float = REDUNDANCY_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Drop rows implied by the others (one LP per row); duplicate rows are merged first."""
    H, h = normalize_rows(H, h)
    order = np.lexsort(np.round(np.hstack([H, h[:, None]]), 12).T[::-1])
    H, h = H[order], h[order]
    keep = np.ones(len(h), dtype=bool)
    for i in range(len(h)):
        others = keep.copy()
        others[i] = False
        if not others.any():
            continue
        res = support(H[others], h[others], H[i])
        if res.status == "optimal" and res.value <= h[i] + tol:
            keep[i] = False
    return H[keep], h[keep]


def box(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """H-representation of the box lower <= x <= upper."""
    lower = np.asarray(lower, float)
    upper = np.asarray(upper, float)
    n = lower.size
    return np.vstack([np.eye(n), -np.eye(n)]), np.concatenate([upper, -lower])


def unit_rhs(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Rewrite {H x <= h} with h > 0 as {H' x <= 1}, returning H'."""
    h = np.asarray(h, float)
    if np.any(h <= 0):
        raise ValueError("unit_rhs needs h > 0 (the origin in the interior)")
    return np.asarray(H, float) / h[:, None]


def theta_vertices(H: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    """Vertices of Θ_k = {H θ <= h}, or None when it is empty or unbounded.

    Full-dimensional sets: Qhull. Flat sets (the exact update (7) with disturbances at vertices of
    W can pin θ* between two opposite data rows): the implicit equalities E θ = e are found with
    one HiGHS LP per row, and the vertices are enumerated in the affine hull θ = θ_0 + N y.
    """
    H, h = np.asarray(H, float), np.asarray(h, float)
    try:
        return vertices(H, h)
    except (ValueError, RuntimeError):
        pass
    try:
        return _flat_vertices(H, h)
    except (ValueError, RuntimeError, np.linalg.LinAlgError):
        return None


#: A row of Θ_k whose minimum over Θ_k is within this of its bound is an implicit equality (the set
#: is flat in that direction). Treating a set thinner than this as flat moves its vertices by at most
#: ~this much, far below the tolerances of the claims that use them (>= 1e-7).
FLAT_TOL = 1e-9


def _flat_vertices(H: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    from scipy.linalg import null_space

    _, radius = chebyshev_center(H, h)
    if radius == float("-inf") or radius == float("inf") or radius != radius:
        return None
    Hn, hn = normalize_rows(H, h)
    lows = np.array([support(Hn, hn, -row).value for row in Hn])  # −min_θ [H]_i θ
    if not np.all(np.isfinite(lows)):
        return None
    eq = hn + lows <= FLAT_TOL
    if not np.any(eq):
        return None
    E, e = Hn[eq], hn[eq]
    theta0 = np.linalg.lstsq(E, e, rcond=None)[0]
    basis = null_space(E, rcond=1e-10)                      # (p, r)
    if basis.shape[1] == 0:
        return theta0[None, :]
    H_red, h_red = Hn[~eq] @ basis, hn[~eq] - Hn[~eq] @ theta0
    if len(H_red) == 0:
        return None
    y = vertices(H_red, h_red)                      # (v, r)
    return theta0 + y @ basis.T


def least_distance_point(point: np.ndarray, H: np.ndarray, h: np.ndarray) -> np.ndarray | None:
    """argmin{‖x − point‖ | H x <= h} by least-distance programming (Lawson & Hanson, *Solving Least
    Squares Problems*, ch. 23): with y = (x − point)/s on unit rows, min ‖y‖ s.t. G y >= g is solved
    through the NNLS problem min ‖E u − f‖, u >= 0, E = [Gᵀ; gᵀ], f = e_{n+1} (scipy's active-set
    NNLS, finite and exact on degenerate sets), y = −r_{1:n}/r_{n+1} with r = E u − f. ``None`` when
    the set is empty (r_{n+1} = 0). Used as the second solver of the projection (12) when a
    backend's answer fails its check (amcp_drake.online.answer_checks), never as the first.
    """
    from scipy.optimize import nnls

    point = np.asarray(point, float)
    H, h = normalize_rows(H, h)
    slack = h - H @ point
    violation = float(np.max(-slack)) if len(slack) else 0.0
    if violation <= 0.0:
        return point.copy()
    G, g = -H, -slack / violation
    n = len(point)
    E = np.vstack([G.T, g[None, :]])
    f = np.zeros(n + 1)
    f[-1] = 1.0
    u, _ = nnls(E, f, maxiter=50 * max(E.shape))
    r = E @ u - f
    if abs(r[-1]) <= LDP_EMPTY_TOL:
        return None
    return point + violation * (-r[:n] / r[-1])


#: least_distance_point: |r_{n+1}| below this means the NNLS residual cannot produce a point (empty
#: set); r_{n+1} = −1/(1 + ‖y‖²) otherwise, so this allows ‖y‖ up to ~1e6 violation units.
LDP_EMPTY_TOL = 1e-12


#: HiGHS tolerances of the certified supports (the controller's fallback for LP (9)). At HiGHS'
#: defaults (1e-7) a support of a thin sliver (a moving window of nearly parallel slabs Δ_j, found
#: by the thorough property profile: n = 1, p = 2, window 8, slab normals 1e-4 rad apart) came out
#: 4.4e-5 too large: the basis was optimal to 1e-7 in reduced cost, yet the vertex sat far along the
#: sliver. At 1e-10 the value is exact to 1e-12 (tests/test_polytope_support.py, against rational
#: arithmetic); the LPs are small (p variables), so the cost is nil.
HIGHS_CERTIFIED_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


@dataclass(frozen=True)
class CertifiedSupport:
    """Support values ``values`` (k,), maximisers ``points`` (k, n) and dual multipliers ``duals``
    (k, rows) >= 0 with duals @ H = directions (LP duality: values <= duals @ h)."""

    values: np.ndarray
    points: np.ndarray
    duals: np.ndarray


def support_certified(H: np.ndarray, h: np.ndarray, directions: np.ndarray) -> CertifiedSupport | None:
    """max{d·x | H x <= h} for each row d by HiGHS at :data:`HIGHS_CERTIFIED_OPTIONS`, with maximiser
    and multipliers (the primal and dual certificate of each value); None when any LP is not solved
    to optimality."""
    H = np.asarray(H, float)
    h = np.asarray(h, float)
    directions = np.atleast_2d(np.asarray(directions, float))
    values, points, duals = [], [], []
    for d in directions:
        res = linprog(-d, A_ub=H, b_ub=h, bounds=[(None, None)] * H.shape[1], method="highs",
                      options=HIGHS_CERTIFIED_OPTIONS)
        if res.status != 0:
            return None
        values.append(float(d @ res.x))
        points.append(np.asarray(res.x, float))
        duals.append(-np.asarray(res.ineqlin.marginals, float))
    return CertifiedSupport(np.array(values), np.array(points), np.array(duals))
