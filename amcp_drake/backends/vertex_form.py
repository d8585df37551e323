"""The vertex form of the tube constraint (5b), shared by both backends' ``formulation="vertex"``.

By the proof of Proposition 9 (docs/explanation/paper.md §4), (5b) holds if and only if, for every l ∈ ℕ_0^{N−1},
every vertex x^j of X0 and every θ ∈ Θ_k,

    H_x (A_cl(θ)(z_l + α_l x^j) + B(θ) v_l − z_{l+1}) − α_{l+1} 1 <= −w̄.

The left side is affine in θ, so "for every θ ∈ Θ_k" may be checked at the vertices θ^s of Θ_k
(Θ_k is a bounded non-empty polytope, so it is the convex hull of its vertices); (15c)-(15d) are
the LP dual of the same maximum over θ, which is why both describe the same feasible set in
(z, α, v). Row i of the constraint for (l, j, s) is

    [H_x A_cl(θ^s)]_i z_l + α_l [H_x A_cl(θ^s) x^j]_i + [H_x B(θ^s)]_i v_l − [H_x]_i z_{l+1} − α_{l+1} <= −[w̄]_i,

which differs between vertices j of X0 only in the coefficient of α_l. Because α_l >= 0 is a
constraint of (20), the rows of all j are implied by the one with the largest coefficient,

    c^s_i = max_j [H_x A_cl(θ^s) x^j]_i  (= max_{x ∈ X0} [H_x A_cl(θ^s)]_i x),

so the exact vertex form needs N·u·S rows (S vertices of Θ_k) in (z, α, v) and no Λ, instead of
N·v·u·q multipliers, N·v·u·p equalities (15d) and N·v·u rows (15c).

:func:`theta_vertices` enumerates the vertices of Θ_k = {H θ <= h} by basis enumeration (every
choice of p linearly independent rows, solved as a batch of p×p systems, kept when feasible), the
textbook definition of a vertex as a basic feasible solution. Unlike Qhull it needs no interior
point, so it is also exact for flat (lower-dimensional) Θ_k, which the fixed-complexity update
(9) produces when θ* is pinned by vertex disturbances. Above :data:`MAX_COMBINATIONS` choices it
falls back to :func:`amcp_drake.model.polytope.vertices` (Qhull, full-dimensional sets only).
"""

from __future__ import annotations

import itertools
from functools import lru_cache

import numpy as np

from amcp_drake.backends.clarabel_retry import NO_REFINEMENT

#: Largest number of row choices C(q, p) enumerated by basis enumeration (20 for Example 1;
#: 20 000 p×p solves take about 10 ms, beyond that Qhull is faster).
MAX_COMBINATIONS = 20_000
#: A choice of p rows is a basis when |det| of the row-normalised p×p matrix exceeds this
#: (below it the intersection point is determined to worse than ~1e-6 and another basis of the
#: same vertex, or the neighbouring ones, describe the set).
SINGULAR_DET = 1e-10
#: A basic solution is feasible when H θ <= h + FEASIBILITY_TOL·max(1, |h|) row-wise. A point
#: kept although it is outside by up to this makes the tube constraint tighter by the same order
#: (conservative); a vertex is never dropped for round-off of order 1e-15·cond.
FEASIBILITY_TOL = 1e-9
#: Basic solutions closer than this (relative to max(1, |θ|), per coordinate) are one vertex.
DUPLICATE_TOL = 1e-12


#: Clarabel settings of the vertex form in both backends (the user's ``solver_options`` override
#: them): :data:`.clarabel_retry.NO_REFINEMENT` (iterative refinement off; on Example 1, 8-facet X0,
#: 80-step lockstep run, solver time 1.91 -> 1.37 ms (Drake) and 3.84 -> 2.70 ms (cvxpy), v unchanged
#: to 1e-11).
CLARABEL_OPTIONS = NO_REFINEMENT


class VertexEnumerationError(ValueError):
    """Θ_k is empty or its vertices could not be enumerated."""


