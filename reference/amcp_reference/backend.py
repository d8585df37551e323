"""The cvxpy backend: status map, solve wrapper and :class:`CvxpyBackend`.

Conventions (design.md):

* Clarabel is the default solver (LP, QP and SDP); any installed cvxpy solver can be chosen by
  name, with ``solver_options`` passed to ``Problem.solve``.
* Problems solved repeatedly are DPP problems built once per shape; each call only sets
  ``Parameter.value`` and re-solves (cvxpy then skips canonicalisation).
* A solver failure is data: ``cvxpy.error.SolverError`` never propagates, it becomes
  :attr:`SolveStatus.ERROR`.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

import numpy as np

from amcp_drake.backends.base import ProjectionResult, SetUpdateResult, TubeMPCData
from amcp_drake.backends.projection_form import projection_form
from amcp_drake.model.status import SolveStatus

from .set_update_dual import DualBasesSetUpdate
from .solver_call import STATUS_MAP, SolverCall, all_finite, map_status  # noqa: F401 - re-exported

#: Formulations of the tube MPC QP (20): "plain" = (15a)-(15d) with Λ, "vertex" = (5b) at Θ_k's vertices.
FORMULATIONS = ("plain", "vertex")
#: Methods of the update (9): "auto" = exact by dual bases where that applies, else the LP; "lp" = the LP.
SET_UPDATE_METHODS = ("auto", "lp")

#: Clarabel tolerances of the projection QP (see CvxpyBackend.__init__). 1e-10 as Drake's: in the
#: scaled form (backends.projection_form) the answer is as accurate as at 1e-11 (measured on collapsed
#: Θ_k: same point to 1e-12), while 1e-11 ended "AlmostSolved" on sets of zero width.
CLARABEL_PROJECTION_OPTIONS = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
#: Clarabel tolerances of the support LPs (offline design and the redundancy removal of the exact update
#: (7)), as Drake's CLARABEL_LP_OPTIONS (written here: the reference may not import the Drake backend). At
#: the defaults (1e-8) the support of the thin Θ_k of campaign seed 13 #6 (~1e-6 wide) was up to 2.6e-9
#: off rational arithmetic, more than the 1e-9 by which (7) decides that a row is redundant; at 1e-10,
#: 6.2e-10 (as Drake's).
CLARABEL_LP_OPTIONS = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
#: Number of parametrised problems kept per kind (support LP, LP (9), projection QP); shapes
#: change rarely (redundancy removal, moving window), so a small LRU cache suffices.
CACHE_SIZE = 32


class ProblemCache:
    """LRU cache of parametrised problems keyed by shape; ``build(key)`` makes a missing one."""

    def __init__(self, build: Callable[[tuple], Any], size: int = CACHE_SIZE) -> None:
        self._build = build
        self._size = size
        self._items: OrderedDict[tuple, Any] = OrderedDict()

    def get(self, key: tuple) -> Any:
        if key in self._items:
            self._items.move_to_end(key)
            return self._items[key]
        item = self._build(key)
        self._items[key] = item
        if len(self._items) > self._size:
            self._items.popitem(last=False)
        return item


class CvxpyBackend:
    """All problems of the algorithm with cvxpy (protocol :class:`amcp_drake.backends.base.Backend`).

    Parameters
    ----------
    solver: cvxpy solver name for every problem ("CLARABEL" by default; the gain LMI needs a
        solver with PSD cones: CLARABEL, SCS or MOSEK).
    solver_options: keyword arguments passed to ``Problem.solve`` (e.g. ``{"tol_gap_abs": 1e-10}``).
    formulation: tube MPC QP (20) with the multipliers Λ of (15c)-(15d) ("plain", the reference
        and default) or with (5b) at the vertices of Θ_k ("vertex", same optimum, no Λ:
        ``MPCSolution.Lambda`` is None; see :mod:`amcp_reference.tube_vertex`).
    set_update_method: "auto" (default): the update (9) exactly by dual bases with numpy, the last
        answer's maximisers reused when they still certify it (:mod:`amcp_reference.set_update_dual`),
        the cvxpy LP where neither applies;
        "lp": always the cvxpy LP.
    compiled_qp: with Clarabel and the vertex formulation, solve each step's QP first from cvxpy's
        compiled program by a Clarabel solver kept between steps, without ``Problem.solve``
        (default True; :mod:`amcp_reference.compiled_clarabel`); a step it does not answer
        is solved through ``Problem.solve``. False: always ``Problem.solve``.
    """

    name = "cvxpy"

    def __init__(self, solver: str = "CLARABEL", solver_options: dict | None = None,
                 formulation: str = "plain", set_update_method: str = "auto", compiled_qp: bool = True) -> None:
        from .offline import SupportLP
        from .online import ProjectionQP, SetUpdateLP

        if formulation not in FORMULATIONS:
            raise ValueError(f"formulation {formulation!r} unknown to the cvxpy backend; choose one of {FORMULATIONS}")
        if set_update_method not in SET_UPDATE_METHODS:
            raise ValueError(f"set_update_method {set_update_method!r} unknown to the cvxpy backend; "
                             f"choose one of {SET_UPDATE_METHODS}")
        self.formulation = formulation
        self.set_update_method = set_update_method
        self.compiled_qp = bool(compiled_qp)
        self._call = SolverCall(solver, solver_options)
        # the LP (9) has its own call object (same solver and options) so that profilers can tell
        # its solver time from the tube QP's (amcp_drake.studies.bench_cpu)
        self._call_lp = SolverCall(solver, solver_options)
        # the support LPs at CLARABEL_LP_OPTIONS (the user's options on top), as Drake's
        support_options = dict(CLARABEL_LP_OPTIONS) if solver.upper() == "CLARABEL" else {}
        support_options.update(solver_options or {})
        self._call_support = SolverCall(solver, support_options)
        # The projection QP of (12) at Clarabel's default tolerances was off by up to 4e-5 when θ̃ is
        # just outside the set (measured by the property suite's lockstep test, before the scaled
        # form); as for Drake's LPs, tighten it (a 2-3 variable QP, so the cost is nil).
        tight = dict(CLARABEL_PROJECTION_OPTIONS) if solver.upper() == "CLARABEL" else {}
        tight.update(solver_options or {})
        self._call_projection = SolverCall(solver, tight)
        self.solver_name = self._call.name
        self._support = ProblemCache(SupportLP)
        self._set_update = ProblemCache(SetUpdateLP)
        self._dual_update = DualBasesSetUpdate()
        self._project = ProblemCache(ProjectionQP)

    # -- offline -----------------------------------------------------------------------------
    def robust_gain(self, A_vertices, B_vertices, Q, R, margin, tick=None):
        """Gain LMI for Assumption 8 and (16); see :func:`amcp_reference.offline.robust_gain`.
        ``tick(stage)`` (the design's time budget) is called before the solves."""
        from .offline import robust_gain

        if tick is not None:
            tick("gain LMI (16)")
        return robust_gain(self._call, A_vertices, B_vertices, Q, R, margin)

    def support(self, H, h, directions):
        """max{d·x | H x <= h} per row d: +inf when unbounded, nan when infeasible or failed."""
        H = np.atleast_2d(np.asarray(H, float))
        h = np.asarray(h, float).reshape(-1)
        directions = np.atleast_2d(np.asarray(directions, float))
        if len(directions) == 0 or directions.shape[1] == 0:
            return np.full(len(directions), np.nan)
        if not all_finite(H, h, directions) or H.shape != (len(h), directions.shape[1]):
            return np.full(len(directions), np.nan)
        return self._support.get(H.shape).solve(self._call_support, H, h, directions)

    # -- online ------------------------------------------------------------------------------
    def set_update(self, H_theta, h_prev, H_data, h_data):
        """The update (9). ``set_update_method="auto"`` (default): exact by dual bases
        (:mod:`amcp_reference.set_update_dual`, numpy, certified row by row), the LP where that
        does not apply; ``"lp"``: always the LP in per-row primal form
        (:class:`amcp_reference.online.SetUpdateLP`)."""
        H_theta = np.atleast_2d(np.asarray(H_theta, float))
        H_data = np.atleast_2d(np.asarray(H_data, float))
        h_prev = np.asarray(h_prev, float).reshape(-1)
        h_data = np.asarray(h_data, float).reshape(-1)
        q, p = H_theta.shape
        if (not all_finite(H_theta, H_data, h_prev, h_data) or h_prev.shape != (q,)
                or H_data.shape != (len(h_data), p)):
            return SetUpdateResult(SolveStatus.ERROR, None, None)
        if self.set_update_method == "auto":
            start = time.perf_counter()
            answer = self._dual_update.solve(H_theta, h_prev, H_data, h_data)
            if answer is not None:
                return SetUpdateResult(SolveStatus.OPTIMAL, answer[0], answer[1], time.perf_counter() - start,
                                       points=answer[2], method="dual bases, reused" if answer[3] else "dual bases")
        return self._set_update.get((q, len(h_data), p)).solve(self._call_lp, H_theta, h_prev, H_data, h_data)

    def project(self, point, H, h):
        """argmin ‖θ − point‖² s.t. H θ <= h, the projection of (12)."""
        point = np.asarray(point, float).reshape(-1)
        H = np.atleast_2d(np.asarray(H, float))
        h = np.asarray(h, float).reshape(-1)
        if not all_finite(point, H, h) or H.shape != (len(h), len(point)):
            return ProjectionResult(SolveStatus.ERROR, None)
        # scaled coordinates and flat slabs as equalities, shared with the Drake backend (campaign
        # problem 0-19: unscaled, this QP ended "inaccurate" on a Θ_k collapsed to a point)
        form = projection_form(point, H, h)
        return self._project.get((len(form.b_in), len(form.b_eq), len(point))).solve(self._call_projection, form)

    def tube_mpc(self, data: TubeMPCData):
        """Build the tube MPC QP (20) once; see :class:`amcp_reference.tube_mpc.CvxpyTubeMPC`
        (plain) and :class:`amcp_reference.tube_vertex.CvxpyVertexTubeMPC` (vertex)."""
        # the tube QP is solved once per step with new parameter values and the same structure: Clarabel's
        # solver is kept and updated (SolverCall keep_solver; measured on Example 1, vertex form: 0.6-0.9 ms
        # CPU less per step, v equal to a fresh solver's to 3e-13 over 300 steps)
        call = SolverCall(self._call.name, self._call.options, keep_solver=True)
        if self.formulation == "vertex":
            from .tube_vertex import CvxpyVertexTubeMPC

            return CvxpyVertexTubeMPC(data, call, compiled=self.compiled_qp)
        from .tube_mpc import CvxpyTubeMPC
        from .tube_vertex import CvxpyVertexTubeMPC

        # the plain form's answers are checked against the vertex form's optimum (tube_mpc,
        # _checked_optimal): with Clarabel and the certainty-equivalence cost, on the user's options
        check = None
        if self._call.name == "CLARABEL" and not data.minmax:
            check = CvxpyVertexTubeMPC(data, SolverCall(self._call.name, self._call.options, keep_solver=True),
                                       compiled=self.compiled_qp, plain_fallback=False)
        return CvxpyTubeMPC(data, call, vertex_check=check)
