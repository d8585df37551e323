"""CPU time per part of one controller step: where a full step of the online loop goes.

``StepRecord.times`` holds wall times (``perf_counter``); on a shared machine wall time is 2–6×
CPU time under load, so the performance targets are CPU time of the calling thread
(``time.thread_time``: the solvers used here run in this thread, Clarabel and DAQP single-threaded).

:class:`CpuProfile` wraps, on one controller instance only (nothing global is patched):

* ``set_update``: the whole set-membership update (Δ_k, the update (9) and its checks);
* ``lp_solver``: the LP/QP solver calls of (9) and of the projection (12) (none for (9) when the
  exact vertex update of :mod:`amcp_drake.backends.set_update_vertices` answers);
* ``lms``: the projected LMS update (12);
* ``qp``: the whole tube QP (20) (coefficient updates, vertices of Θ_k, solver, reading back);
* ``qp_solver``: the QP solver calls alone (Drake: ``Solve``, which includes Drake's translation of
  the program into the solver's format; cvxpy: ``Problem.solve``, which includes cvxpy's parameter
  application, and the compiled route of the vertex form, ``_solve_compiled``, which includes the
  evaluation of cvxpy's compiled data and reading the variables back, also inside the cvxpy plain
  form's optimality check by its vertex form; fast path: the DAQP call and its checks' fallback solves);
* ``total``: the whole ``AdaptiveMPC.step``;
* ``outside_solvers`` = total − lp_solver − qp_solver: everything that is not a solver call.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

#: Parts reported per step (ms of CPU time).
PARTS = ("set_update", "lms", "lp_solver", "qp", "qp_solver", "total", "outside_solvers")


class CpuProfile:
    """Thread CPU time per part of each step of one controller (see the module docstring)."""

    def __init__(self, ctrl) -> None:
        self.ctrl = ctrl
        self.current: dict[str, float] = {}
        self._wrap(ctrl, "_update_set", "set_update")
        self._wrap(ctrl, "_update_estimate", "lms")
        self._wrap(ctrl, "_solve_qp", "qp")
        for obj in _solver_objects(ctrl.backend, "lp"):
            self._wrap(obj, "solve", "lp_solver")
        for obj in _solver_objects(ctrl.mpc, "qp"):
            self._wrap(obj, "solve", "qp_solver")
        if hasattr(ctrl.mpc, "_solve_compiled"):  # the cvxpy vertex form's compiled route
            self._wrap(ctrl.mpc, "_solve_compiled", "qp_solver")
        check = getattr(ctrl.mpc, "_vertex_check", None)  # the cvxpy plain form's optimality check
        if check is not None:
            for obj in _solver_objects(check, "qp"):
                self._wrap(obj, "solve", "qp_solver")
            self._wrap(check, "_solve_compiled", "qp_solver")

    def _wrap(self, obj: Any, method: str, part: str) -> None:
        inner: Callable = getattr(obj, method)
        current = self.current

        def timed(*args, **kwargs):
            start = time.thread_time()
            try:
                return inner(*args, **kwargs)
            finally:
                current[part] = current.get(part, 0.0) + time.thread_time() - start

        setattr(obj, method, timed)

    def step(self, x):
        """``ctrl.step(x)``; returns (u, record, {part: CPU seconds}) for this step."""
        self.current.clear()
        start = time.thread_time()
        u, record = self.ctrl.step(x)
        parts = {p: self.current.get(p, 0.0) for p in PARTS}
        parts["total"] = time.thread_time() - start
        parts["outside_solvers"] = parts["total"] - parts["lp_solver"] - parts["qp_solver"]
        return u, record, parts


def _solver_objects(owner: Any, kind: str) -> list[Any]:
    """The solver-call objects of a backend (``kind="lp"``: the solvers of (9) and (12)) or of
    a tube QP (``kind="qp"``), found by the attribute names the backends use; de-duplicated."""
    names = {"lp": ("_lp", "_lp_fallback", "_call_lp", "_call_projection"),
             "qp": ("_solver", "_plain_solver", "_call", "_plain_call", "_fast")}[kind]
    seen: list[Any] = []
    for name in names:
        obj = getattr(owner, name, None)
        if obj is not None and hasattr(obj, "solve") and all(obj is not s for s in seen):
            seen.append(obj)
    return seen


__all__ = ["PARTS", "CpuProfile"]
