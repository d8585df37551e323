"""Offline problems in cvxpy: the robust gain LMI (Assumption 8, eq. (16)) and support LPs.

``call`` arguments are :class:`amcp_reference.backend.SolverCall` objects (solver name + options).
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from amcp_drake.backends.base import GainResult
from amcp_drake.backends.gain_scaling import solve_scaled, tight_first
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
    original coordinates, ⟨TᵀT, S̃⟩; each M_i ⪰ margin·I is posed as Drake poses it (:func:`psd_slack`:
    a PSD variable equal to M_i − margin·I on the upper triangle), so both backends hand Clarabel the
    same problem; every solve is tried at Clarabel 1e-10 first
    (:data:`~amcp_drake.backends.gain_scaling.GAIN_TIGHT`); (16) is re-checked on the answer, and an
    inaccurate answer is solved once more in its own coordinates, then as written
    (:func:`~amcp_drake.backends.gain_scaling.solve_scaled`). By Schur complements M_i ⪰ 0 is
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
    return solve_scaled(lambda A_t, B_t, Q_t, R_t, W, options: _gain_lmi(call, A_t, B_t, Q_t, R_t, W, margin, options),
                        A_vertices, B_vertices, Q, R, first=tight_first(call.name == "CLARABEL", call.options))


def _gain_lmi(call, A_vertices, B_vertices, Q, R, weight, margin, options=None):
    """One solve of the LMI of :func:`robust_gain` (scaled data), maximising ⟨weight, S⟩, with
    ``options`` on top of the call's: (status, K, P), K and P also for an inaccurate answer.

    Posed as the Drake backend poses it (:func:`psd_slack`): every matrix inequality M ⪰ margin·I as a
    PSD variable X with X = M − margin·I on the upper triangle. The direct form ``M >> margin*I``, a cone
    on an affine expression, stalled "AlmostSolved" on generated problems the Drake backend solves
    (docs/decisions.md, "The cvxpy gain LMI in Drake's form").
    """
    n, m = A_vertices.shape[1], B_vertices.shape[2]
    Qh, Rh = sqrtm_psd(Q), sqrtm_psd(R)
    S = cp.Variable((n, n), symmetric=True, name="S")
    Y = cp.Variable((m, n), name="Y")
    Znn, Znm, Zmn = np.zeros((n, n)), np.zeros((n, m)), np.zeros((m, n))
    constraints = [psd_slack(S - margin * np.eye(n), "S >= margin I")]
    for i, (Ai, Bi) in enumerate(zip(A_vertices, B_vertices)):
        AS = Ai @ S + Bi @ Y
        M = cp.bmat([
            [S, AS.T, S @ Qh, Y.T @ Rh],
            [AS, S, Znn, Znm],
            [Qh @ S, Znn, np.eye(n), Znm],
            [Rh @ Y, Zmn, Zmn, np.eye(m)],
        ])
        # M is symmetric by construction (S symmetric); only its upper triangle is used
        constraints.append(psd_slack(M - margin * np.eye(2 * n + n + m), f"(16) at vertex {i}"))
    problem = cp.Problem(cp.Maximize(cp.sum(cp.multiply(weight, S))), constraints)
    status, _, _ = call.solve(problem, options)
    if status not in (SolveStatus.OPTIMAL, SolveStatus.INACCURATE) or S.value is None or Y.value is None:
        return status, None, None
    S_val = 0.5 * (S.value + S.value.T)
    if not np.all(np.isfinite(S_val)) or np.min(np.linalg.eigvalsh(S_val)) <= 0.0:
        return status, None, None
    P = np.linalg.inv(S_val)
    return status, np.asarray(Y.value @ P, float), 0.5 * (P + P.T)


def psd_slack(expression, name: str) -> cp.Constraint:
    """``expression`` ⪰ 0 for a symmetric affine (k, k) expression, in the standard form of Drake's
    ``AddPositiveSemidefiniteConstraint`` on an expression: a PSD variable X (a cone on variables
    alone) and one equality per upper-triangle entry, X_ij = expression_ij (i <= j).

    Why not ``expression >> 0``: cvxpy passes that cone to Clarabel on the affine map itself, which
    Clarabel equilibrates differently and splits along its structural zeros (the zero blocks of (16);
    chordal decomposition, on by default). Of the 300 gain LMIs of ``benchmarks/gain_twins.py 0 0 150``
    that form had 220 accepted at the tight first try and 2 rejected on every rung (Clarabel
    "AlmostSolved"); without the chordal decomposition 229 and 0; in this form 277 and 0, as the Drake
    backend, which hands the same Clarabel the same problem (the same sizes; on draw 12 the same
    iterates to the printed digits). Equalities on the upper triangle only, as Drake: ``X == expression``
    on the full matrix states every off-diagonal equality twice (linearly dependent rows; 281 and 0 on
    the same draws, no better, and no longer Drake's problem). The cone X ⪰ 0 comes with the variable's
    ``PSD`` attribute; the equality is returned."""
    size = expression.shape[0]
    X = cp.Variable((size, size), PSD=True, name=f"slack of {name}")
    rows, cols = np.triu_indices(size)
    return (X - expression)[rows, cols] == 0


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
