"""The fixed-complexity update (9) solved exactly by basis enumeration, with its dual certificate.

(9) is, row by row, the support of Θ_{k−1} ∩ Δ_k = {θ | H̃ θ <= h̃} (H̃ = [H_θ; H_data] (R, p),
h̃ = [h_{k−1}; h_data]) in the directions of the rows of H_θ (docs/explanation/paper.md §2):

    [h_k]_i = max{[H_θ]_i θ | H̃ θ <= h̃}.

A linear function on a bounded non-empty polytope attains its maximum at a vertex, so [h_k]_i is
the per-facet maximum over the vertices of Θ_{k−1} ∩ Δ_k. The vertices are enumerated
as basic feasible solutions (every choice B of p linearly independent rows of H̃, θ_B = H̃_B⁻¹ h̃_B,
kept when H̃ θ_B <= h̃), as in :func:`.vertex_form.theta_vertices`.

The answer carries its own proof. For row i, a primal-feasible basis B whose multipliers
λ_B = H̃_B⁻ᵀ [H_θ]_iᵀ are >= 0 is optimal (LP duality: [H_θ]_i θ <= λ_Bᵀ H̃ θ <= λ_Bᵀ h̃ = [H_θ]_i θ_B
for every feasible θ), and λ (λ_B on B, 0 elsewhere) is row i of the multipliers Λ of (9):
Λ H̃ = H_θ, Λ >= 0, Λ h̃ = h_k. Such a basis exists for every row of a bounded non-empty LP
(simplex theory); when round-off hides it (degenerate vertices), or the set is empty, or there are
more than :data:`MAX_BASES` choices, :func:`solve_by_vertices` returns None and the caller solves
the LP (9) instead: "where it applies" in the words of the issue.
"""

from __future__ import annotations

from math import comb

import numpy as np

from amcp_drake.backends.vertex_form import SINGULAR_DET, combinations
from amcp_drake.model.arrays import same_bits

#: Largest number of row choices C(R, p) enumerated (Example 1: C(10, 3) = 120, about 60 µs);
#: the LP is cheaper beyond a few thousand.
MAX_BASES = 3000
#: A basic solution is primal feasible when H̃ θ <= h̃ + PRIMAL_TOL·max(1, |h̃|) on unit rows. Smaller
#: than the vertex enumeration's 1e-9: a point kept although outside by ε can raise [h_k]_i by ε,
#: and h_k must match the LP's to 1e-9; solves of p×p systems of unit rows err by ~1e-15·cond.
PRIMAL_TOL = 1e-11
#: Multipliers above −DUAL_TOL count as >= 0 (they are clipped to 0 in the returned Λ); the
#: certificate is then exact up to DUAL_TOL·Σ|h̃| in the bound λᵀ h̃.
DUAL_TOL = 1e-12
#: The value of the certifying basis must agree with the maximum over the vertices to this
#: (relative to max(1, |h|)); otherwise the enumeration is not trusted and the LP is solved.
AGREEMENT_TOL = 1e-10


