"""The adaptive MPC online loop (docs/explanation/paper.md §6, "Online", steps (i)-(iv)), backend-agnostic.

At each k: (i) measure x_k; (ii) if k > 0 update Θ_k by (9) (or (7), or the moving window of
Remark 4) and θ̂_k by the projected LMS (12); (iii) solve the tube MPC QP (20); (iv) apply
u_k = K x_k + v*_{0|k} (21). Every optimisation problem is delegated to the backend.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from amcp_drake.backends import TubeMPCData, get_backend
from amcp_drake.backends.base import Attempt
from amcp_drake.model import polytope
from amcp_drake.model.arrays import all_finite, same_bits, scalar_operand
from amcp_drake.model.errors import InconsistentDataError, ProblemError
from amcp_drake.model.limits import DEFAULT_MAX_MEMORY_MB, estimate_for
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import Problem
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online import answer_checks, answers, policy
from amcp_drake.online.formulation_choice import resolve_formulation
from amcp_drake.online.state import ControllerState, StepState

#: Rows of Δ_k are scaled to unit norm before the update: near x = 0 the raw rows −H_w D_{k−1} are of
#: order ‖x_{k−1}‖, and the LP solvers' absolute tolerances then allow errors of order tol/‖row‖ in θ
#: (found by the property suite: the per-row LP (9) excluded θ* by 1e-2 with rows of norm ~1e-3).
#: Rows shorter than this carry nothing floating point can resolve (1 + H_w d_k is computed with an
#: absolute error ~1e-16, i.e. ~1e-10 after scaling) and are dropped, which can only enlarge Θ_k.
DELTA_ROW_MIN_NORM = 1e-6
#: Numerical margin added to every (unit) row of Δ_k, in θ units: with vertex disturbances θ* lies on
#: the boundary of every Δ_k, and Θ_k collapses onto θ* (a point, found by the property suite). The
#: LP (9) is then degenerate and interior-point and simplex solvers alike return offsets that are
#: wrong by 1e-8..1e-2 or a false "infeasible". With the margin, Θ_k always contains Θ ∩ B_ε(θ*) (a
#: set with interior), Δ_k ⊆ Δ_k^ε keeps Lemma 3 exact, and a disturbance outside W by more than
#: this distance is still reported as inconsistent data.
DELTA_MARGIN = 1e-6
#: The exact update (7) removes a row when the backend's support LP over the other rows exceeds the row's
#: bound by at most this (unit rows, θ units), i.e. removing it enlarges Θ_k by at most this much. The
#: removed rows are then re-checked (removed_row_excess) at answer_checks.SET_NESTED_TOL = 1e-8; the
#: backends' support LPs were within 6e-10 (Drake) and 2.6e-9 (cvxpy) of rational arithmetic on the thin
#: Θ_k of campaign seed 13 #6, so a row they remove passes that re-check.
REDUNDANT_ROW_TOL = polytope.REDUNDANCY_TOL

# ufunc reductions called directly: ``ndarray.all``/``sum`` and ``np.all`` reach these same reductions
# through Python wrappers (~1-2 µs per call in the online loop)
_and_reduce = np.logical_and.reduce
_add_reduce = np.add.reduce
# Products of 1-D/2-D operands are written ``a.dot(b)``: the BLAS call of ``@`` (gemv/gemm, the same bits:
# checked on the run's shapes) without the matmul ufunc's dispatch, and the routine of ``np.dot`` without
# NumPy 2's Python-level dispatcher (~0.3 µs per call; docs/decisions.md, "The overhead outside the solvers").
# The constant operands of Δ_k (6) as 0-d arrays (model.arrays.scalar_operand: the same operations, no
# conversion of a Python float per call):
_ONE = scalar_operand(1.0)
_DELTA_ROW_MIN_NORM = scalar_operand(DELTA_ROW_MIN_NORM)
_DELTA_MARGIN = scalar_operand(DELTA_MARGIN)



#: ``kind`` of the provenance entry (:mod:`amcp_drake.online.answers`) of a step at which Θ_{k−1} ∩ Δ_k is
#: empty, recorded by ``AdaptiveMPC.step(x, on_inconsistent="record")``: the update (9)/(7) had no answer
#: because the data contradict Θ and W (an answer, not a solver defect: its ``check`` is empty).
INCONSISTENT_KIND = "inconsistent_data"


def is_inconsistent(record) -> bool:
    """True when ``record`` is the record of an empty Θ_{k−1} ∩ Δ_k (:data:`INCONSISTENT_KIND`)."""
    return any(e.get("kind") == INCONSISTENT_KIND for e in (getattr(record, "answers", None) or []))


def removed_row_excess(H_kept: np.ndarray, h_kept: np.ndarray, row: np.ndarray, bound: float) -> float:
    """How far the kept rows of (7) allow exceeding a removed row: (max{row·θ | H_kept θ <= h_kept} −
    bound)/‖row‖, +inf when that LP has no optimum. HiGHS at polytope.HIGHS_CERTIFIED_OPTIONS: at its
    default tolerances (1e-7) the support of the thin Θ_k of campaign seed 13 #6 (~1e-6 wide, rows cutting
    it by 1e-10..1e-7) came out up to 9.7e-8 too large against rational arithmetic, and rows the backend
    rightly removed were put back at 7 of 15 steps; at 1e-10 it was exact to 1e-16
    (tests/test_exact_update.py)."""
    res = polytope.support(H_kept, h_kept, row, certified=True)
    if res.status != "optimal":
        return float("inf")
    return (res.value - float(bound)) / max(float(np.linalg.norm(row)), 1e-300)


@dataclass
class StepRecord:
    """Everything recorded at step k. Shapes as in :class:`~amcp_drake.backends.MPCSolution`;
    ``H_theta`` (q_k, p), ``h_theta`` (q_k,) describe Θ_k; ``set_Lambda`` are the multipliers of (9)."""

    k: int
    x: np.ndarray
    u: np.ndarray | None
    status: SolveStatus
    H_theta: np.ndarray
    h_theta: np.ndarray
    theta_hat: np.ndarray
    theta_tilde: np.ndarray | None = None
    v: np.ndarray | None = None
    z: np.ndarray | None = None
    alpha: np.ndarray | None = None
    Lambda: np.ndarray | None = None
    cost: float | None = None
    set_status: SolveStatus = SolveStatus.NOT_RUN
    set_Lambda: np.ndarray | None = None
    h_theta_stages: np.ndarray | None = None
    pe_status: str = "off"
    pe_bounds: tuple | None = None
    #: PE constraint enforced at this step (excitation.pe_quadratic): λ_min of the window Gram of the
    #: stacked input [u_j; …; u_{j−pe_dim+1}] >= pe_level. pe_dim = n + 1 is docs/explanation/paper.md §8's constraint
    #: (status "enforced"); a smaller pe_dim is a rung of the ladder used while ρ is unattainable
    #: ("enforced_partial", or "enforced_necessary" for pe_dim = 1: Σ_window u_j² >= pe_level).
    pe_level: float | None = None
    pe_dim: int | None = None
    projection_status: SolveStatus = SolveStatus.NOT_RUN
    infeasible_constraints: tuple[str, ...] = ()
    #: Which answer check failed and which fallback was used (amcp_drake.online.answer_checks, docs/decisions.md
    #: "Verified solver answers"); "" when every answer of the step passed its checks.
    detail: str = ""
    #: ``MPCSolution.detail`` of the step's QP (20) answer (which program answered, retries, fallbacks
    #: inside the backend); when the answer applied is another one (refined, or the other formulation
    #: after a failed check), its detail follows after "; ". Counted by amcp_drake.studies.resolves.
    qp_detail: str = ""
    times: dict[str, float] = field(default_factory=dict)
    #: How each solver answer of the step was obtained, as data (amcp_drake.online.answers): one entry
    #: {"problem", "outcome", "kind", "check"} per problem solved. None: a record without provenance
    #: (a trajectory written before it was recorded), reported as unknown.
    answers: list[dict[str, str]] | None = None
    #: Every solve of the step's answer policy (:mod:`amcp_drake.online.policy`), in order, as typed
    #: :class:`~amcp_drake.backends.base.Attempt` s; ``answers``, the policy's part of ``detail`` and
    #: ``qp_detail`` are rendered from them. Not written to a trajectory file (``answers`` is).
    attempts: list[Attempt] = field(default_factory=list)


class AdaptiveMPC:
    """Adaptive robust MPC of Lorenzen et al. (2019) with a chosen backend.

    ``step(x)`` returns ``(u, record)``; ``u`` is None when the QP (20) was not solved to
    optimality (the status is on the record: a solver failure is data, not an exception).
    Raises InconsistentDataError when Θ_{k-1} ∩ Δ_k is empty.

    The controller holds what is built once (problem, design, backend, the programs of (9), (12), (20))
    and the current state ``state`` (:class:`~amcp_drake.online.state.ControllerState`), which ``step``
    replaces; ``step_from(state, x)`` steps any state without changing the controller.
    """

    def __init__(self, problem: Problem, design: OfflineDesign, backend="drake",
                 options: OnlineOptions | None = None, max_memory_mb: float | None = None, **backend_options) -> None:
        self.problem = problem
        self.design = design
        self.options = options or OnlineOptions()
        # the memory limit of the other formulation, built only when an answer fails its checks
        self.max_memory_mb = DEFAULT_MAX_MEMORY_MB if max_memory_mb is None else float(max_memory_mb)
        self._other_refused: str | None = None  # why the other formulation is too large to build
        # formulation="auto": the size rule of amcp_drake.online.formulation_choice picks plain or vertex
        backend_options, self.formulation_choice = resolve_formulation(backend_options, problem, design, self.options)
        self.backend = get_backend(backend, **backend_options)
        self._backend_spec = (backend, dict(backend_options))
        self._other_mpc = None  # the other formulation of (20), built on first need (answer checks)
        self._tube_check: answer_checks.TubeCheck | None = None  # check_tube preassembled, on first need
        self._set_check = answer_checks.SetUpdateCheck()  # check_set_update, its answer-only parts reused
        self.data = TubeMPCData(
            A0=problem.A0, B0=problem.B0, A=problem.A, B=problem.B, F=problem.F, G=problem.G, Q=problem.Q,
            R=problem.R, N=problem.N, K=design.K, P=design.P, H_x=design.H_x, X0_vertices=design.X0_vertices,
            w_bar=design.w_bar, f_bar=design.f_bar, H_T=design.H_T, h_T=design.h_T, H_theta=design.H_theta, h_theta0=design.h_theta0,
            cost=self.options.cost)
        if self.options.cost != "certainty_equivalence" and self.backend.formulation != "plain":
            raise ProblemError("formulation", "'plain' (the min-max cost (19) needs formulation='plain')",
                               repr(self.backend.formulation))
        if self.options.d_theta > 0 and self.backend.formulation != "plain":
            raise ProblemError("formulation", "'plain' (time-varying parameters need formulation='plain': the "
                               "predicted sets (26) differ per stage)", repr(self.backend.formulation))
        if self.options.pe_window is not None:
            if problem.m != 1:
                raise ProblemError("online.pe_window", "None for m > 1 (the PE constraint of Section 4.2 is for "
                                   "a scalar input)", repr(self.options.pe_window))
            if self.backend.formulation != "plain":
                raise ProblemError("formulation", "'plain' (the PE constraint needs formulation='plain')",
                                   repr(self.backend.formulation))
        self.mpc = self.backend.tube_mpc(self.data)
        self._x_shape = (problem.n,)
        self._mu = scalar_operand(design.mu)  # the LMS gain μ of (12) as a 0-d array (scalar_operand)
        self._minus_H_w = -problem.H_w  # −H_w of Δ_k (6), negated once (the same product bit for bit)
        #: ‖[H_θ]_i‖: the dilation D_l of Section 4.1 on un-normalised rows (same set as on unit rows)
        self._row_norms = np.linalg.norm(np.asarray(design.H_theta, float), axis=1)
        #: max |θ_j| over Θ0 ⊇ Θ_k (scipy, once): bounds the residual of Λ H̃ = H_θ in check_set_update
        self._theta_box = self._box_of_theta0()
        self.reset()

    def initial_state(self) -> ControllerState:
        """The state at k = 0: Θ_0 = {H_θ θ <= h_θ0}, θ̂_0 from the problem, no previous step."""
        return ControllerState(k=0, H_theta=self.design.H_theta, h_theta=self.design.h_theta0,
                               theta_hat=self.problem.theta_hat0)

    def reset(self) -> None:
        """Back to k = 0 (:meth:`initial_state`)."""
        self.state = self.initial_state()

    # the current state's fields, read-only (a new state: ``ctrl.state = ctrl.state.replace(...)``)
    @property
    def k(self) -> int:
        """The index of the next step (:attr:`ControllerState.k`)."""
        return self.state.k

    @property
    def H_theta(self) -> np.ndarray:
        """The rows of Θ_k (:attr:`ControllerState.H_theta`)."""
        return self.state.H_theta

    @property
    def h_theta(self) -> np.ndarray:
        """The offsets of Θ_k (:attr:`ControllerState.h_theta`)."""
        return self.state.h_theta

    @property
    def theta_hat(self) -> np.ndarray:
        """θ̂_k (:attr:`ControllerState.theta_hat`)."""
        return self.state.theta_hat

    # -- (ii) set-membership update ------------------------------------------------------------
    def _delta(self, s: StepState, x_prev, u_prev, x) -> tuple[np.ndarray, np.ndarray]:
        """Δ_k of (6): {θ | −H_w D_{k−1} θ <= 1 + H_w d_k}, d_k = A0 x_{k−1} + B0 u_{k−1} − x_k, rows
        scaled to unit norm (see DELTA_ROW_MIN_NORM)."""
        pr = self.problem
        D, d = self._regression(s, x_prev, u_prev, x)
        H, h = self._minus_H_w.dot(D), _ONE + pr.H_w.dot(d)
        norms = np.sqrt(_add_reduce(H * H, axis=1))
        keep = norms >= _DELTA_ROW_MIN_NORM
        if not _and_reduce(keep, axis=None):
            H, h, norms = H[keep], h[keep], norms[keep]
        return H / norms[:, None], h / norms + _DELTA_MARGIN

    def _regression(self, s: StepState, x_prev, u_prev, x) -> tuple[np.ndarray, np.ndarray]:
        """(D_{k−1}, d_k) of (6): D(x_{k−1}, u_{k−1}) (n, p) and d_k = A0 x_{k−1} + B0 u_{k−1} − x_k,
        computed once per step for Δ_k and the LMS (12) (kept in the step's working state ``s``; the arguments
        are compared by identity, they are the step's own arrays)."""
        cached = s.regression
        if cached is not None and cached[0] is x_prev and cached[1] is u_prev and cached[2] is x:
            return cached[3], cached[4]
        pr = self.problem
        D = pr.regressor(x_prev, u_prev)
        d = pr.A0.dot(x_prev) + pr.B0.dot(u_prev) - x
        s.regression = (x_prev, u_prev, x, D, d)
        return D, d

    def _box_of_theta0(self) -> np.ndarray:
        """max |θ_j| over Θ0 = {H_θ θ <= h_θ0} (2p HiGHS LPs; +inf in a direction where Θ0 is unbounded)."""
        H, h = np.asarray(self.design.H_theta, float), np.asarray(self.design.h_theta0, float)
        box = np.empty(H.shape[1])
        for j in range(H.shape[1]):
            e = np.zeros(H.shape[1])
            e[j] = 1.0
            box[j] = max(abs(polytope.support(H, h, s * e).value) for s in (1.0, -1.0))
        return np.where(np.isfinite(box), box, np.inf)

    def _update_set(self, s: StepState, H_delta, h_delta, record: StepRecord) -> bool:
        """Θ_k by (7), (9) or the window; every answer checked (answer_checks). True when Θ_k is set
        (the step may go on), False when the data are inconsistent (raises) or nothing is usable."""
        opts = self.options
        if opts.update == "exact":
            return self._update_exact(s, H_delta, h_delta, record)
        if opts.update == "window":
            s.window = ([(H_delta, h_delta)] + s.window)[: opts.window]
            H_data = np.vstack([w[0] for w in s.window])
            # time-varying θ* (Section 4.1): Δ_{k−i} holds θ*_{k−i−1}, so its unit rows are dilated
            # by i·d_θ to hold θ*_{k−1} (the data of (9) must all contain the same point)
            h_data = np.concatenate([w[1] + age * opts.d_theta for age, w in enumerate(s.window)])
        else:
            H_data, h_data = H_delta, h_delta
        H_theta = self.design.H_theta
        h_prev = s.h_theta

        def check(h, Lam, pts):
            return answer_checks.failures(
                self._set_check.check(h, Lam, pts, H_theta, h_prev, H_data, h_data, self._theta_box))

        def attempt(rung):
            # the rungs of policy.SET_UPDATE: the backend's LP, HiGHS' per-row supports of Θ_{k−1} ∩ Δ_k
            # (another solver, checked the same way), Θ_{k−1} kept (always valid, and nested (10))
            if rung.name == "first":
                result = self.backend.set_update(H_theta, h_prev, H_data, h_data)
                record.times["set_update"] = result.solve_time
                record.set_status = result.status
                if result.status in (SolveStatus.INFEASIBLE, SolveStatus.UNBOUNDED):
                    # confirm emptiness independently before declaring the data inconsistent
                    _, radius = polytope.chebyshev_center(np.vstack([H_theta, H_data]), np.concatenate([h_prev, h_data]))
                    if radius == float("-inf"):
                        raise InconsistentDataError(s.k, f"LP (9) status {result.status.value}; scipy confirms the "
                                                            "intersection is empty")
                answer, failed, status, cpu = (result.h, result.Lambda), [], result.status, result.solve_time
                if status is SolveStatus.OPTIMAL:
                    failed = self._timed_checks(record, check, result.h, result.Lambda, result.points)
                    if failed:
                        record.set_status = SolveStatus.INACCURATE
            elif rung.name == "highs_support_lps":
                t0 = time.process_time()
                sup = polytope.support_certified(np.vstack([H_theta, H_data]), np.concatenate([h_prev, h_data]), H_theta)
                record.times["answer_checks_cpu"] = record.times.get("answer_checks_cpu", 0.0) + time.process_time() - t0
                if sup is None:
                    return None, Attempt("set_update", rung.name, SolveStatus.ERROR)
                answer, failed, status, cpu = (sup.values, sup.duals), check(sup.values, sup.duals, sup.points), \
                    SolveStatus.OPTIMAL, 0.0
            else:
                return (None, None), Attempt("set_update", rung.name, SolveStatus.OPTIMAL, accepted=True)
            return answer, Attempt("set_update", rung.name, status, check=failed[0].name if failed else "",
                                   accepted=status is SolveStatus.OPTIMAL and not failed, failures=tuple(failed),
                                   solver_cpu=cpu)

        (h, Lam), attempts = policy.run(policy.SET_UPDATE, attempt)
        self._record_attempts(record, policy.SET_UPDATE, attempts)
        s.h_theta = self._dilate(np.asarray(h_prev, float) if h is None else self._nested(s, h), 1)
        if h is not None:
            record.set_Lambda = Lam
        return True

    @staticmethod
    def _timed_checks(record: StepRecord, check, *args) -> list:
        """``check(*args)``, its CPU time added to ``record.times["answer_checks_cpu"]``."""
        t0 = time.process_time()
        failed = check(*args)
        record.times["answer_checks_cpu"] = record.times.get("answer_checks_cpu", 0.0) + time.process_time() - t0
        return failed

    def _update_exact(self, s: StepState, H_delta, h_delta, record: StepRecord) -> bool:
        """(7) with redundant rows removed by backend LPs (a row goes when the others allow exceeding it
        by at most REDUNDANT_ROW_TOL); every removed row is re-checked with HiGHS at its certified
        tolerances (:func:`removed_row_excess`: it must be implied by the kept rows to SET_NESTED_TOL,
        else Θ_k ⊄ Θ_{k−1}), and the rows that are not are kept.

        The removed rows are checked in order and a row that is not implied is put back at once, so the
        rows checked after it are checked against it too. Sound: adding rows to the kept set can only
        shrink it, so a removed row implied by the smaller set stays implied. Putting back only the failed
        row (not every row) keeps Θ_k from growing by several rows a step; the re-check uses the backend's
        LP tolerances (HiGHS at its defaults was 4e-8 off on campaign seed 13 #6 and put rows back at 7
        of 15 steps)."""
        H = np.vstack([s.H_theta, H_delta])
        h = np.concatenate([s.h_theta, h_delta])
        _, radius = polytope.chebyshev_center(H, h)
        if radius == float("-inf"):
            raise InconsistentDataError(s.k, "exact intersection (7) is infeasible")
        q = len(s.h_theta)
        dropped = np.zeros(len(h), dtype=bool)
        if s.exact_rows_irredundant:
            # a row of Δ_k with sup over Θ_{k−1} <= its bound is implied by Θ_{k−1} ⊇ Θ_{k−1} ∩ Δ_k, so by
            # whatever rows describe the intersection: dropped at once (re-checked below like any
            # removed row). When none cuts, Θ_k = Θ_{k−1}, whose rows are irredundant: no other LP.
            dropped[q:] = self.backend.support(s.H_theta, s.h_theta, H_delta) <= h_delta + REDUNDANT_ROW_TOL
        if dropped[q:].all():
            keep = ~dropped
        else:
            keep = self._irredundant_rows(H, h, dropped)
        s.exact_rows_irredundant = True
        record.set_status = SolveStatus.OPTIMAL
        t0 = time.process_time()
        not_implied = {}
        for i in np.flatnonzero(~keep):  # in order; a row put back counts for the rows checked after it
            excess = removed_row_excess(H[keep], h[keep], H[i], h[i])
            if excess > answer_checks.SET_NESTED_TOL:
                not_implied[int(i)] = excess
                keep[i] = True
        record.times["answer_checks_cpu"] = record.times.get("answer_checks_cpu", 0.0) + time.process_time() - t0
        if not_implied:
            record.set_status = SolveStatus.INACCURATE
            self._note(record, f"exact update (7): {len(not_implied)} removed row(s) not implied by the kept rows "
                               f"(worst {max(not_implied.values()):.3g} > {answer_checks.SET_NESTED_TOL:.0e}, HiGHS); "
                               "fallback: those rows kept")
            self._answer(record, "exact_update", "fallback", "removed_rows_kept", "removed row implied by the kept rows")
        else:
            self._answer(record, "exact_update", "first")
        s.H_theta, s.h_theta = H[keep], h[keep]
        return True

    def _nested(self, s: StepState, h) -> np.ndarray:
        """min(h, h_θ,k−1) for a checked answer h of (9): Θ_{k−1} ∩ Δ_k ⊆ Θ_{k−1}, so every offset of
        Θ_{k−1} bounds the update too, and the smaller of the two is still an outer bound. It makes the
        nesting (10) exact where a solver's h exceeds h_θ,k−1 by round-off (the answer check allows
        SET_NESTED_TOL = 1e-8): without it a window update drifted 4e-9 above h_θ0 in 15 steps (campaign
        seed 4 #37), and the Drake plain form left its reduced program, which needs Θ_k ⊆ Θ0."""
        return np.minimum(np.asarray(h, float), s.h_theta)

    @staticmethod
    def _note(record: StepRecord, text: str) -> None:
        record.detail = f"{record.detail}; {text}" if record.detail else text

    @classmethod
    def _answer(cls, record: StepRecord, problem: str, outcome: str, kind: str = "", check: str = "") -> None:
        """Record how the step's answer of ``problem`` was obtained (:mod:`amcp_drake.online.answers`)."""
        cls._entry(record, answers.entry(problem, outcome, kind, check))

    @staticmethod
    def _entry(record: StepRecord, entry: dict[str, str]) -> None:
        """Append the provenance entry ``entry`` to ``record.answers``."""
        if record.answers is None:  # a record built outside step(), e.g. by a replay of one update
            record.answers = []
        record.answers.append(entry)

    def _dilate(self, h: np.ndarray, l: int) -> np.ndarray:
        """min(h + l d_θ n, h_θ0), n_i = ‖[H_θ]_i‖: the fixed-shape form of D_l(·) ∩ Θ0 of (25)/(26).

        For a row [H_θ]_i and ‖θ*_{k+l} − θ*_k‖ <= l d_θ, Cauchy-Schwarz gives [H_θ]_i θ*_{k+l} <=
        [H_θ]_i θ*_k + l d_θ ‖[H_θ]_i‖, which is D_l on the normalised row. Intersecting with
        Θ0 = {H_θ θ <= h_θ0} ⊇ Θ (same shape) is the row-wise min: this is (25) with Θ replaced by
        its outer approximation Θ0 of the fixed shape (equal to Θ when H_θ is that of (3)).
        """
        if self.options.d_theta == 0.0 or l == 0:
            return h
        return np.minimum(h + l * self.options.d_theta * self._row_norms, np.asarray(self.design.h_theta0, float))

    def stage_offsets(self, h: np.ndarray) -> np.ndarray:
        """(N, q) offsets of the predicted sets (26): row l is h_{θ l|k} = min(h_θk + l d_θ n, h_θ0)."""
        return np.stack([self._dilate(h, l) for l in range(self.problem.N)])

    def _irredundant_rows(self, H: np.ndarray, h: np.ndarray, dropped: np.ndarray | None = None) -> np.ndarray:
        """Rows of {H θ <= h} not implied by the others (support LPs of the backend), in order; rows
        ``dropped`` (known to be implied) are left out from the start."""
        keep = np.ones(len(h), dtype=bool) if dropped is None else ~dropped
        for i in np.flatnonzero(keep):
            keep[i] = False
            value = self.backend.support(H[keep], h[keep], H[i:i + 1])[0]
            if not (value <= h[i] + REDUNDANT_ROW_TOL):
                keep[i] = True
        return keep

    # -- (ii) projected LMS (12) -----------------------------------------------------------------
    def _update_estimate(self, s: StepState, x_prev, u_prev, x, record: StepRecord) -> bool:
        """θ̂_k by (12); the backend's projection is checked (answer_checks.check_projection) and
        replaced, when it fails, by the least-distance solution (another solver, checked the same
        way), else by θ̂_{k−1} if it is in S, else by the Chebyshev centre of S if it is in S. True
        when θ̂_k is set."""
        pr = self.problem
        D, d = self._regression(s, x_prev, u_prev, x)
        # x_k − x̂_k with x̂_k = A(θ̂)x_{k−1} + B(θ̂)u_{k−1} = A0 x_{k−1} + B0 u_{k−1} + D θ̂ by (2): −(d_k + D θ̂)
        error = -(d + D.dot(s.theta_hat))
        theta_tilde = s.theta_hat + (self._mu * D.T).dot(error)
        record.theta_tilde = theta_tilde
        if self.options.projection == "Theta":
            H, h, target = pr.H_theta, pr.h_theta, "Θ"
        else:
            H, h, target = s.H_theta, s.h_theta, "Θ_k"
        if _and_reduce(H.dot(theta_tilde) <= h, axis=None):
            # the projection of a point of the set is the point itself: no QP needed
            s.theta_hat = theta_tilde
            record.projection_status = SolveStatus.OPTIMAL
            return True
        candidates = (s.theta_hat,)
        tol = answer_checks.PROJECTION_MEMBERSHIP_TOL

        def checked(rung, theta, cpu=0.0):
            failed = answer_checks.failures(answer_checks.check_projection(theta, theta_tilde, H, h, candidates))
            return theta, Attempt("projection", rung, SolveStatus.OPTIMAL, check=failed[0].name if failed else "",
                                  accepted=not failed, solver_cpu=cpu, failures=tuple(failed))

        def in_S(theta) -> bool:
            Hn, hn = polytope.normalize_rows(H, h)
            return bool(np.all(np.isfinite(theta))) and float(np.max(Hn @ theta - hn)) <= tol

        def attempt(rung):
            # the rungs of policy.PROJECTION
            if rung.name == "first":
                result = self.backend.project(theta_tilde, H, h)
                record.times["projection"] = result.solve_time
                record.projection_status = result.status
                clock[0] = time.process_time()  # the checks and fallbacks from here: answer_checks_cpu
                if result.status is not SolveStatus.OPTIMAL:
                    return None, Attempt("projection", "first", result.status, solver_cpu=result.solve_time)
                theta, a = checked("first", result.theta, cpu=result.solve_time)
                if not a.accepted:
                    record.projection_status = SolveStatus.INACCURATE
                return np.asarray(theta, float), a
            if rung.name == "least_distance":
                ldp = polytope.least_distance_point(theta_tilde, H, h)
                return (None, Attempt("projection", rung.name, SolveStatus.ERROR)) if ldp is None else checked(rung.name, ldp)
            if rung.name == "kept_previous_estimate":
                return None, Attempt("projection", rung.name, SolveStatus.OPTIMAL, accepted=in_S(s.theta_hat))
            centre, radius = polytope.chebyshev_center(H, h)
            ok = in_S(centre)
            return centre, Attempt("projection", rung.name, SolveStatus.OPTIMAL if ok else SolveStatus.INFEASIBLE,
                                   accepted=ok, options=(("radius", f"{radius:.3g}"),))

        clock = [time.process_time()]
        try:
            theta, attempts = policy.run(policy.PROJECTION, attempt)
        finally:
            record.times["answer_checks_cpu"] = record.times.get("answer_checks_cpu", 0.0) + time.process_time() - clock[0]
        self._record_attempts(record, policy.PROJECTION, attempts, target=target)
        if not attempts[-1].accepted:
            return False
        if theta is not None:
            s.theta_hat = theta
        return True

    # -- (iii) the QP (20), with the PE two-QP procedure of docs/explanation/paper.md §8 when enabled -----------------
    def _solve_qp(self, s: StepState, x, h_arg, H_arg, record: StepRecord):
        """(answer, checked): the QP (20), or docs/explanation/paper.md §8's PE procedure; ``checked`` is True when the
        answer already passed the answer checks (a PE candidate is checked before it competes)."""
        opts = self.options
        if opts.pe_window is None:
            return self.mpc.solve(x, h_arg, s.theta_hat, H_arg), False
        from amcp_drake.online.excitation import RETRY_LEVEL_FACTORS, pe_bounds, pe_quadratic, pe_quadratic_at

        u_hist = np.array(s.u_hist)
        quad = pe_quadratic(u_hist, self.problem.n, opts.pe_window, opts.pe_level)
        bounds = pe_bounds(quad)
        if bounds is None:
            record.pe_status = "inactive" if quad is None else "satisfied"
            return self.mpc.solve(x, h_arg, s.theta_hat, H_arg), False
        spent = 0.0
        level = quad.level
        # the rung's level, then reduced levels (RETRY_LEVEL_FACTORS) when no input reaches it
        for factor in (1.0,) + RETRY_LEVEL_FACTORS:
            if factor != 1.0:
                quad = pe_quadratic_at(u_hist, quad.dim, opts.pe_window, level * factor)
                bounds = pe_bounds(quad)
                if bounds is None:  # the reduced level holds for every input
                    record.times["pe_solver"] = spent
                    record.pe_status, record.pe_dim, record.pe_level = "satisfied", int(quad.dim), float(quad.level)
                    return self.mpc.solve(x, h_arg, s.theta_hat, H_arg), False
            best, best_b = None, None
            for b in bounds:
                sol = self.mpc.solve(x, h_arg, s.theta_hat, H_arg, u0_bounds=b)
                spent += sol.solver_time
                if sol.status is not SolveStatus.OPTIMAL:
                    continue
                # verified before it competes: a wrong "optimal" under the PE bound (thorough profile:
                # Clarabel answered a PE-bounded QP with (15c) violated by 0.15) counts as no answer,
                # so the reduced levels and the fallback to (20) alone still apply
                what = f"tube QP (20) with PE bound u_0 in [{b[0]:.6g}, {b[1]:.6g}]"
                cand, attempts = policy.run(policy.PE_CANDIDATE, self._tube_rungs(
                    s, "pe_candidate", sol, False, x, h_arg, H_arg, b, record))
                record.attempts.extend(attempts)
                if cand is None:
                    first = attempts[0]
                    self._note(record, answer_checks.describe_failures(what, list(first.failures)) + "; candidate dropped")
                    self._answer(record, "pe_candidate", "not_solved", "candidate_dropped", first.check)
                    continue
                if cand is not sol:
                    self._note(record, policy.notes(policy.PE_CANDIDATE, attempts, what))
                    self._entry(record, policy.answer_entry(policy.PE_CANDIDATE, attempts))
                sol = cand
                if best is None or sol.cost < best.cost:
                    best, best_b = sol, b
            if best is not None:
                record.times["pe_solver"] = spent
                record.pe_status = ("enforced" if quad.dim == self.problem.n + 1 else
                                    "enforced_necessary" if quad.necessary_only else "enforced_partial")
                record.pe_dim = int(quad.dim)
                record.pe_bounds = tuple(float(v) for v in best_b)
                record.pe_level = float(quad.level)
                return best, True
        record.times["pe_solver"] = spent
        # no input satisfies both (20) and the PE constraint: (20) alone (SRC-1's fallback; the PE
        # constraint is not part of the recursive-feasibility argument)
        record.pe_status = "fallback"
        return self.mpc.solve(x, h_arg, s.theta_hat, H_arg), False

    # -- (iii) answer checks of (20) and the other formulation as fallback --------------------------
    def _tube_checks(self, sol, x, h_arg, H_arg, s: StepState | None = None) -> list:
        """answer_checks.check_tube (preassembled: answer_checks.TubeCheck) with Θ_k's vertices (Qhull)
        for the (5b) check: always in the vertex form; in the plain form too when Θ_k is one set for
        every stage (d_θ = 0), since (15c) and (15d) each met to 1e-6 bound (5b) only to about
        1e-6·(1 + ‖θ‖) (thorough profile: a plain answer 1.25e-6 outside (5b) passed them). ``s``: the
        step's working state (θ̂_k, the vertex cache); None: a copy of the current state (its cache unchanged)."""
        if s is None:
            s = self.state.working()
        vertices = None
        if sol.v is not None and (sol.Lambda is None or np.ndim(h_arg) == 1):
            H = np.asarray(self.design.H_theta if H_arg is None else H_arg, float)
            h = np.asarray(h_arg, float)
            h = h if h.ndim == 1 else h[0]
            last = s.checked_vertices
            if last is not None and same_bits(last[1], h) and same_bits(last[0], H):
                vertices = last[2]
            else:
                vertices = self._theta_k_vertices(H, h, s.theta_hat)
                s.checked_vertices = (H.copy(), h.copy(), vertices)
        if self._tube_check is None or self._tube_check.data is not self.data:
            self._tube_check = answer_checks.TubeCheck(self.data)
        return self._tube_check.check(sol, x, vertices, h_arg, H_arg)

    #: An interior point for Qhull must be this far inside every unit row of Θ_k (θ units); closer,
    #: the Chebyshev centre is computed by an LP instead.
    INTERIOR_MARGIN = 1e-6

    def _theta_k_vertices(self, H: np.ndarray, h: np.ndarray, theta_hat: np.ndarray) -> np.ndarray | None:
        """Vertices of Θ_k by Qhull, for the vertex-form check of (5b); None when they cannot be found (the
        check is then "not run"). θ̂_k serves as Qhull's interior point when it is INTERIOR_MARGIN inside Θ_k,
        which saves the Chebyshev LP (1.6 of 1.7 ms per step on Example 1)."""
        from scipy.spatial import HalfspaceIntersection

        Hn, hn = polytope.normalize_rows(H, h)
        if float(np.min(hn - Hn @ theta_hat)) >= self.INTERIOR_MARGIN:
            try:
                return HalfspaceIntersection(np.hstack([Hn, -hn[:, None]]), np.asarray(theta_hat, float)).intersections
            except (ValueError, RuntimeError):
                pass
        return polytope.theta_vertices(H, h)  # flat Θ_k too (in its affine hull); None if empty/unbounded

    def _other_formulation(self):
        """The tube QP (20) in the other formulation ("plain" <-> "vertex") of the same backend, or None
        where only "plain" applies (min-max cost, d_θ > 0, PE) or the backend was passed as an instance."""
        opts = self.options
        name, backend_options = self._backend_spec
        if (not isinstance(name, str) or opts.cost != "certainty_equivalence" or opts.d_theta > 0
                or opts.pe_window is not None):
            return None
        if self._other_refused is not None:
            return None
        if self._other_mpc is None:
            other = "vertex" if self.backend.formulation == "plain" else "plain"
            est = estimate_for(self.problem, None, 1, self.options, design=self.design, formulation=other)
            if est.memory_bytes > self.max_memory_mb * 2**20:
                self._other_refused = (f"the {other} form's estimated size exceeds the memory limit of "
                                       f"{self.max_memory_mb:,g} MiB ({est.describe()})")
                return None
            options = {**backend_options, "formulation": other}
            # the fast path (qp_solver="daqp") is the vertex form's only: the plain form of a fast-path
            # controller is solved by the backend's solver (the fast-path option would raise ValueError there)
            options.pop("qp_solver", None)
            self._other_mpc = get_backend(name, **options).tube_mpc(self.data)
        return self._other_mpc

    def _tube_rungs(self, s: StepState, problem: str, first, checked: bool, x, h_arg, H_arg, u0_bounds,
                    record: StepRecord):
        """The function :func:`amcp_drake.online.policy.run` calls for each rung of the tube QP (20)
        (:data:`~amcp_drake.online.policy.TUBE_QP`, or a PE candidate's
        :data:`~amcp_drake.online.policy.PE_CANDIDATE`): ``first`` is the answer of the first try
        (``checked``: it passed the answer checks already); "refine" solves the same QP again with
        iterative refinement when the backend's program ``REFINES`` (the first try runs without it for
        speed, clarabel_retry.NO_REFINEMENT; found by the thorough profile: a first try 1.3e-6 outside
        (15c) at x_0 on the boundary of the feasible set); "other_formulation" solves the other
        formulation of the same backend (:meth:`_other_formulation`; not run when there is none). Every
        "optimal" answer is checked (:meth:`_failed_tube_checks`)."""
        def attempt(rung):
            if rung.name == "first":
                failed = [] if checked or first.status is not SolveStatus.OPTIMAL else \
                    self._failed_tube_checks(s, first, x, h_arg, H_arg, record)
                return first, self._attempt(problem, "first", first, failed)
            if rung.name == "refine":
                if not self.mpc.REFINES:
                    return None
                alt = self.mpc.solve(x, h_arg, s.theta_hat, H_arg, u0_bounds=u0_bounds, refine=True)
                record.times["solver_refined"] = record.times.get("solver_refined", 0.0) + alt.solver_time
                failed = (self._failed_tube_checks(s, alt, x, h_arg, H_arg, record)
                          if alt.status is SolveStatus.OPTIMAL else [])
                return alt, self._attempt(problem, "refine", alt, failed, (("refine", "true"),))
            other = self._other_formulation()
            if other is None:
                because = self._other_refused or "no other formulation for these options"
                return None, Attempt(problem, rung.name, SolveStatus.NOT_RUN, check=because)
            alt = other.solve(x, h_arg, s.theta_hat, H_arg)
            record.times["solver_fallback"] = alt.solver_time
            failed = (self._failed_tube_checks(s, alt, x, h_arg, H_arg, record)
                      if alt.status is SolveStatus.OPTIMAL else [])
            return alt, self._attempt(problem, rung.name, alt, failed,
                                      (("formulation", other.formulation),))
        return attempt

    @staticmethod
    def _attempt(problem: str, rung: str, sol, failed: list, options: tuple = ()) -> Attempt:
        """The :class:`Attempt` of a solve of (20) whose answer ``sol`` failed the checks ``failed``."""
        return Attempt(problem, rung, sol.status, check=failed[0].name if failed else "",
                       accepted=sol.status is SolveStatus.OPTIMAL and not failed, options=options,
                       solver_cpu=sol.solver_time, failures=tuple(failed), detail=sol.detail, inner=sol.attempts)

    def _failed_tube_checks(self, s: StepState, sol, x, h_arg, H_arg, record: StepRecord) -> list:
        """The failed answer checks of ``sol`` (:meth:`_tube_checks`); their CPU time is added to
        ``record.times["answer_checks_cpu"]``."""
        t0 = time.process_time()
        failed = answer_checks.failures(self._tube_checks(sol, x, h_arg, H_arg, s))
        record.times["answer_checks_cpu"] = record.times.get("answer_checks_cpu", 0.0) + time.process_time() - t0
        return failed

    def _verified_qp(self, s: StepState, sol, checked: bool, x, h_arg, H_arg, record: StepRecord):
        """The answer of (20) to apply, or None: the rungs of :data:`~amcp_drake.online.policy.TUBE_QP`
        from the first answer ``sol`` (``checked``: it passed the checks already). The step status is
        "inaccurate" when an "optimal" first answer failed a check and its re-solve did not answer, and
        when an answer of the other formulation replaced one with no answer (:attr:`policy.TUBE_QP.no_answer <amcp_drake.online.policy.TUBE_QP>`); an
        "infeasible" QP is an answer and has no fallback."""
        answer, attempts = policy.run(policy.TUBE_QP, self._tube_rungs(s, "tube_qp", sol, checked, x, h_arg, H_arg,
                                                                       None, record))
        self._record_attempts(record, policy.TUBE_QP, attempts)
        record.qp_detail = policy.solver_details(attempts)
        why = policy.reason(policy.TUBE_QP, attempts[0])
        if (why == "check" and attempts[-1].rung != "refine") or (why == "no_answer" and answer is not None):
            record.status = SolveStatus.INACCURATE
        return answer

    def _record_attempts(self, record: StepRecord, pol, attempts: list, **names: str) -> None:
        """Add ``attempts`` of the problem of ``pol`` to the record, with the note (``names``: its fields,
        :func:`~amcp_drake.online.policy.notes`) and the provenance entry rendered from them
        (:mod:`amcp_drake.online.policy`)."""
        record.attempts.extend(attempts)
        note = policy.notes(pol, attempts, **names)
        if note:
            self._note(record, note)
        self._entry(record, policy.answer_entry(pol, attempts))

    def _inconsistent(self, record: StepRecord, exc: InconsistentDataError, start: float) -> StepRecord:
        """The record of a step at which Θ_{k−1} ∩ Δ_k is empty (``step(x, on_inconsistent="record")``)."""
        record.status = record.set_status = SolveStatus.INFEASIBLE
        record.detail = str(exc)
        self._answer(record, "exact_update" if self.options.update == "exact" else "set_update", "not_solved",
                     INCONSISTENT_KIND)
        record.times["total"] = time.perf_counter() - start
        return record

    # -- one step --------------------------------------------------------------------------------
    def step(self, x: np.ndarray, on_inconsistent: str = "raise") -> tuple[np.ndarray | None, StepRecord]:
        """Steps (i)-(iv) at the measured state x_k from the current state (:meth:`step_from`), which
        then becomes the next state."""
        u, self.state, record = self.step_from(self.state, x, on_inconsistent)
        return u, record

    def step_from(self, state: ControllerState, x: np.ndarray,
                  on_inconsistent: str = "raise") -> tuple[np.ndarray | None, ControllerState, StepRecord]:
        """Steps (i)-(iv) at the measured state x_k from ``state``: (u_k, the next state, the step's record).

        A function of (``state``, x) given what the controller builds once (design, programs): ``state``
        is not changed, and two states stepped by one controller, interleaved, are two independent runs.
        The programs are shared: every solve sets all coefficients it uses from the step's inputs.
        ``u_k`` is None when the QP (20) was not solved (the status is on the record); ProblemError when
        x is not a finite vector of length n.

        When Θ_{k−1} ∩ Δ_k is empty (the data contradict Θ and W), ``on_inconsistent="raise"`` (the
        default) raises InconsistentDataError; ``"record"`` returns ``(None, state, record)`` instead, the
        record holding the event (:data:`INCONSISTENT_KIND`, :func:`is_inconsistent`): status ``infeasible``,
        Θ_{k−1} and θ̂_{k−1} unchanged, the message in ``detail``. The run should stop there: the
        state returned is ``state``, that of step k−1 (a measured run keeps its records up to this one)."""
        if on_inconsistent not in ("raise", "record"):
            raise ProblemError("on_inconsistent", "'raise' or 'record'", repr(on_inconsistent))
        start = time.perf_counter()
        x = np.asarray(x, float)
        if x.shape != self._x_shape or not all_finite(x):
            raise ProblemError("x", f"a finite state vector of length {self.problem.n}", f"{x!r}")
        s = state.working()
        record = StepRecord(k=s.k, x=x, u=None, status=SolveStatus.NOT_RUN, H_theta=s.H_theta,
                            h_theta=s.h_theta, theta_hat=s.theta_hat, answers=[])
        if s.prev is not None and self.options.update != "none":
            x_prev, u_prev = s.prev
            t0 = time.perf_counter()
            try:
                ok = self._update_set(s, *self._delta(s, x_prev, u_prev, x), record)
            except InconsistentDataError as exc:
                if on_inconsistent == "raise":
                    raise
                return None, state, self._inconsistent(record, exc, start)
            record.times["set_update_total"] = time.perf_counter() - t0
            if not ok:
                record.status = record.set_status
                record.times["total"] = time.perf_counter() - start
                return None, s.freeze(), record
            t0 = time.perf_counter()
            ok = self._update_estimate(s, x_prev, u_prev, x, record)
            record.times["lms_total"] = time.perf_counter() - t0
            if not ok:
                record.status = record.projection_status
                if record.status is SolveStatus.OPTIMAL:  # pragma: no cover - _update_estimate sets a failure status
                    record.status = SolveStatus.INACCURATE
                record.times["total"] = time.perf_counter() - start
                return None, s.freeze(), record
        record.H_theta, record.h_theta, record.theta_hat = s.H_theta, s.h_theta, s.theta_hat
        H_arg = s.H_theta if self.options.update == "exact" else None
        h_arg = s.h_theta
        if self.options.d_theta > 0:
            h_arg = record.h_theta_stages = self.stage_offsets(s.h_theta)
        sol, checked = self._solve_qp(s, x, h_arg, H_arg, record)
        record.status = sol.status
        record.times["qp_update"] = sol.update_time
        record.times["solver"] = sol.solver_time
        record.infeasible_constraints = sol.infeasible_constraints
        sol = self._verified_qp(s, sol, checked, x, h_arg, H_arg, record)
        u = None
        if sol is not None:
            record.v, record.z, record.alpha, record.Lambda, record.cost = sol.v, sol.z, sol.alpha, sol.Lambda, sol.cost
            u = self.design.K.dot(x) + sol.v[0]
            record.u = u
            s.prev = (x, u)
            if self.options.pe_window is not None:
                s.u_hist.append(float(u[0]))
                del s.u_hist[:-(self.options.pe_window + self.problem.n)]
        s.k += 1
        nxt = s.freeze()
        record.H_theta, record.h_theta, record.theta_hat = nxt.H_theta, nxt.h_theta, nxt.theta_hat
        record.times["total"] = time.perf_counter() - start
        return u, nxt, record
