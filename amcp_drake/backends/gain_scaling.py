"""Scaling of the gain LMI (Assumption 8, eq. (16)) so that its margin and the solver's tolerances
are relative to the problem, not to the units of x and u (docs/decisions.md, "Gain LMI (16) on
badly scaled systems").

The LMI in S = P⁻¹, Y = K S is solved with an absolute margin ε (S ⪰ εI and every block ⪰ εI)
and an interior-point solver whose tolerances are absolute too. Both mean something different
for every choice of units: with x in units a thousand times larger, S is a million times smaller
and ε = 1e-6 makes Example 1 infeasible. So both backends solve it in the coordinates

    x = T x̃,  u = U ũ,  with Tᵀ P_ref T = I and U = R^{-1/2},

P_ref = the mean over the vertices of Θ of the Riccati solutions P_v of (A_v, B_v, Q, R). Every
robust P of (16) satisfies P ⪰ P_v at every vertex (P bounds the cost-to-go of K at vertex v,
which is at least the optimal one), so P̃ = Tᵀ P T ⪰ I-ish and S̃ = P̃⁻¹ is of order one: the
margin is then relative to the cost-to-go. The data are transformed by congruence,

    Ã_v = T⁻¹ A_v T,  B̃_v = T⁻¹ B_v U,  Q̃ = Tᵀ Q T,  R̃ = Uᵀ R U = I,

and the objective stays that of the original problem: trace(S) = trace(T S̃ Tᵀ) = ⟨TᵀT, S̃⟩
(normalised to trace(TᵀT) = 1), so the optimiser is the same up to the margin and the solver's
accuracy. Back: K = U K̃ T⁻¹, P = T⁻ᵀ P̃ T⁻¹. Any T with Tᵀ P_ref T = I gives the same scaled
constraints up to an orthogonal congruence (a state change x' = D x maps P_ref to D⁻ᵀ P_ref D⁻¹),
so the margin and the solver see the same problem in any units; the answer is the same for
x' = c x and any change of units of u. For a non-uniform D the paper's objective trace(P⁻¹) is
itself another objective (trace(D S Dᵀ)), so K moves, but (16) is solved as accurately.

When a vertex is not stabilisable ((16) is then infeasible: K must make every vertex's closed
loop Schur), :func:`solve_scaled` answers "infeasible" without calling a solver
(:func:`unstabilisable_vertex`, the PBH test), rather than ask the solver to report it:
Clarabel does at the default margin, but at ``design.lmi_margin`` = 1e-8 or 1e-9 it
panics inside Rust on x⁺ = 1.5x + 0·u ("Eigval error"), which the Drake backend cannot catch:
the Python process is aborted (SIGABRT). A vertex that is stabilisable but has no stabilising
Riccati solution for other reasons keeps T = I and the solver decides.

The robust P can be far from P_ref (a common Lyapunov function for very different vertices:
on the two-mass spring of Kothare et al. 1996, P reaches 6.6e4 where the vertex Riccati
solutions stay below 2.3e3). When the solver then ends "inaccurate" with an answer, or its
"optimal" answer violates (16) after inversion, :func:`solve_scaled` solves once more in the
coordinates of that answer (P_ref = its P), where S̃ is of order one by construction, and, that
failing too, in the original coordinates (the LMI as written); only an "optimal" answer that
satisfies (16) is ever returned.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from amcp_drake.backends.base import GainResult
from amcp_drake.model.status import SolveStatus

#: One solve of the gain LMI in scaled data: (Ã_v, B̃_v, Q̃, R̃, objective weight W) ->
#: (status, K̃, P̃), K̃ and P̃ given for OPTIMAL and, when the solver has them, for INACCURATE.
ScaledSolve = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, "dict | None"],
                       tuple[SolveStatus, "np.ndarray | None", "np.ndarray | None"]]
#: (the last argument: solver options for this solve only, on top of the backend's; None: the backend's)

#: Clarabel tolerances tried first for every solve of the gain LMI (16), in both backends (the user's
#: options override them; :func:`tight_first`). The optimum of trace(S) is flat in Y: K is fixed only to
#: about √(relative gap). Measured on ``sls_mpc_2d_eps0.05`` (scaled data, solves at 1e-12): K_1 moves by
#: ±3.3e-5, ±3.5e-4, ±3.5e-3 within a relative objective gap of 1e-10, 1e-8, 1e-6. At the defaults (1e-8)
#: the two backends' K differed by 2.7e-4 there (``amcp compare`` failed on a shipped example: tolerance
#: 1.95e-4) and by 1.2e-4 relatively on massera2017; at 1e-10 by at most 1.7e-5 relatively over the
#: ten files of examples/ (docs/decisions.md, "Gain LMI at tight tolerances"). A tight solve that ends
#: without an accepted answer (e.g. "inaccurate": cvxpy on massera2017) is solved again at the backend's
#: own options, so no problem that designed before is lost.
GAIN_TIGHT = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
#: Settings tried on top of the first try's when it ends without an accepted answer,
#: before the backend's own options. Only the static regularisation changes: equilibration and step
#: lengths stay, so the iterates follow the first try's path and an answer lands where the first try
#: would have. Example 1 in x' = 1e3 x (Drake, on an AMD EPYC): the first try stalled "AlmostSolved"
#: where Example 1 itself is solved, the backend's options then gave a K 3.3e-5 from Example 1's (the
#: flatness of the optimum at 1e-8), this rung a K 1e-10 from it; the other rungs of the QP ladder
#: (equilibration off, shorter steps) solved it 2.7e-6 … 7e-6 away.
GAIN_TIGHT_RETRIES = ({"static_regularization_constant": 1e-10},)


def tight_first(solver_is_clarabel: bool, user_options) -> dict | None:
    """The first try's options of every gain-LMI solve: :data:`GAIN_TIGHT` for Clarabel without the
    settings the user chose (names in ``user_options``), else None (no first try)."""
    if not solver_is_clarabel:
        return None
    return {k: v for k, v in GAIN_TIGHT.items() if k not in user_options} or None


@dataclass(frozen=True, eq=False)
class GainScaling:
    """x = T x̃, u = U ũ for the gain LMI; ``reference`` says where T came from."""

    T: np.ndarray
    U: np.ndarray
    reference: str

    @property
    def objective_weight(self) -> np.ndarray:
        """W ∝ TᵀT, so that trace(S) = c ⟨W, S̃⟩ for S = T S̃ Tᵀ (c > 0). Normalised to trace 1: the
        maximiser is the same, and the objective's size no longer depends on the units (with x in
        units 1e3 smaller, TᵀT is 1e-6 and the solver stopped on its absolute gap far from the
        optimum: K off by 34 % in its first entry on Example 1)."""
        W = self.T.T @ self.T
        return W / np.trace(W)

    def scaled(self, A_vertices, B_vertices, Q, R):
        """(Ã_v, B̃_v, Q̃, R̃) of the module docstring."""
        T_inv = np.linalg.inv(self.T)
        A_t = np.array([T_inv @ A @ self.T for A in A_vertices])
        B_t = np.array([T_inv @ B @ self.U for B in B_vertices])
        Q_t = self.T.T @ Q @ self.T
        R_t = self.U.T @ R @ self.U
        return A_t, B_t, _sym(Q_t), _sym(R_t)

    def unscaled(self, K_t: np.ndarray, P_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """K = U K̃ T⁻¹, P = T⁻ᵀ P̃ T⁻¹."""
        T_inv = np.linalg.inv(self.T)
        return self.U @ K_t @ T_inv, _sym(T_inv.T @ P_t @ T_inv)


#: PBH test of :func:`unstabilisable_vertex`: a mode counts as unstable when |λ| >= 1 − this (the
#: LMI's strict decrease cannot hold at |λ| = 1 either), and as unreachable when the smallest singular
#: value of [A − λI, B] is at most this times max(1, ‖[A, B]‖₂) (eigenvalues and singular values are
#: accurate to ~1e-15 of that norm; 1e-9 leaves a factor 1e6 for round-off and still calls a mode
#: reachable whose input direction is 1e-9 of the matrix's size, which no solver would design for).
PBH_TOL = 1e-9


def unstabilisable_vertex(A_vertices, B_vertices) -> int | None:
    """The index of a vertex (A_i, B_i) that is not stabilisable (PBH: an eigenvalue λ of A_i with
    |λ| >= 1 and rank [A_i − λI, B_i] < n), or None. Every K satisfying (16) makes every vertex's
    closed loop Schur, so such a vertex makes the gain LMI infeasible."""
    for i, (A, B) in enumerate(zip(np.asarray(A_vertices, float), np.asarray(B_vertices, float))):
        n = A.shape[0]
        size = max(1.0, float(np.linalg.norm(np.hstack([A, B]), 2)))
        for lam in np.linalg.eigvals(A):
            if abs(lam) < 1.0 - PBH_TOL:
                continue
            sigma = np.linalg.svd(np.hstack([A - lam * np.eye(n), B.astype(complex)]), compute_uv=False)
            if sigma[-1] <= PBH_TOL * size:  # n singular values: rank < n
                return i
    return None


def solve_scaled(solve: ScaledSolve, A_vertices, B_vertices, Q, R, first: dict | None = None) -> GainResult:
    """The gain LMI by ``solve``, K and P in the original coordinates (module docstring). In every
    scaling, ``first`` (e.g. :func:`tight_first`) is tried first (with :data:`GAIN_TIGHT_RETRIES` when
    it stalls), then the backend's own options when it gave no accepted answer. Scalings tried in
    order, each only while no answer is decided ("infeasible" and "unbounded" are answers):

    1. :func:`gain_scaling` (mean vertex Riccati solution);
    2. the coordinates of the answer of 1 when it was "inaccurate", or "optimal" but violating (16);
    3. the identity: the LMI as written, the plain formulation, so that no problem
       solved by it is lost (found on a generated 3-state problem, seed 22 of the random problems,
       where Clarabel ended "AlmostSolved" in the cvxpy backend on 1 and 2 with P̃ ≈ I).
    """
    n, m = np.shape(A_vertices)[1], np.shape(B_vertices)[2]
    if unstabilisable_vertex(A_vertices, B_vertices) is not None:
        return GainResult(SolveStatus.INFEASIBLE, None, None)
    scaling = gain_scaling(A_vertices, B_vertices, Q, R)
    result, answer_P = _attempt(solve, scaling, A_vertices, B_vertices, Q, R, first)
    if result.status is not SolveStatus.INACCURATE and result.status is not SolveStatus.ERROR:
        return result
    if answer_P is not None:
        second = GainScaling(_inv_sqrt(answer_P), scaling.U, "the previous answer's P")
        result, _ = _attempt(solve, second, A_vertices, B_vertices, Q, R, first)
        if result.status is not SolveStatus.INACCURATE and result.status is not SolveStatus.ERROR:
            return result
    identity = GainScaling(np.eye(n), np.eye(m), "identity (the LMI as written)")
    if np.array_equal(scaling.T, identity.T) and np.array_equal(scaling.U, identity.U):
        return result
    return _attempt(solve, identity, A_vertices, B_vertices, Q, R, first)[0]


def _attempt(solve: ScaledSolve, scaling: GainScaling, A_vertices, B_vertices, Q, R, first: dict | None):
    """One scaling: the solve with ``first`` (when it ends "inaccurate", again with each of
    :data:`GAIN_TIGHT_RETRIES` on top), then (no accepted answer) with the backend's options. Returns
    (GainResult in original coordinates, the P of a positive definite answer that was not accepted,
    else None)."""
    data = scaling.scaled(A_vertices, B_vertices, Q, R)
    if first:
        result, _ = _one_solve(solve, scaling, data, first)
        if result.status is SolveStatus.OPTIMAL:
            return result, None
        if result.status is SolveStatus.INACCURATE:  # stalled: the same path with less regularisation
            for rung in GAIN_TIGHT_RETRIES:
                again, _ = _one_solve(solve, scaling, data, {**first, **rung})
                if again.status is SolveStatus.OPTIMAL:
                    return again, None
    return _one_solve(solve, scaling, data, None)


def _one_solve(solve: ScaledSolve, scaling: GainScaling, data, options: dict | None):
    """One solve in the coordinates of ``scaling`` (``data``: the scaled Ã_v, B̃_v, Q̃, R̃); returns as
    :func:`_attempt`."""
    status, K_t, P_t = solve(*data, scaling.objective_weight, options)
    answer = K_t is not None and P_t is not None and _positive_definite(P_t)
    if status is SolveStatus.OPTIMAL and not (
            answer and gain_residual(*data, K_t, P_t) <= GAIN_CHECK_TOL * max(1.0, np.linalg.norm(P_t, 2))):
        # no positive definite P, or the solver accepted an S of the order of its tolerance (e.g. an
        # unstabilisable vertex): the LMI holds to solver accuracy but (16) does not hold for
        # P = S⁻¹ (checked in the scaled coordinates, where P̃ is of order one, so relative to the
        # cost-to-go); an error in S̃ is amplified by ‖P̃‖², so the answer's own coordinates are next
        status = SolveStatus.INACCURATE
    if status is SolveStatus.OPTIMAL:
        return GainResult(status, *scaling.unscaled(K_t, P_t)), None
    usable = status is SolveStatus.INACCURATE and answer
    return GainResult(status, None, None), (scaling.unscaled(K_t, P_t)[1] if usable else None)


#: Acceptance of (16) after inversion, relative to ‖P̃‖ (scaled coordinates): an LMI error ε in S̃
#: appears as about ε‖P̃‖² in (16), i.e. ε‖P̃‖ relatively; with Clarabel's ε = 1e-8 a genuine
#: solution stays below 1e-4 while ‖P̃‖ <= 1e4. A degenerate S of the order of ε (e.g. an
#: unstabilisable vertex, accepted by the solver within its tolerance) violates (16) by about ‖P̃‖
#: itself, i.e. O(1). (Was the cvxpy backend's own check; now both backends make it.)
GAIN_CHECK_TOL = 1e-4


def gain_residual(A_vertices, B_vertices, Q, R, K, P) -> float:
    """max over vertices of λ_max(A_clᵀ P A_cl − P + Q + Kᵀ R K), which (16) requires to be <= 0."""
    worst = -np.inf
    for Ai, Bi in zip(A_vertices, B_vertices):
        Acl = Ai + Bi @ K
        M = Acl.T @ P @ Acl - P + Q + K.T @ R @ K
        worst = max(worst, float(np.max(np.linalg.eigvalsh(_sym(M)))))
    return worst


def gain_scaling(A_vertices, B_vertices, Q, R) -> GainScaling:
    """T from the mean Riccati solution over the vertices, U = R^{-1/2} (module docstring)."""
    A_vertices = np.asarray(A_vertices, float)
    B_vertices = np.asarray(B_vertices, float)
    n, m = A_vertices.shape[1], B_vertices.shape[2]
    R = np.asarray(R, float)
    if np.min(np.linalg.eigvalsh(_sym(R))) <= 0.0:  # R ≻ 0 is validated by Problem; no scaling without it
        return GainScaling(np.eye(n), np.eye(m), "identity (R is not positive definite)")
    U = _inv_sqrt(R)
    P_ref = _mean_riccati(A_vertices, B_vertices, np.asarray(Q, float), R)
    if P_ref is None:
        return GainScaling(np.eye(n), U, "identity (a vertex has no stabilising Riccati solution)")
    return GainScaling(_inv_sqrt(P_ref), U, "mean vertex Riccati solution")


def _mean_riccati(A_vertices, B_vertices, Q, R) -> np.ndarray | None:
    solutions = []
    for A, B in zip(A_vertices, B_vertices):
        try:
            with np.errstate(all="ignore"):
                P = sla.solve_discrete_are(A, B, Q, R)
        except (ValueError, np.linalg.LinAlgError):
            return None
        if not np.all(np.isfinite(P)) or np.min(np.linalg.eigvalsh(_sym(P))) <= 0.0:
            return None
        solutions.append(_sym(P))
    return _sym(np.mean(solutions, axis=0))


def _positive_definite(M: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(M)) and np.min(np.linalg.eigvalsh(_sym(M))) > 0.0)


def _inv_sqrt(M: np.ndarray) -> np.ndarray:
    vals, vecs = np.linalg.eigh(_sym(M))
    return (vecs / np.sqrt(vals)) @ vecs.T


def _sym(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)