def solve_by_vertices(H_theta: np.ndarray, h_prev: np.ndarray, H_data: np.ndarray,
                      h_data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(h_k (q,), Λ (q, q + r), maximisers (q, p)) of (9) by basis enumeration, each row certified
    by its multipliers (dual) and its maximising vertex (primal); None when the enumeration does
    not apply (see the module docstring)."""
    answer = _solve(H_theta, h_prev, H_data, h_data)
    return None if answer is None else answer[:3]


class VertexSetUpdate:
    """:func:`solve_by_vertices` with the vertices of Θ_{k−1} kept between steps.

    Once Θ_k has settled, most data sets Δ_k contain Θ_{k−1} (no vertex of Θ_{k−1} violates a row
    of Δ_k): then Θ_{k−1} ∩ Δ_k = Θ_{k−1} (a bounded convex set is the hull of its vertices), and
    its vertices, bases and multipliers (Λ with zeros on the rows of Δ_k) are those of the last
    enumeration of Θ_{k−1} alone, which is reused as long as (H_θ, h_{k−1}) is unchanged to the bit.
    The test is exact (H_data θ_B <= h_data without tolerance); any vertex cut off, however
    little, enumerates Θ_{k−1} ∩ Δ_k in full.
    """

    def __init__(self) -> None:
        # (H_θ, h_{k−1}, vertices (F, p), h, Λ (q, q), maximisers (q, p)) of Θ_{k−1} alone, or None
        self._last: tuple[np.ndarray, ...] | None = None
        # Λ of the reuse case for the current _last and number of data rows (zeros on the rows of Δ_k):
        # each answer is a copy of it, one call instead of zeros and a slice assignment
        self._lambda_template: np.ndarray | None = None

    def solve(self, H_theta: np.ndarray, h_prev: np.ndarray, H_data: np.ndarray,
              h_data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """As :func:`solve_by_vertices`."""
        H_theta, h_prev = np.asarray(H_theta, float), np.asarray(h_prev, float)
        H_data, h_data = np.asarray(H_data, float), np.asarray(h_data, float)
        if H_data.ndim < 2:
            H_data = np.atleast_2d(H_data)
        last = self._last
        if last is None or not (same_bits(last[1], h_prev) and same_bits(last[0], H_theta)):
            alone = _solve(H_theta, h_prev, np.zeros((0, H_theta.shape[1])), np.zeros(0))
            last = self._last = None if alone is None else (H_theta.copy(), h_prev.copy(), alone[3], *alone[:3])
            self._lambda_template = None
        if last is not None and np.logical_and.reduce(last[2].dot(H_data.T) <= h_data, axis=None):
            q = len(h_prev)
            template = self._lambda_template
            if template is None or template.shape[1] != q + len(h_data):
                template = self._lambda_template = np.zeros((q, q + len(h_data)))
                template[:, :q] = last[4]
            return last[3].copy(), template.copy(), last[5].copy()
        return solve_by_vertices(H_theta, h_prev, H_data, h_data)


def _solve(H_theta: np.ndarray, h_prev: np.ndarray, H_data: np.ndarray,
           h_data: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(h_k, Λ, maximisers (q, p), the primal-feasible basic solutions (F, p)) or None; see
    :func:`solve_by_vertices`."""
    H_theta = np.asarray(H_theta, float)
    H_tilde = np.vstack([H_theta, np.asarray(H_data, float)])
    h_tilde = np.concatenate([np.asarray(h_prev, float), np.asarray(h_data, float)])
    rows, p = H_tilde.shape
    norms = np.linalg.norm(H_tilde, axis=1)
    if rows < p or np.any(norms == 0.0) or comb(rows, p) > MAX_BASES:
        return None
    Hn, hn = H_tilde / norms[:, None], h_tilde / norms
    combos = combinations(rows, p)
    M = Hn[combos]                                              # (C, p, p)
    basis = np.abs(np.linalg.det(M)) > SINGULAR_DET
    if not np.any(basis):
        return None
    combos, M = combos[basis], M[basis]
    points = np.linalg.solve(M, hn[combos][..., None])[..., 0]   # θ_B = M_B⁻¹ h̃_B (unit rows)
    feasible = np.all(points @ Hn.T <= hn + PRIMAL_TOL * np.maximum(1.0, np.abs(hn)), axis=1)
    if not np.any(feasible):
        return None                                             # empty (or round-off): the LP decides
    combos, points = combos[feasible], points[feasible]
    M_inv = np.linalg.inv(M[feasible])                          # (F, p, p), F = feasible bases only
    values = points @ H_theta.T                                 # (F, q): [H_θ]_i θ_B
    h = values.max(axis=0)
    # multipliers on the unit rows of each basis for each direction: μᵀ = [H_θ]_i M_B⁻¹
    mu = np.matmul(H_theta[None], M_inv)                        # (F, q, p)
    dual_ok = np.all(mu >= -DUAL_TOL, axis=2)                   # (F, q)
    certified = dual_ok & (np.abs(values - h) <= AGREEMENT_TOL * np.maximum(1.0, np.abs(h)))
    if not np.all(np.any(certified, axis=0)):
        return None
    q = H_theta.shape[0]
    chosen = np.argmax(certified, axis=0)                       # first certifying basis per row
    Lambda = np.zeros((q, rows))
    cols = combos[chosen]                                       # (q, p)
    Lambda[np.arange(q)[:, None], cols] = np.clip(mu[chosen, np.arange(q)], 0.0, None) / norms[cols]
    # Θ_{k−1} ∩ Δ_k ⊆ Θ_{k−1}: [h_k]_i <= [h_{k−1}]_i exactly (Lemma 3); min removes round-off above it
    return np.minimum(h, h_tilde[:q]), Lambda, points[chosen], points


__all__ = ["MAX_BASES", "VertexSetUpdate", "solve_by_vertices"]
