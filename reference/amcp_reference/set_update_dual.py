"""The update (9) of the cvxpy backend solved exactly by enumerating *dual* bases.

Row i of (9) is the LP (docs/explanation/paper.md §2), with H̃ = [H_θ; H_data] (R, p) and h̃ = [h_{k−1}; h_data]:

    [h_k]_i = max{[H_θ]_i θ | H̃ θ <= h̃}  =  min{λᵀ h̃ | λᵀ H̃ = [H_θ]_i, λ >= 0}   (LP duality).

A basic solution of the dual has its support in p linearly independent rows B of H̃:
λ_B = H̃_B⁻ᵀ [H_θ]_iᵀ. It is dual feasible when λ_B >= 0, and then, for every θ of
Θ_{k−1} ∩ Δ_k, [H_θ]_i θ = λ_Bᵀ H̃_B θ <= λ_Bᵀ h̃_B (weak duality): an outer bound. Its primal
point θ_B = H̃_B⁻¹ h̃_B attains that bound ([H_θ]_i θ_B = λ_Bᵀ H̃_B θ_B = λ_Bᵀ h̃_B), so a basis
that is dual feasible *and* primal feasible (H̃ θ_B <= h̃) is optimal: its bound is attained in
the set. Such a basis exists for every row of a bounded non-empty LP (simplex theory) and
certifies the row twice: λ is row i of the multipliers Λ of (9) (Λ H̃ = H_θ, Λ >= 0, Λ h̃ = h_k)
and θ_B is a maximiser.

This is the dual of the Drake backend's enumeration (``amcp_drake.backends.set_update_vertices``:
primal-feasible bases, the maximum of [H_θ]_i over them, then a certifying dual) and written
independently of it, so that the two backends still cross-check (9). Where it does not apply —
more than :data:`MAX_BASES` choices of rows, a zero row, no basis certified within the tolerances
below (round-off on degenerate vertices), or an empty intersection — :func:`solve_by_dual_bases`
returns None and the backend solves the LP (:class:`amcp_reference.online.SetUpdateLP`).
"""

from __future__ import annotations

from functools import lru_cache
from itertools import combinations
from math import comb

import numpy as np

#: Largest number of row choices C(R, p) enumerated (Example 1: C(10, 3) = 120); beyond it the LP
#: (cvxpy, ~2 ms) is cheaper than the batched p×p solves.
MAX_BASES = 3000
#: A choice of p unit rows is a basis when |det| exceeds this: below it θ_B and λ_B are determined
#: to worse than ~1e-6, and other bases of the same vertex describe it.
SINGULAR_DET = 1e-10
#: Dual feasibility: λ_B >= −DUAL_TOL on unit rows (negative round-off is clipped to 0 in Λ; the bound
#: λᵀh̃ then errs by at most DUAL_TOL·Σ|h̃_B|, far below the 1e-9 agreement required of h).
DUAL_TOL = 1e-12
#: Primal feasibility of θ_B: H̃ θ_B <= h̃ + PRIMAL_TOL·max(1, |h̃|) on unit rows; a point kept although
#: outside by ε can move its row's value by ε, and h must match the LP to 1e-9.
PRIMAL_TOL = 1e-11
#: The certifying basis: its dual bound λ_Bᵀh̃_B and its primal value [H_θ]_i θ_B (equal in exact
#: arithmetic) agree to this, relative to max(1, |h_i|).
AGREEMENT_TOL = 1e-10


@lru_cache(maxsize=32)
def _row_choices(rows: int, p: int) -> np.ndarray:
    """Every choice of p of ``rows`` rows, (C(rows, p), p), cached per shape (read-only)."""
    choices = np.array(list(combinations(range(rows), p)), dtype=np.intp).reshape(-1, p)
    choices.setflags(write=False)
    return choices


