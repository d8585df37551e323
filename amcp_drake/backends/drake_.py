"""Drake backend: every optimisation problem as a ``pydrake.solvers.MathematicalProgram``.

Conventions (design.md; DEVELOPERS.md engineering facts):

* Clarabel is the default solver (accurate for LP, QP and SDP). Any Drake solver can be selected
  by name (``solver="osqp"``); ``solver_options`` are passed to it.
* Programs solved repeatedly (support LPs, tube MPC QP) are built once and their coefficients
  updated with ``UpdateCoefficients``; no symbolic expression is built per step.
* Every coefficient is checked for finiteness before it reaches Drake (Drake aborts the
  interpreter with ``SystemExit`` on non-finite coefficients).
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from amcp_drake.backends import gain_lmi_compact as compact
from amcp_drake.backends.base import (
    ProjectionResult,
    SetUpdateResult,
    TubeMPCData,
)
from amcp_drake.backends.drake_set_update import DrakeSetUpdateLP
from amcp_drake.backends.drake_solver import SOLVERS, STATUS_MAP, DrakeSolver  # noqa: F401 - SOLVERS, STATUS_MAP re-exported
from amcp_drake.backends.drake_solver import DrakeSolver as _Solver  # noqa: F401 - old name, used by amcp_properties.mutants
from amcp_drake.backends.drake_solver import finite_or_raise as _finite
from amcp_drake.backends.gain_scaling import gain_residual, solve_scaled, tight_first
from amcp_drake.backends.projection_form import projection_form
from amcp_drake.backends.set_update_vertices import VertexSetUpdate
from amcp_drake.model.status import SolveStatus

#: Clarabel tolerances for the LPs (support, set update (9)). With the defaults (1e-8) the optimal
#: offsets of (9) drift above h_{k-1} by up to 1.2e-7 on Example 1, which Lemma 3 forbids; with
#: these the drift is about 1e-9 (measured on the 50-step Example 1 run).
CLARABEL_LP_OPTIONS = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}

#: Formulations of the tube MPC QP (20): "plain" = (15a)-(15d) with Λ, "vertex" = (5b) at Θ_k's vertices.
FORMULATIONS = ("plain", "vertex")
#: How the update (9) is solved: "auto" = by vertices where that applies, else the LP; "lp" = the LP.
SET_UPDATE_METHODS = ("auto", "lp")
#: From this many states on the gain LMI (16) is solved in its compact form (:mod:`.gain_lmi_compact`):
#: every shipped example (n <= 8) keeps the form as written and so its design, bit for bit.
COMPACT_FROM_N = 9

class DrakeBackend:
    """All problems of the algorithm with Drake's ``MathematicalProgram``.

    Parameters
    ----------
    solver: Drake solver for the LPs and the tube QP ("clarabel" by default).
    solver_options: options passed to that solver (e.g. ``{"tol_gap_abs": 1e-10}``).
    sdp_solver: solver for the gain LMI (must support PSD cones: "clarabel", "scs" or "csdp").
    formulation: tube MPC QP (20) with the multipliers Λ of (15c)-(15d) ("plain", the reference
        and default) or with (5b) at the vertices of Θ_k ("vertex", same optimum, no Λ:
        ``MPCSolution.Lambda`` is None; see ``drake_vertex``).
    set_update_method: "auto" (default): the update (9) by the vertices of Θ_{k−1} ∩ Δ_k with a dual
        certificate per row where that applies, else the LP; "lp": always the LP.
    qp_solver: None (default: ``solver`` for the tube QP) or "daqp": the fast path of the vertex form
        (:mod:`.daqp_fast`): DAQP warm-started from the previous active set, every answer checked by
        its KKT residuals and primal feasibility against the original rows, Clarabel on any doubt.
    """

    name = "drake"

    def __init__(self, solver: str = "clarabel", solver_options: dict | None = None,
                 sdp_solver: str = "clarabel", formulation: str = "plain", set_update_method: str = "auto",
                 qp_solver: str | None = None) -> None:
        if formulation not in FORMULATIONS:
            raise ValueError(f"formulation {formulation!r} unknown to the Drake backend; choose one of {FORMULATIONS}")
        self.formulation = formulation
        self._solver_options = dict(solver_options or {})
        self._solver = DrakeSolver(solver, solver_options)
        lp_options = dict(CLARABEL_LP_OPTIONS) if solver.lower() == "clarabel" else {}
        lp_options.update(solver_options or {})
        self._lp = DrakeSolver(solver, lp_options)
        self._lp_fallback = DrakeSolver("clp", None) if solver.lower() == "clarabel" else None
        #: the status of every direction of the last :meth:`support` call that got no answer
        self.last_support_failures: list[str] = []
        self._sdp = DrakeSolver(sdp_solver, None)
        if qp_solver not in (None, "daqp"):
            raise ValueError(f"qp_solver {qp_solver!r} unknown; choose None (the solver above) or 'daqp' (fast path)")
        if qp_solver == "daqp" and formulation != "vertex":
            raise ValueError("qp_solver='daqp' (the fast path) needs formulation='vertex'")
        self.qp_solver = qp_solver
        if set_update_method not in SET_UPDATE_METHODS:
            raise ValueError(f"set_update_method {set_update_method!r} unknown; choose one of {SET_UPDATE_METHODS}")
        self.set_update_method = set_update_method
        self._vertex_update = VertexSetUpdate()
        self._set_update_cache: dict[tuple[int, int, int], DrakeSetUpdateLP] = {}
        self.solver_name = self._solver.name

    # -- offline: gain LMI for Assumption 8 and (16) -----------------------------------------
    def robust_gain(self, A_vertices, B_vertices, Q, R, margin, tick=None):
        """maximise trace(S) s.t. for each vertex i (S = P⁻¹, Y = K S):

        [[S, (A_i S + B_i Y)ᵀ, S Q^½, Yᵀ R^½], [A_i S + B_i Y, S, 0, 0], [Q^½ S, 0, I, 0],
         [R^½ Y, 0, 0, I]] ⪰ margin·I,  S ⪰ margin·I.

        By Schur complements this is A_cl(θ^i)ᵀ P A_cl(θ^i) − P + Q + KᵀRK ⪯ 0, eq. (16).
        Solved in the coordinates of :mod:`.gain_scaling` (x = T x̃, u = U ũ with TᵀP_refT = I), so the
        margin is relative to the cost-to-go, with the objective trace(S) of the original coordinates;
        each solve is tried at Clarabel 1e-10 first (:data:`.gain_scaling.GAIN_TIGHT`); an inaccurate answer
        is solved once more in its own coordinates, then as written (:func:`.gain_scaling.solve_scaled`,
        which also re-checks (16) on the answer).
        From :data:`COMPACT_FROM_N` states on, the compact form of :mod:`.gain_lmi_compact` is solved
        instead (the same feasible set in blocks of 2n, vertices of Θ added as they are violated).
        ``tick(stage)``: called before every solve (the design's time budget and progress lines).
        """
        A_vertices = np.asarray(A_vertices, float)
        B_vertices = np.asarray(B_vertices, float)
        _finite("robust_gain", A_vertices, B_vertices, Q, R)
        one = self._gain_lmi_compact if A_vertices.shape[1] >= COMPACT_FROM_N else self._gain_lmi

        def solve(A_t, B_t, Q_t, R_t, W, options):
            if tick is not None:
                tick("gain LMI (16)")
            return one(A_t, B_t, Q_t, R_t, W, margin, options, tick=tick)
        first = tight_first(self._sdp.name == "clarabel" and one == self._gain_lmi, self._sdp.option_values)
        return solve_scaled(solve, A_vertices, B_vertices, np.asarray(Q, float), np.asarray(R, float), first=first)

    def _gain_lmi_compact(self, A_vertices, B_vertices, Q, R, weight, margin, options=None, tick=None):
        """One solve of the compact form of the LMI (16) (:mod:`.gain_lmi_compact`), maximising ⟨weight, S⟩,
        on the vertices of Θ that its active-vertex loop needs: (status, K, P) as :meth:`_gain_lmi`.

        Clarabel often ends this form "AlmostSolved" (measured on the 5- to 8-mass chains, at 1e-10 and at
        its defaults alike) with an answer whose K, P satisfy (16) at every vertex with a margin of
        ~1e-6; such an answer is accepted (status "optimal") when numpy's eigenvalues confirm (16) at every
        vertex, instead of the three further solves of the retry ladder. :func:`.gain_scaling.solve_scaled`
        and the design re-check (16) on it as on every answer."""
        S_block, stage, vertex_blocks, (n, m, ns, nx) = compact.build_blocks(A_vertices, B_vertices, Q, R)
        cost = compact.svec_weight(np.asarray(weight, float))

        def solve_subset(indices):
            prog = MathematicalProgram()
            x = prog.NewContinuousVariables(nx, "x")
            for name, block in [("S >= margin I", S_block), ("stage cost bound", stage)] + [
                    (f"(16) at vertex {i}", vertex_blocks[i]) for i in indices]:
                F = block.dense_terms(margin)
                prog.AddLinearMatrixInequalityConstraint(F, x).evaluator().set_description(name)
            prog.AddLinearCost(-np.concatenate([cost, np.zeros(nx - ns)]), 0.0, x)
            result, _ = self._sdp.solve(prog, options)
            status = self._sdp.status(result)
            if status not in (SolveStatus.OPTIMAL, SolveStatus.INACCURATE):
                return status, None
            return status, np.asarray(result.GetSolution(x), float)

        first = range(len(vertex_blocks)) if len(vertex_blocks) <= compact.ALL_VERTICES_MAX else \
            compact.initial_vertices(A_vertices, B_vertices, Q, R)
        status, x, _ = compact.solve_compact(solve_subset, vertex_blocks, list(first), tick)
        if x is None:
            return status, None, None
        S_val, Y_val = compact.unpack(x, n, m)
        if not np.all(np.isfinite(S_val)) or np.min(np.linalg.eigvalsh(S_val)) <= 0.0:
            return status, None, None
        P = np.linalg.inv(S_val)
        K, P = Y_val @ P, 0.5 * (P + P.T)
        if status is SolveStatus.INACCURATE and gain_residual(A_vertices, B_vertices, Q, R, K, P) <= 0.0:
            status = SolveStatus.OPTIMAL  # a stalled solve whose answer satisfies (16) at every vertex (docstring)
        return status, K, P

    def _gain_lmi(self, A_vertices, B_vertices, Q, R, weight, margin, options=None, tick=None):
        """One solve of the LMI of :meth:`robust_gain` (scaled data), maximising ⟨weight, S⟩, with
        ``options`` on top of the SDP solver's: (status, K, P), K and P also for an inaccurate answer."""
        n, m = A_vertices.shape[1], B_vertices.shape[2]
        Qh = _sqrtm_psd(Q)
        Rh = _sqrtm_psd(R)
        prog = MathematicalProgram()
        S = prog.NewSymmetricContinuousVariables(n, "S")
        Y = prog.NewContinuousVariables(m, n, "Y")
        with np.errstate(invalid="ignore"):  # numpy warns on object (symbolic) arrays; values are exact
            S_margin = S - margin * np.eye(n)
        prog.AddPositiveSemidefiniteConstraint(S_margin).evaluator().set_description("S >= margin I")
        for i, (Ai, Bi) in enumerate(zip(A_vertices, B_vertices)):
            self._add_vertex_lmi(prog, i, Ai, Bi, S, Y, Qh, Rh, margin)
        with np.errstate(invalid="ignore"):  # numpy warns on object (symbolic) arrays; values are exact
            prog.AddLinearCost(-np.sum(weight * S))  # trace(S) in the original coordinates
        result, _ = self._sdp.solve(prog, options)
        status = self._sdp.status(result)
        if status not in (SolveStatus.OPTIMAL, SolveStatus.INACCURATE):
            return status, None, None
        S_val = np.asarray(result.GetSolution(S), float).reshape(n, n)
        Y_val = np.asarray(result.GetSolution(Y), float).reshape(m, n)
        S_val = 0.5 * (S_val + S_val.T)
        if not np.all(np.isfinite(S_val)) or np.min(np.linalg.eigvalsh(S_val)) <= 0.0:
            return status, None, None
        P = np.linalg.inv(S_val)
        return status, Y_val @ P, 0.5 * (P + P.T)

    @staticmethod
    def _add_vertex_lmi(prog, i, Ai, Bi, S, Y, Qh, Rh, margin) -> None:
        n, m = Bi.shape
        with np.errstate(invalid="ignore"):  # numpy warns on object (symbolic) arrays; values are exact
            AS = Ai @ S + Bi @ Y
            top = np.hstack([S, AS.T, S @ Qh, Y.T @ Rh])
            second = np.hstack([AS, S, np.zeros((n, n)), np.zeros((n, m))])
            third = np.hstack([Qh @ S, np.zeros((n, n)), np.eye(n), np.zeros((n, m))])
            fourth = np.hstack([Rh @ Y, np.zeros((m, n)), np.zeros((m, n)), np.eye(m)])
            M = np.vstack([top, second, third, fourth])
            size = M.shape[0]
            binding = prog.AddPositiveSemidefiniteConstraint(M - margin * np.eye(size))
        binding.evaluator().set_description(f"(16) at vertex {i}")

    # -- offline: support-function LPs ------------------------------------------------------
    def support(self, H, h, directions):
        """max{d·x | H x <= h} for each row d, one program with its cost updated per direction: +inf when
        unbounded, NaN when no solver answered (a direction Clarabel does not answer is solved again by
        CLP; the statuses of the NaN directions are in ``last_support_failures``)."""
        H = np.asarray(H, float)
        h = np.asarray(h, float)
        directions = np.atleast_2d(np.asarray(directions, float))
        _finite("support", H, h, directions)
        n = H.shape[1]
        prog = MathematicalProgram()
        x = prog.NewContinuousVariables(n, "x")
        prog.AddLinearConstraint(sp.csc_matrix(H), np.full(len(h), -np.inf), h, x).evaluator().set_description("H x <= h")
        cost = prog.AddLinearCost(np.zeros(n), 0.0, x).evaluator()
        values = np.empty(len(directions))
        self.last_support_failures = []
        for i, d in enumerate(directions):
            cost.UpdateCoefficients(-d, 0.0)
            solver = self._lp
            result, _ = solver.solve(prog)
            status = solver.status(result)
            if status not in (SolveStatus.OPTIMAL, SolveStatus.UNBOUNDED) and self._lp_fallback is not None:
                # Clarabel ends some unbounded LPs "NumericalError" (an input-only Z leaves X_f^0 unbounded);
                # the simplex method (CLP) tells unbounded from failed
                solver = self._lp_fallback
                result, _ = solver.solve(prog)
                status = solver.status(result)
            if status is SolveStatus.OPTIMAL:
                values[i] = float(d @ result.GetSolution(x))
            elif status is SolveStatus.UNBOUNDED:
                values[i] = np.inf
            else:
                values[i] = np.nan
                self.last_support_failures.append(f"{status.value} ({solver.describe(result)})")
        return values

    # -- online: fixed-complexity set-membership update, LP (9) ------------------------------
    def set_update(self, H_theta, h_prev, H_data, h_data):
        """The update (9): h_k and its multipliers Λ (Λ H̃ = H_θ, Λ h̃ <= h_k, Λ >= 0) with
        H̃ = [H_θ; H_data], h̃ = [h_prev; h_data].

        ``set_update_method="auto"`` (default): the per-facet maximum over the vertices of
        Θ_{k−1} ∩ Δ_k, each row certified by its multipliers, the vertices of Θ_{k−1} reused when Δ_k
        cuts none of them (:class:`.set_update_vertices.VertexSetUpdate`), and the LP of
        :mod:`.drake_set_update` where that does not apply; ``"lp"``: always the LP.
        """
        H_theta, h_prev = np.asarray(H_theta, float), np.asarray(h_prev, float)
        H_data, h_data = np.asarray(H_data, float), np.asarray(h_data, float)
        # one finiteness test of the four inputs (the same verdict as four: a concatenation is finite iff each part is)
        _finite("set_update", np.concatenate((H_theta.ravel(), H_data.ravel(), h_prev.ravel(), h_data.ravel())))
        if self.set_update_method == "auto":
            start = time.perf_counter()
            answer = self._vertex_update.solve(H_theta, h_prev, H_data, h_data)
            if answer is not None:
                return SetUpdateResult(SolveStatus.OPTIMAL, answer[0], answer[1], time.perf_counter() - start,
                                       points=answer[2], method="vertices")
        H_tilde = np.vstack([H_theta, H_data])
        h_tilde = np.concatenate([h_prev, h_data])
        q, p = H_theta.shape
        key = (q, len(h_tilde), p)
        if key not in self._set_update_cache:
            self._set_update_cache[key] = DrakeSetUpdateLP(*key)
        # Θ_{k-1} ∩ Δ_k with empty interior (θ* pinned at a vertex by vertex disturbances) makes
        # this LP degenerate: its dual optimal face is unbounded and Clarabel (interior point)
        # then ends in NumericalError, AlmostSolved or even a false "unbounded" (found by the
        # property suite). The simplex method of CLP (the fallback) is exact on degenerate LPs.
        solvers = (self._lp,) if self._lp_fallback is None else (self._lp, self._lp_fallback)
        status, h, Lam, points, elapsed = self._set_update_cache[key].solve(solvers, H_theta, H_tilde, h_tilde)
        return SetUpdateResult(status, h, Lam, elapsed, points=points, method="lp")

    # -- online: projection QP of (12) -------------------------------------------------------
    def project(self, point, H, h):
        """argmin ‖θ − point‖² s.t. H θ <= h (the projection Π of (12))."""
        point = np.asarray(point, float)
        H = np.asarray(H, float)
        h = np.asarray(h, float)
        _finite("project", point, H, h)
        # Scaled coordinates and flat slabs as equalities, shared with the cvxpy backend
        # (projection_form: both found on collapsed Θ_k, e.g. campaign problem 0-19).
        form = projection_form(point, H, h)
        prog = MathematicalProgram()
        y = prog.NewContinuousVariables(point.size, "y")
        if len(form.b_in):
            prog.AddLinearConstraint(form.G_in, np.full(len(form.b_in), -np.inf), form.b_in,
                                     y).evaluator().set_description("(12) theta in set")
        if len(form.b_eq):
            prog.AddLinearEqualityConstraint(form.G_eq, form.b_eq, y).evaluator().set_description(
                "(12) theta in flat slab (mid-plane)")
        prog.AddQuadraticErrorCost(np.eye(point.size), np.zeros(point.size), y)
        # tight tolerances (as for the LPs): at the QP defaults the projection was off by 4e-6
        result, elapsed = self._lp.solve(prog)
        status = self._lp.status(result)
        if status is not SolveStatus.OPTIMAL:
            return ProjectionResult(status, None, elapsed)
        return ProjectionResult(status, form.theta(result.GetSolution(y)), elapsed)

    # -- online: tube MPC QP (20) --------------------------------------------------------------
    def tube_mpc(self, data: TubeMPCData):
        if self.formulation == "vertex":
            from amcp_drake.backends.drake_vertex import DrakeVertexTubeMPC

            return DrakeVertexTubeMPC(data, self._solver, self._solver_options, fast=self.qp_solver == "daqp")
        from amcp_drake.backends.drake_tube import DrakeTubeMPC

        return DrakeTubeMPC(data, self._solver)


def _sqrtm_psd(M: np.ndarray) -> np.ndarray:
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T
