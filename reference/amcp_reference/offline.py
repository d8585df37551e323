"""Offline problems in cvxpy: the robust gain LMI (Assumption 8, eq. (16)) and support LPs.

``call`` arguments are :class:`amcp_reference.backend.SolverCall` objects (solver name + options).
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from amcp_drake.backends.base import GainResult
from amcp_drake.backends.gain_scaling import gain_scaling
from amcp_drake.model.status import SolveStatus


def sqrtm_psd(M: np.ndarray) -> np.ndarray:
    """Symmetric square root M^{1/2} of a symmetric positive semidefinite matrix (eigh)."""
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


def robust_gain(call, A_vertices, B_vertices, Q, R, margin: float) -> GainResult:
    """K, P of Assumption 8 and (16) from the robust LQR LMI.

    Variables S = Sᵀ (n, n), Y (m, n). For every vertex (A_i, B_i) of {(A(θ), B(θ)) | θ ∈ Θ}:

        M_i = [[S,            (A_i S + B_i Y)ᵀ, S Q^½, Yᵀ R^½],
               [A_i S + B_i Y, S,               0,     0     ],
               [Q^½ S,        0,               I,     0     ],
               [R^½ Y,        0,               0,     I     ]]  ⪰ margin·I,   S ⪰ margin·I,

    maximise trace(S). Then K = Y S⁻¹ and P = S⁻¹. Solved in the coordinates of
    :mod:`amcp_drake.backends.gain_scaling` (x = T x̃, u = U ũ with TᵀP_refT = I; the same as the
    Drake backend), so the margin is relative to the cost-to-go; the objective is trace(S) of the
    original coordinates, ⟨TᵀT, S̃⟩. By Schur complements M_i ⪰ 0 is
    S − (A_i S + B_i Y)ᵀ S⁻¹ (A_i S + B_i Y) − S Q S − Yᵀ R Y ⪰ 0, i.e. (multiplying by P on both
    sides) A_cl,iᵀ P A_cl,i − P + Q + Kᵀ R K ⪯ 0: eq. (16) at vertex i, hence on Θ by convexity.

    Shapes: A_vertices (v, n, n), B_vertices (v, n, m), Q (n, n), R (m, m).
    """
    A_vertices = np.asarray(A_vertices, float)
    B_vertices = np.asarray(B_vertices, float)
    Q = np.asarray(Q, float)
    R = np.asarray(R, float)
    if not all(np.all(np.isfinite(a)) for a in (A_vertices, B_vertices, Q, R)) or not np.isfinite(margin):
        return GainResult(SolveStatus.ERROR, None, None)
    n, m = A_vertices.shape[1], B_vertices.shape[2]
    scaling = gain_scaling(A_vertices, B_vertices, Q, R)
    A_vertices, B_vertices, Q, R = scaling.scaled(A_vertices, B_vertices, Q, R)
    Qh, Rh = sqrtm_psd(Q), sqrtm_psd(R)
    S = cp.Variable((n, n), symmetric=True, name="S")
    Y = cp.Variable((m, n), name="Y")
    Znn, Znm, Zmn = np.zeros((n, n)), np.zeros((n, m)), np.zeros((m, n))
    constraints = [S >> margin * np.eye(n)]
    for Ai, Bi in zip(A_vertices, B_vertices):
        AS = Ai @ S + Bi @ Y
        M = cp.bmat([
            [S, AS.T, S @ Qh, Y.T @ Rh],
            [AS, S, Znn, Znm],
            [Qh @ S, Znn, np.eye(n), Znm],
            [Rh @ Y, Zmn, Zmn, np.eye(m)],
        ])
        # M is symmetric by construction (S symmetric); symmetrise so cvxpy sees it too.
        constraints.append(0.5 * (M + M.T) >> margin * np.eye(2 * n + n + m))
    problem = cp.Problem(cp.Maximize(cp.sum(cp.multiply(scaling.objective_weight, S))), constraints)
    status, _, _ = call.solve(problem)
    if status is not SolveStatus.OPTIMAL:
        return GainResult(status, None, None)
    S_val = 0.5 * (S.value + S.value.T)
    P = np.linalg.inv(S_val)
    P = 0.5 * (P + P.T)
    K = np.asarray(Y.value @ P, float)
    if gain_residual(A_vertices, B_vertices, Q, R, K, P) > GAIN_CHECK_TOL * max(1.0, np.linalg.norm(P, 2)):
        # the solver accepted an S of the order of its tolerance (e.g. an unstabilisable vertex):
        # the LMI holds to solver accuracy but (16) does not hold for P = S⁻¹ (checked in the scaled
        # coordinates, where P̃ is of order one, so the test is relative to the cost-to-go)
        return GainResult(SolveStatus.INACCURATE, None, None)
    K, P = scaling.unscaled(K, P)
    return GainResult(status, K, P)


#: Acceptance of (16) after inversion, relative to ‖P‖: an LMI error ε in S appears as about
#: ε‖P‖² in (16), i.e. ε‖P‖ relatively; with Clarabel's ε = 1e-8 a genuine solution stays below
#: 1e-4 while ‖P‖ <= 1e4. A degenerate S of the order of ε (e.g. an unstabilisable vertex,
#: accepted by the solver within its tolerance) violates (16) by about ‖P‖ itself, i.e. O(1).
GAIN_CHECK_TOL = 1e-4


def gain_residual(A_vertices, B_vertices, Q, R, K, P) -> float:
    """max over vertices of λ_max(A_clᵀ P A_cl − P + Q + Kᵀ R K), which (16) requires to be <= 0."""
    worst = -np.inf
    for Ai, Bi in zip(A_vertices, B_vertices):
        Acl = Ai + Bi @ K
        M = Acl.T @ P @ Acl - P + Q + K.T @ R @ K
        worst = max(worst, float(np.max(np.linalg.eigvalsh(0.5 * (M + M.T)))))
    return worst


class SupportLP:
    """max d·x s.t. H x <= h as one DPP problem for a shape (rows, dim) of H.

    H, h and d are parameters, so one canonicalisation serves every call with this shape (the
    design and the redundancy removal call ``support`` many times with the same shapes).
    """

    def __init__(self, shape: tuple[int, int]) -> None:
        rows, dim = shape
        self.H = cp.Parameter((rows, dim), name="H")
        self.h = cp.Parameter(rows, name="h")
        self.d = cp.Parameter(dim, name="d")
        self.x = cp.Variable(dim, name="x")
        self.problem = cp.Problem(cp.Maximize(self.d @ self.x), [self.H @ self.x <= self.h])

    def solve(self, call, H: np.ndarray, h: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """Support values for each row of ``directions`` (k, dim): +inf unbounded, nan otherwise failed."""
        self.H.value = H
        self.h.value = h
        values = np.full(len(directions), np.nan)
        for i, d in enumerate(directions):
            self.d.value = d
            status, _, _ = call.solve(self.problem)
            if status is SolveStatus.OPTIMAL:
                values[i] = float(d @ self.x.value)
            elif status is SolveStatus.UNBOUNDED:
                values[i] = np.inf
        return values