@lru_cache(maxsize=64)
def combinations(q: int, p: int) -> np.ndarray:
    return np.array(list(itertools.combinations(range(q), p)), dtype=np.intp).reshape(-1, p)


def theta_vertices(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Vertices (S, p) of the bounded polytope Θ_k = {θ | H θ <= h} (H (q, p), h (q,)).

    Raises :class:`VertexEnumerationError` when the set is empty (no basic feasible solution).
    The set must be bounded (Θ_k ⊆ Θ0 is); for an unbounded set the result would describe only
    its vertices, not its recession directions.
    """
    H = np.atleast_2d(np.asarray(H, float))
    h = np.asarray(h, float).reshape(-1)
    q, p = H.shape
    if h.shape != (q,) or not (np.all(np.isfinite(H)) and np.all(np.isfinite(h))):
        raise VertexEnumerationError(f"theta_vertices: H {H.shape} and h {h.shape} must be finite with matching rows")
    norms = np.linalg.norm(H, axis=1)
    keep = norms > 0
    if not np.all(keep):  # a zero row 0 <= h_i: infeasible if h_i < 0, void otherwise
        if np.any(h[~keep] < -FEASIBILITY_TOL):
            raise VertexEnumerationError("theta_vertices: a zero row with a negative offset (empty set)")
        H, h, norms = H[keep], h[keep], norms[keep]
        q = H.shape[0]
    Hn, hn = H / norms[:, None], h / norms
    if q < p:
        raise VertexEnumerationError(f"theta_vertices: {q} rows cannot bound a set in R^{p}")
    if _n_choose_k(q, p) > MAX_COMBINATIONS:
        return _qhull_vertices(Hn, hn)
    _, points = basic_feasible_solutions(Hn, hn)
    return _unique(points)


def basic_feasible_solutions(Hn: np.ndarray, hn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The basic feasible solutions of {θ | Hn θ <= hn} (unit rows, q >= p): (bases (b, p), points
    (b, p)) for every choice of p rows with |det| > SINGULAR_DET whose point H_B^{-1} h_B meets every
    row to FEASIBILITY_TOL·max(1, |h|). Every choice is tried (the caller keeps q choose p within
    MAX_COMBINATIONS). Raises :class:`VertexEnumerationError` when no p rows are independent
    (unbounded set) or no basis is feasible (empty set). Shared by :func:`theta_vertices` and
    :func:`amcp_drake.backends.multiplier_basis.feasible_bases`."""
    q, p = Hn.shape
    combos = combinations(q, p)
    M = Hn[combos]                       # (C, p, p)
    b = hn[combos]                       # (C, p)
    basis = np.abs(np.linalg.det(M)) > SINGULAR_DET
    if not np.any(basis):
        raise VertexEnumerationError("theta_vertices: no p linearly independent rows (unbounded set)")
    points = np.linalg.solve(M[basis], b[basis][..., None])[..., 0]
    feasible = np.all(points @ Hn.T <= hn + FEASIBILITY_TOL * np.maximum(1.0, np.abs(hn)), axis=1)
    if not np.any(feasible):
        raise VertexEnumerationError("theta_vertices: Theta_k is empty (no basic feasible solution)")
    return combos[basis][feasible], points[feasible]


def _n_choose_k(q: int, p: int) -> int:
    from math import comb

    return comb(q, p)


def _unique(points: np.ndarray) -> np.ndarray:
    """Drop basic solutions that repeat a vertex (degenerate vertices have several bases)."""
    scale = np.maximum(1.0, np.max(np.abs(points)))
    kept = [0]
    for i in range(1, len(points)):
        if np.max(np.abs(points[i] - points[kept]), axis=1).min() > DUPLICATE_TOL * scale:
            kept.append(i)
    return points[kept]


def _qhull_vertices(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    from amcp_drake.model import polytope

    try:
        return polytope.vertices(H, h)
    except ValueError as exc:  # flat or empty set: Qhull needs an interior point
        raise VertexEnumerationError(f"theta_vertices: {exc}") from None


__all__ = ["theta_vertices", "VertexEnumerationError", "MAX_COMBINATIONS", "CLARABEL_OPTIONS"]
