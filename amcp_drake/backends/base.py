"""The backend protocol: the only place where optimisation problems are formulated.

A backend formulates and solves, with its own modelling layer:

* offline (docs/explanation/paper.md §4-§6): the robust gain LMI for (K, P) of Assumption 8 / eq. (16), and batched
  support-function LPs (used for w̄, f̄, h̄^k, the minimal-RPI template of X0, the terminal-set
  recursion of docs/explanation/paper.md §5 and redundancy removal);
* online: the fixed-complexity set-membership LP (9) (also used, with more data rows, for the
  moving window of Remark 4), the projection QP of the LMS update (12), and the tube MPC QP (20)
  with constraints (15a)-(15d) and the certainty-equivalence cost (17)-(18).

Everything else (problem data, design orchestration, controller loop, simulator, certificates)
is written once and shared. Two implementations: ``amcp_drake.backends.drake_`` (Drake
``MathematicalProgram``) and ``amcp_reference.backend`` (cvxpy).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from amcp_drake.model.status import SolveStatus


@dataclass(frozen=True, eq=False)
class GainResult:
    """Robust gain K (m, n) and terminal weight P (n, n) from the LMI; None unless status is optimal."""

    status: SolveStatus
    K: np.ndarray | None
    P: np.ndarray | None


@dataclass(frozen=True, eq=False)
class SetUpdateResult:
    """LP (9): new offsets h (q,) and multipliers Λ (q, q + rows of data); status UNBOUNDED or
    INFEASIBLE means Θ_{k-1} ∩ Δ_k is empty. ``points`` (q, p), optional: a maximiser of row i's
    support LP per row (the primal certificate that h is tight; checked by amcp_drake.online.answer_checks
    when given)."""

    status: SolveStatus
    h: np.ndarray | None
    Lambda: np.ndarray | None
    solve_time: float = 0.0
    points: np.ndarray | None = None
    #: "lp" (an LP solver), "vertices" (Drake: primal basis enumeration with its dual certificate) or
    #: "dual bases" / "dual bases, reused" (cvxpy: amcp_reference.set_update_dual)
    method: str = "lp"


@dataclass(frozen=True, eq=False)
class ProjectionResult:
    """QP of (12): the Euclidean projection of a point onto {H θ <= h}."""

    status: SolveStatus
    theta: np.ndarray | None
    solve_time: float = 0.0


@dataclass(frozen=True, eq=False)
class TubeMPCData:
    """Fixed data of the tube MPC QP (20), set once per controller.

    * problem matrices: ``A0 B0 A B F G Q R N`` as in :class:`~amcp_drake.model.problem.Problem`;
    * ``K`` (m, n), ``P`` (n, n): Assumption 8 and (16);
    * ``H_x`` (u, n): X0 = {x | H_x x <= 1}; ``X0_vertices`` (v, n): x^j of (14);
    * ``w_bar`` (u,), ``f_bar`` (c,): offline constants of Proposition 9;
    * ``H_T`` (r, n), ``h_T`` (r,): terminal set X_f = {(z, α) | H_T z + h_T α <= 1, α >= 0};
    * ``H_theta`` (q, p): the shape of Θ_k in (15c)-(15d); constant while q is constant;
    * ``h_theta0`` (q,) or None: Θ0 = {H_θ θ <= h_θ0} ⊇ Θ_k for every k (the design's Θ0);
    * ``cost``: ``"certainty_equivalence"`` (17)-(18) or ``"minmax"`` (19) in epigraph form
      (Remark 13; plain formulation only).
    """

    # The problem's and the offline design's fields that the QP needs, named as in Problem and
    # offline.result.OfflineDesign: a backend sits below the offline layer and may not import it, so the
    # protocol lists them itself (filled in by online.controller.AdaptiveMPC).
    A0: np.ndarray
    B0: np.ndarray
    A: np.ndarray
    B: np.ndarray
    F: np.ndarray
    G: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    N: int
    K: np.ndarray
    P: np.ndarray
    H_x: np.ndarray
    X0_vertices: np.ndarray
    w_bar: np.ndarray
    f_bar: np.ndarray
    H_T: np.ndarray
    h_T: np.ndarray
    H_theta: np.ndarray
    cost: str = "certainty_equivalence"
    #: offsets of Θ0 = {H_θ θ <= h_θ0} ⊇ every Θ_k (the design's); optional: with it the Drake plain
    #: form leaves out the rows of (15c) implied by others on Θ0 (backends/dominated_rows.py)
    h_theta0: np.ndarray | None = None

    @property
    def minmax(self) -> bool:
        """Whether the QP's cost is the min-max cost (19) (else (17)-(18) with θ̂_k)."""
        return self.cost == "minmax"


@dataclass(frozen=True, eq=False)
class Attempt:
    """One solve of one problem of a step, as data: ``problem`` (``"tube_qp"``, ``"set_update"``,
    ``"pe_candidate"``, ...: :data:`amcp_drake.online.answers.PROBLEMS`), ``rung`` (the step of the
    answer policy that solved it: ``"first"``, ``"refine"``, ``"other_formulation"``, ...:
    :mod:`amcp_drake.online.policy`), ``options`` (what the rung changed, as (name, value) pairs, e.g.
    ``(("formulation", "vertex"),)``), ``status`` (the solver's), ``check`` (the name of the first
    answer check that failed, "" when none failed or none ran), ``accepted`` (this answer was used),
    ``solver_cpu`` (the solver's time in s), ``failures`` (the failed checks themselves, for the
    step's notes), ``detail`` (the solver's own account, ``MPCSolution.detail``) and ``inner`` (the
    backend's own re-solves within this solve, ``MPCSolution.attempts``)."""

    problem: str
    rung: str
    status: SolveStatus
    check: str = ""
    accepted: bool = False
    options: tuple[tuple[str, str], ...] = ()
    solver_cpu: float = 0.0
    failures: tuple = ()
    detail: str = ""
    #: the backend's own re-solves inside this solve (``MPCSolution.attempts``)
    inner: tuple[Attempt, ...] = ()

    def option(self, name: str, default: str = "") -> str:
        """The value of option ``name`` of this attempt (``default`` when the rung did not set it)."""
        return next((v for k, v in self.options if k == name), default)


@dataclass(frozen=True, eq=False)
class MPCSolution:
    """Solution of (20): ``v`` (N, m), ``z`` (N+1, n), ``alpha`` (N+1,), ``Lambda`` (N, v, u, q),
    ``cost`` = J_N of (17) (including the constant term), times in seconds. Arrays are None when
    no solution is present (see :data:`~amcp_drake.model.status.SOLUTION_PRESENT`). ``Lambda`` is also
    None for the vertex form of (5b) (``formulation="vertex"``), which has no multipliers."""

    status: SolveStatus
    v: np.ndarray | None
    z: np.ndarray | None
    alpha: np.ndarray | None
    Lambda: np.ndarray | None
    cost: float | None
    solver_time: float = 0.0
    update_time: float = 0.0
    infeasible_constraints: tuple[str, ...] = field(default_factory=tuple)
    detail: str = ""
    #: the backend's own re-solves of this answer after its first solve, in order (the retry ladder, the
    #: program with every row of (15c), the vertex form's plain fallback, ...): :class:`Attempt` s with
    #: the answer's status, which ``detail`` describes in words
    attempts: tuple[Attempt, ...] = ()


@runtime_checkable
class TubeMPCSolver(Protocol):
    """A tube MPC QP (20) built once; ``solve`` updates coefficients and solves. ``formulation``: the
    form of (20) it solves ("plain": (15) with the multipliers Λ; "vertex": (5b) at the vertices of Θ_k);
    ``REFINES``: ``solve`` takes ``refine=True`` (Clarabel's iterative refinement from the first solve,
    the controller's re-solve of an answer that failed its checks)."""

    formulation: str
    REFINES: bool

    def solve(self, x: np.ndarray, h_theta: np.ndarray, theta_hat: np.ndarray,
              H_theta: np.ndarray | None = None) -> MPCSolution:
        """Solve (20) for the measured state x_k, Θ_k = {H_θ θ <= h_theta} and θ̂_k.

        ``H_theta`` is given only when the shape of Θ_k differs from ``TubeMPCData.H_theta``
        (exact update (7)); the solver may then rebuild.
        """
        ...


@runtime_checkable
class Backend(Protocol):
    """One implementation of every optimisation problem of the algorithm; ``formulation``: that of
    the programs :meth:`tube_mpc` builds ("plain" or "vertex")."""

    name: str
    formulation: str

    def robust_gain(self, A_vertices: np.ndarray, B_vertices: np.ndarray, Q: np.ndarray, R: np.ndarray,
                    margin: float, tick=None) -> GainResult:
        """LMI for K, P with A_cl(θ^k)ᵀ P A_cl(θ^k) + Q + KᵀRK ⪯ P at every vertex, eq. (16). ``tick(stage)``
        (optional): the design's time budget, called between solves (it raises to stop the design)."""
        ...

    def support(self, H: np.ndarray, h: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """max{d·x | H x <= h} for each row d of ``directions``: +inf when unbounded, nan when
        infeasible or failed."""
        ...

    def set_update(self, H_theta: np.ndarray, h_prev: np.ndarray, H_data: np.ndarray,
                   h_data: np.ndarray) -> SetUpdateResult:
        """LP (9) with H̃ = [H_θ; H_data], h̃ = [h_prev; h_data]."""
        ...

    def project(self, point: np.ndarray, H: np.ndarray, h: np.ndarray) -> ProjectionResult:
        """argmin{‖θ − point‖ | H θ <= h}, the projection of (12)."""
        ...

    def tube_mpc(self, data: TubeMPCData) -> TubeMPCSolver:
        """Build the QP (20) once for ``data``."""
        ...


def backend_attempts(rungs, status: SolveStatus, problem: str = "tube_qp") -> tuple[Attempt, ...]:
    """``MPCSolution.attempts`` of the backend's re-solves ``rungs`` ((rung, options) pairs, e.g. from
    :func:`amcp_drake.backends.clarabel_retry.solve_with_retries`) of an answer of status ``status``."""
    return tuple(Attempt(problem, rung, status, options=options) for rung, options in rungs)