def solve_by_dual_bases(H_theta, h_prev, H_data, h_data) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(h_k (q,), Λ (q, q + r), maximisers (q, p)) of (9), each row certified by a basis that is
    dual and primal feasible; None where the enumeration does not apply (module docstring)."""
    H_theta = np.asarray(H_theta, float)
    H_tilde = np.concatenate([H_theta, np.asarray(H_data, float).reshape(-1, H_theta.shape[1])])
    h_tilde = np.concatenate([np.asarray(h_prev, float), np.asarray(h_data, float).reshape(-1)])
    rows, p = H_tilde.shape
    q = H_theta.shape[0]
    if rows < p or comb(rows, p) > MAX_BASES:
        return None
    norms = np.sqrt((H_tilde * H_tilde).sum(axis=1))
    if not norms.all():
        return None
    unit, offset = H_tilde / norms[:, None], h_tilde / norms
    choices = _row_choices(rows, p)
    M = unit[choices]                                                  # (C, p, p): rows of each basis
    basis = np.abs(np.linalg.det(M)) > SINGULAR_DET
    choices, M = choices[basis], M[basis]
    if not len(choices):
        return None
    # dual: M_Bᵀ μ = [H_θ]_iᵀ for every row i at once, μ (C, p, q) on the unit rows of B
    mu = np.linalg.solve(M.transpose(0, 2, 1), np.broadcast_to(H_theta.T, (len(M), p, q)))
    dual_ok = (mu >= -DUAL_TOL).all(axis=1)                            # (C, q)
    bounds = np.einsum("cpq,cp->cq", mu, offset[choices])              # λ_Bᵀ h̃_B
    # primal: θ_B = M_B⁻¹ h̃_B, feasible for every row of H̃
    points = np.linalg.solve(M, offset[choices][..., None])[..., 0]    # (C, p)
    primal_ok = (points @ unit.T <= offset + PRIMAL_TOL * np.maximum(1.0, np.abs(offset))).all(axis=1)
    # equal values up to round-off (exact arithmetic: always equal; a badly conditioned basis is refused)
    agree = np.abs(points @ H_theta.T - bounds) <= AGREEMENT_TOL * np.maximum(1.0, np.abs(bounds))
    certified = dual_ok & primal_ok[:, None] & agree                   # (C, q): optimal bases per row
    if not certified.any(axis=0).all():
        return None                                                    # empty, or round-off: the LP decides
    chosen = certified.argmax(axis=0)                                  # one certifying basis per row
    columns = choices[chosen]                                          # (q, p)
    Lambda = np.zeros((q, rows))
    Lambda[np.arange(q)[:, None], columns] = np.maximum(mu[chosen, :, np.arange(q)], 0.0) / norms[columns]
    # the dual bound (an outer bound) is h; Θ_{k−1} ∩ Δ_k ⊆ Θ_{k−1} gives h <= h_{k−1} exactly (Lemma 3)
    h = np.minimum(bounds[chosen, np.arange(q)], h_tilde[:q])
    return h, Lambda, points[chosen]


class DualBasesSetUpdate:
    """:func:`solve_by_dual_bases` that first tries the last answer's maximisers.

    Row i of the last answer has a maximiser θ_i with [H_θ]_i θ_i = [h_{k−1}]_i. When every θ_i
    also satisfies the new data (H_data θ_i <= h_data) and attains [h_{k−1}]_i, it is a maximiser of
    row i over Θ_{k−1} ∩ Δ_k too (the maximum over the subset cannot exceed [h_{k−1}]_i, which θ_i
    attains), and λ = e_i (row i of H_θ itself) is its dual certificate: h_k = h_{k−1},
    Λ = [I | 0]. Both are checked here with tolerances (PRIMAL_TOL, AGREEMENT_TOL), and the
    controller checks the answer again (amcp_drake.online.answer_checks). This holds in most steps
    once Θ_k has settled; otherwise the dual bases are enumerated.
    """

    def __init__(self) -> None:
        self._points: np.ndarray | None = None  # maximisers of the last answer, (q, p)

    def solve(self, H_theta, h_prev, H_data, h_data) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool] | None:
        """(h_k, Λ, maximisers, reused) or None (then the LP decides)."""
        H_theta, h_prev = np.asarray(H_theta, float), np.asarray(h_prev, float)
        H_data, h_data = np.asarray(H_data, float).reshape(-1, H_theta.shape[1]), np.asarray(h_data, float).reshape(-1)
        points = self._points
        if points is not None and points.shape == H_theta.shape:
            H_tilde = np.concatenate([H_theta, H_data])
            h_tilde = np.concatenate([h_prev, h_data])
            norms = np.sqrt((H_tilde * H_tilde).sum(axis=1))
            if norms.all():
                slack = (points @ H_tilde.T - h_tilde) / norms          # (q, R): <= 0 inside, unit rows
                inside = (slack <= PRIMAL_TOL * np.maximum(1.0, np.abs(h_tilde / norms))).all()
                attained = (np.abs((H_theta * points).sum(axis=1) - h_prev)
                            <= AGREEMENT_TOL * np.maximum(1.0, np.abs(h_prev))).all()
                if inside and attained:
                    Lambda = np.zeros((len(h_prev), len(h_tilde)))
                    Lambda[:, :len(h_prev)] = np.eye(len(h_prev))
                    return h_prev.copy(), Lambda, points.copy(), True
        answer = solve_by_dual_bases(H_theta, h_prev, H_data, h_data)
        self._points = None if answer is None else answer[2]
        return None if answer is None else (*answer, False)


__all__ = ["MAX_BASES", "DualBasesSetUpdate", "solve_by_dual_bases"]
