"""(15d) solved for p of the q multipliers of each row of (15c): the Drake plain form's Λ.

Each row ρ = (l, j, i) of (15c)-(15d) has a multiplier row Λ_ρ = Λ^j_{l|k}[i, :] ∈ R^q with

    (15d)  Λ_ρ H_θ = c_ρ,   c_ρ = [H_x]_i D^j_{l|k} ∈ R^p (linear in z_l, α_l, v_l),   Λ_ρ >= 0,
    (15c)  Λ_ρ h_θ + [H_x]_i d^j_{l|k} − α_{l+1} <= −w̄_i.

H_θ (q, p) has full column rank (Θ is bounded, docs/explanation/paper.md §2), so some p of its rows, B, form an
invertible H_B. With M = H_B^{-1} the equality (15d) is Λ_B = c_ρ M − Λ_N (H_N M) exactly, and

    Λ_ρ h_θ = c_ρ κ + Λ_N s,    κ = M h_B (the point where the facets B are active),
                                s = h_N − H_N κ (the other facets' slacks there).

So (15c)-(15d) with Λ >= 0 are, with no loss, the q − p free multipliers Λ_N >= 0, the p rows
Λ_B = c_ρ M − Λ_N H_N M >= 0 and (15c) with the coefficients κ on c_ρ and s on Λ_N: no equality
rows, and q − p instead of q multipliers per row (Example 1, 8-facet X0: 1 963 variables instead
of 3 883 and no 1 920 equalities). The full Λ_ρ is recovered from the solution by
:meth:`MultiplierBasis.full`, so the certificates re-check (15c), (15d) and Λ >= 0 on the same
multipliers as before.

B is chosen by QR with column pivoting of H_θᵀ (the best-conditioned greedy choice); for a box
H_θ = [I; −I] (rows interleaved or not) it picks one row of each pair and M is a signed identity.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np
import scipy.linalg

#: Multipliers of a basis count as >= 0 down to −DUAL_FEASIBILITY_TOL·max(1, ‖c_ρ‖): rounding of
#: c H_B^{-1} for an optimal basis with a zero multiplier (a degenerate optimum), far below the
#: answer checks' 1e-6 (model.tolerances.TUBE_TOL).
DUAL_FEASIBILITY_TOL = 1e-9
#: Largest condition number of H_B accepted: above it H_θ is treated as rank deficient (an
#: unbounded Θ, which the problem validation rejects before any QP is built).
MAX_BASIS_CONDITION = 1e10


@dataclass(frozen=True, eq=False)
class MultiplierBasis:
    """The split of the q rows of H_θ into p basic rows B and q − p others N (see the module)."""

    basic: np.ndarray      #: B (p,), row indices of H_θ, increasing
    nonbasic: np.ndarray   #: N (q − p,), the other row indices, increasing
    M: np.ndarray          #: H_B^{-1} (p, p)
    H_N: np.ndarray        #: the rows N of H_θ (q − p, p)
    HNM: np.ndarray        #: H_N M (q − p, p)

    @classmethod
    def of(cls, H_theta: np.ndarray) -> MultiplierBasis:
        """The basis of H_θ (q, p) chosen by QR with column pivoting of H_θᵀ. Raises ValueError
        when H_θ has no p rows with a condition number below :data:`MAX_BASIS_CONDITION`."""
        H = np.asarray(H_theta, float)
        q, p = H.shape
        if q <= p:
            raise ValueError(f"H_theta has {q} rows for {p} parameters: Theta is unbounded")
        _, _, pivots = scipy.linalg.qr(H.T, mode="economic", pivoting=True)
        basic = np.sort(pivots[:p])
        H_B = H[basic]
        if np.linalg.cond(H_B) > MAX_BASIS_CONDITION:
            raise ValueError(f"H_theta has no {p} well-conditioned rows (cond {np.linalg.cond(H_B):.3g}): "
                             "Theta is unbounded or nearly so")
        nonbasic = np.setdiff1d(np.arange(q), basic)
        M = np.linalg.inv(H_B)
        return cls(basic, nonbasic, M, H[nonbasic], H[nonbasic] @ M)

    @property
    def q(self) -> int:
        return len(self.basic) + len(self.nonbasic)

    def offsets(self, h_theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(κ, s) of (15c) for offsets h_θ (..., q): κ = M h_B (..., p), s = h_N − H_N κ (..., q − p)."""
        h = np.asarray(h_theta, float)
        kappa = h[..., self.basic] @ self.M.T
        return kappa, h[..., self.nonbasic] - kappa @ self.H_N.T

    def full(self, c: np.ndarray, lam_nonbasic: np.ndarray) -> np.ndarray:
        """Λ (..., q) from c (..., p) and Λ_N (..., q − p): Λ_B = c M − Λ_N H_N M, so Λ H_θ = c."""
        lam = np.empty(np.shape(c)[:-1] + (self.q,))
        lam[..., self.basic] = c @ self.M - lam_nonbasic @ self.HNM
        lam[..., self.nonbasic] = lam_nonbasic
        return lam


