"""Rows of (15c)-(15d) implied by others for every Θ_k ⊆ Θ0: the plain form keeps only the rest.

Row ρ = (l, j, i) of (15c)-(15d), with its multipliers eliminated by LP duality (proof of
Proposition 9), is

    F^j_{l,i} = max_{θ ∈ Θ_k} [H_x]_i (A_cl(θ) z_l + B(θ) v_l − z_{l+1}) + α_l g_{ij}(θ) − α_{l+1} <= −w̄_i,
    g_{ij}(θ) = [H_x]_i A_cl(θ) x^j,

where only g_{ij} depends on the vertex x^j of X0. If another vertex j' has g_{ij'}(θ) >= g_{ij}(θ)
for every θ ∈ Θ0, then, since α_l >= 0 and Θ_k ⊆ Θ0 (Θ_k is nested in Θ0 by (10); the dilated sets
(26) are intersected with Θ0), F^j_{l,i} <= F^{j'}_{l,i} for every (z, α, v) and every step: row
(l, j, i) is implied by row (l, j', i) and can be left out of the program without changing its
feasible set in (z, α, v). g_{ij} is affine in θ, so the test runs at the vertices of Θ0, once per
controller. Measured on Example 1 (8-facet X0): of the 64 rows per stage, 8 remain (one vertex
per facet); 4 of 16 with 4 facets, 28 of 256 with 16 facets.

The multipliers of a left-out row are still recorded (the certificates re-check (15c), (15d) and
Λ >= 0 on every row): they are the optimal multipliers of the row's own LP,
:func:`amcp_drake.backends.multiplier_basis.optimal_multipliers`.
"""

from __future__ import annotations

import numpy as np


def kept_vertices(H_x: np.ndarray, Acl0: np.ndarray, Acl_i: np.ndarray, X0_vertices: np.ndarray,
                  theta0_vertices: np.ndarray) -> np.ndarray:
    """Mask (u, v): True where row (l, j, i) of (15c) is kept (the same for every stage l).

    Vertex j is left out for facet i when some j' != j has g_{ij'} >= g_{ij} at every vertex of Θ0
    (``theta0_vertices`` (S, p)), strictly at one of them or with j' < j (of equal rows the first is
    kept). Every left-out row is then implied by a kept one (the relation is a preorder on a finite
    set, so each j is dominated by a maximal element, and maximal elements are kept). The
    comparison is exact in floating point: a pair that differs only by rounding is kept."""
    A_s = Acl0 + np.tensordot(np.asarray(theta0_vertices, float), Acl_i, axes=1)       # (S, n, n)
    g = np.einsum("ia,sab,jb->isj", np.asarray(H_x, float), A_s, np.asarray(X0_vertices, float))  # (u, S, v)
    u, _, nv = g.shape
    keep = np.zeros((u, nv), dtype=bool)
    for i in range(u):
        keep[i] = _maximal(g[i].T)
    return keep


def _maximal(points: np.ndarray) -> np.ndarray:
    """Mask of the points (v, S) that no other point dominates (>= in every coordinate, and > in one or
    earlier in the order), compared exactly. A dominator has a floating-point coordinate sum at least as
    large (rounding is monotone), and a dominated dominator is itself dominated by a kept point (the
    relation is transitive): so the points are visited by decreasing sum, each compared only with the
    points kept so far and with the points of the same sum (visited or not). The work is v times the
    number kept, not v², and memory stays (v, S)."""
    nv = len(points)
    total = points.sum(axis=1)
    order = np.lexsort((np.arange(nv), -total))         # decreasing sum, then index
    keep = np.zeros(nv, dtype=bool)
    kept: list[int] = []
    kept_points = np.empty_like(points)
    start = 0
    while start < nv:
        stop = start
        while stop < nv and total[order[stop]] == total[order[start]]:
            stop += 1
        group = order[start:stop]
        for j in group:
            g_j = points[j]
            dominated = False
            if kept:
                others = kept_points[:len(kept)]
                geq = np.all(others >= g_j, axis=1)
                strict = np.any(others > g_j, axis=1)
                earlier = np.asarray(kept) < j
                dominated = bool(np.any(geq & (strict | earlier)))
            if not dominated and len(group) > 1:
                others = points[group]
                geq = np.all(others >= g_j, axis=1)
                strict = np.any(others > g_j, axis=1)
                dominated = bool(np.any(geq & (strict | (group < j)) & (group != j)))
            if not dominated:
                keep[j] = True
                kept_points[len(kept)] = g_j
                kept.append(int(j))
        start = stop
    return keep


__all__ = ["kept_vertices"]
