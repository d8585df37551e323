"""Online problems in cvxpy: the set-membership LP (9) and the projection QP of (12).

Both are DPP problems cached by shape: each call sets parameters and re-solves.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from amcp_drake.backends.base import ProjectionResult, SetUpdateResult
from amcp_drake.model.status import SolveStatus


class SetUpdateLP:
    """The fixed-complexity update (9) in its per-row primal form (docs/explanation/paper.md §2).

    With H̃ = [H_θ; H_data] ((q + r), p) and h̃ = [h_prev; h_data], for every row i of H_θ

        [h]_i = max [H_θ]_i θ_i  s.t.  H̃ θ_i <= h̃,

    i.e. the support of Θ_{k−1} ∩ Δ_k in direction [H_θ]_i. The q LPs are solved as one LP
    with q copies θ_i (rows of a (q, p) variable); its objective is separable, so the KKT
    conditions decouple row by row. The dual of row i (multipliers of H̃ θ_i <= h̃, >= 0) is
    row i of Λ: stationarity gives λ_iᵀ H̃ = [H_θ]_i and complementarity λ_iᵀ h̃ = [h]_i, which
    are the constraints Λ H̃ = H_θ, Λ h̃ <= h of (9) (with equality, and 1ᵀh minimal by duality).
    This is deliberately not the matrix form used by the Drake backend.
    """

    def __init__(self, shape: tuple[int, int, int]) -> None:
        q, r, p = shape
        self.q, self.r, self.p = q, r, p
        self.H_theta = cp.Parameter((q, p), name="H_theta")
        self.H_tilde = cp.Parameter((q + r, p), name="H_tilde")
        self.h_tilde = cp.Parameter(q + r, name="h_tilde")
        self.theta = cp.Variable((q, p), name="theta")  # row i: maximiser of row-i LP
        # row i of (θ H̃ᵀ) is (H̃ θ_i)ᵀ; right-hand side 1 h̃ᵀ repeats h̃ in every row
        self.rows = self.theta @ self.H_tilde.T <= np.ones((q, 1)) @ cp.reshape(self.h_tilde, (1, q + r), order="F")
        objective = cp.Minimize(-cp.sum(cp.multiply(self.H_theta, self.theta)))
        self.problem = cp.Problem(objective, [self.rows])

    def solve(self, call, H_theta, h_prev, H_data, h_data) -> SetUpdateResult:
        """Return h (q,) and Λ (q, q + r) >= 0, or status INFEASIBLE/UNBOUNDED with None."""
        self.H_theta.value = H_theta
        self.H_tilde.value = np.vstack([H_theta, H_data])
        self.h_tilde.value = np.concatenate([h_prev, h_data])
        status, elapsed, _ = call.solve(self.problem)
        if status is not SolveStatus.OPTIMAL:
            return SetUpdateResult(status, None, None, elapsed)
        h = np.einsum("ij,ij->i", H_theta, self.theta.value)
        # duals of a <= constraint in a minimisation are >= 0 up to solver round-off (~1e-12)
        Lambda = np.clip(np.asarray(self.rows.dual_value, float), 0.0, None)
        return SetUpdateResult(status, h, Lambda, elapsed, points=np.asarray(self.theta.value, float))


class ProjectionQP:
    """min ‖y‖² s.t. G_in y <= b_in, G_eq y = b_eq: the Euclidean projection Π of the LMS update (12)
    in the scaled form shared with the Drake backend (:mod:`amcp_drake.backends.projection_form`:
    scaled coordinates, flat slabs as mid-plane equalities); shape (inequality rows, equality rows, p)."""

    def __init__(self, shape: tuple[int, int, int]) -> None:
        rows, eq_rows, p = shape
        self.y = cp.Variable(p, name="y")
        constraints = []
        if rows:
            self.G_in = cp.Parameter((rows, p), name="G_in")
            self.b_in = cp.Parameter(rows, name="b_in")
            constraints.append(self.G_in @ self.y <= self.b_in)
        if eq_rows:
            self.G_eq = cp.Parameter((eq_rows, p), name="G_eq")
            self.b_eq = cp.Parameter(eq_rows, name="b_eq")
            constraints.append(self.G_eq @ self.y == self.b_eq)
        self.problem = cp.Problem(cp.Minimize(cp.sum_squares(self.y)), constraints)

    def solve(self, call, form) -> ProjectionResult:
        if len(form.b_in):
            self.G_in.value = form.G_in
            self.b_in.value = form.b_in
        if len(form.b_eq):
            self.G_eq.value = form.G_eq
            self.b_eq.value = form.b_eq
        status, elapsed, _ = call.solve(self.problem)
        if status is not SolveStatus.OPTIMAL:
            return ProjectionResult(status, None, elapsed)
        return ProjectionResult(status, form.theta(self.y.value), elapsed)