@dataclass(frozen=True, eq=False)
class FeasibleBases:
    """The primal feasible bases of Θ_k = {H_θ θ <= h_θ} (:func:`feasible_bases`): ``rows`` (b, p) row
    indices, ``inverse`` (p, p·b) with column k·b + j = column k of H_Bj^{-1}, so that
    (c @ inverse).reshape(r, p, b)[ρ, :, j] is c_ρ H_Bj^{-1} for every basis at once (the minimum over
    the p multipliers is taken by p − 1 elementwise minima of (r, b) slices)."""

    q: int
    rows: np.ndarray
    inverse: np.ndarray


def feasible_bases(H_theta: np.ndarray, h_theta: np.ndarray) -> FeasibleBases | None:
    """The bases B of H_θ whose point θ_B = H_B^{-1} h_B is in Θ_k, enumerated as the vertices are
    (:func:`.vertex_form.basic_feasible_solutions`); None when H_θ has more than
    :data:`.vertex_form.MAX_COMBINATIONS` bases or none is feasible (Θ_k empty)."""
    from amcp_drake.backends.vertex_form import MAX_COMBINATIONS, VertexEnumerationError, basic_feasible_solutions

    H = np.asarray(H_theta, float)
    h = np.asarray(h_theta, float)
    q, p = H.shape
    if comb(q, p) > MAX_COMBINATIONS:
        return None
    norms = np.linalg.norm(H, axis=1)
    try:
        combos, _ = basic_feasible_solutions(H / norms[:, None], h / norms)
    except VertexEnumerationError:
        return None
    inverse = np.linalg.inv(H[combos])                                                  # (b, p, p)
    return FeasibleBases(q, combos, inverse.transpose(1, 2, 0).reshape(p, -1))


def optimal_multipliers(H_theta: np.ndarray, h_theta: np.ndarray, c: np.ndarray,
                        bases: FeasibleBases | None = None) -> np.ndarray | None:
    """For each row c_ρ of ``c`` (r, p): Λ_ρ >= 0 (q,) with Λ_ρ H_θ = c_ρ and Λ_ρ h_θ minimal, i.e.
    the multipliers of (15c)-(15d) for one row, with Λ_ρ h_θ = max {c_ρ θ : H_θ θ <= h_θ} (LP
    duality). Used for the rows of (15c) that the plain form leaves out (:mod:`.dominated_rows`).

    By enumeration of the bases of H_θ (``bases``: :func:`feasible_bases` of (H_θ, h_θ), computed
    here when not given): a basis B whose point θ_B = H_B^{-1} h_B is in Θ_k (primal feasible) and
    whose multipliers λ_B = c_ρ H_B^{-1} are >= 0 (dual feasible) is optimal (an LP with a finite
    optimum has such a basis). Per row the basis with the largest min(λ_B) is taken; Λ_ρ is λ_B on
    B and 0 elsewhere, so Λ_ρ H_θ = c_ρ to rounding. Returns None when there are no feasible bases
    (or too many) or a row has no basis with min(λ_B) >= −:data:`DUAL_FEASIBILITY_TOL`·max(1, ‖c_ρ‖)
    (the caller then solves the program with every row)."""
    if bases is None:
        bases = feasible_bases(H_theta, h_theta)
        if bases is None:
            return None
    c = np.atleast_2d(np.asarray(c, float))
    r, p = c.shape
    lam = (c @ bases.inverse).reshape(r, p, -1)                                         # [ρ, :, j] = c_ρ H_Bj^{-1}
    worst = lam[:, 0].copy()                                                            # min over the p
    norm2 = c[:, 0] * c[:, 0]                                                           # multipliers and
    for k in range(1, p):                                                               # ‖c_ρ‖², by slices
        np.minimum(worst, lam[:, k], out=worst)                                        # (numpy reduces a
        norm2 += c[:, k] * c[:, k]                                                      # short axis slowly)
    best = worst.argmax(axis=1)
    rows = np.arange(r)
    if np.any(worst[rows, best] < -DUAL_FEASIBILITY_TOL * np.maximum(1.0, np.sqrt(norm2))):
        return None
    out = np.zeros((r, bases.q))
    out[rows[:, None], bases.rows[best]] = lam[rows, :, best]
    return out


__all__ = ["DUAL_FEASIBILITY_TOL", "MAX_BASIS_CONDITION", "FeasibleBases", "MultiplierBasis", "feasible_bases",
           "optimal_multipliers"]
