"""A cvxpy solver name with its options (:class:`SolverCall`) and the status map of cvxpy's status
strings: shared by every cvxpy problem of the backend (``backend``, ``online``, ``offline``,
``tube_mpc``, ``tube_vertex``), which import it without importing each other.
"""

from __future__ import annotations

import time
import warnings
from typing import Any

import cvxpy as cp
import cvxpy.settings as cps
import numpy as np

from amcp_drake.backends.clarabel_retry import RETRIED
from amcp_drake.model.status import SolveStatus

#: cvxpy status string -> canonical status (cvxpy.settings). Inaccurate certificates of
#: infeasibility / unboundedness count as such (no solution is returned either way);
#: ``user_limit`` (iteration or time limit) is reported as inaccurate, as Drake's kIterationLimit.
STATUS_MAP: dict[str, SolveStatus] = {
    cps.OPTIMAL: SolveStatus.OPTIMAL,
    cps.OPTIMAL_INACCURATE: SolveStatus.INACCURATE,
    cps.INFEASIBLE: SolveStatus.INFEASIBLE,
    cps.INFEASIBLE_INACCURATE: SolveStatus.INFEASIBLE,
    cps.UNBOUNDED: SolveStatus.UNBOUNDED,
    cps.UNBOUNDED_INACCURATE: SolveStatus.UNBOUNDED,
    cps.INFEASIBLE_OR_UNBOUNDED: SolveStatus.INFEASIBLE,
    cps.USER_LIMIT: SolveStatus.INACCURATE,
    cps.SOLVER_ERROR: SolveStatus.ERROR,
}

def map_status(status: str | None) -> SolveStatus:
    """Canonical status of a cvxpy status string (unknown or None -> ERROR)."""
    return STATUS_MAP.get(status, SolveStatus.ERROR) if status is not None else SolveStatus.ERROR


def is_solver_panic(exc: BaseException) -> bool:
    """True for a Rust panic raised inside a solver (Clarabel's Python wheel is Rust, bound by pyo3):
    it reaches Python as ``pyo3_runtime.PanicException``, a ``BaseException`` that is not an
    ``Exception`` and not cvxpy's ``SolverError``. Found on the gain LMI of an unstabilisable vertex
    (x+ = 1.5 x + 0·u, margin 1e-9): Clarabel panicked with "Eigval error: Eigen(1)" in a PSD cone's
    eigendecomposition; a solver failure is a status, never an exception (the class is matched by
    name: ``pyo3_runtime`` is not an importable module)."""
    return type(exc).__module__ == "pyo3_runtime" and type(exc).__name__ == "PanicException"


def all_finite(*arrays: Any) -> bool:
    """True when every entry of every array is finite."""
    return all(np.all(np.isfinite(np.asarray(a, float))) for a in arrays)


def clarabel_defaults() -> dict[str, Any]:
    """Every setting of ``clarabel.DefaultSettings()`` with its default value, except ``verbose``
    (cvxpy sets it from ``Problem.solve(verbose=...)``).

    Why: with ``warm_start=True`` cvxpy's Clarabel interface updates the kept solver with the call's
    options applied on top of the solver's *current* settings, so an option given once (a rung of
    the retry ladder, ``NO_REFINEMENT``) stayed in force for every later solve of the same problem
    (found on massera2017 with cvxpy and θ* = −1: after one full retry ladder, later steps ran
    without equilibration or refinement at max_step_fraction 0.5 and stalled "AlmostSolved" where a
    fresh solver was "Solved"; tests/test_cvxpy_backend.py). Passing every setting restores the
    defaults first. Read from the installed Clarabel, so a new setting is included.
    """
    import clarabel

    defaults = clarabel.DefaultSettings()
    return {name: getattr(defaults, name) for name in dir(defaults)
            if not name.startswith("_") and name != "verbose" and not callable(getattr(defaults, name))}


class SolverCall:
    """A cvxpy solver name plus options; :meth:`solve` never raises ``SolverError`` or a solver's panic."""

    def __init__(self, solver: str, options: dict | None, keep_solver: bool = False) -> None:
        """``keep_solver``: solve with cvxpy's ``warm_start=True``, which for Clarabel keeps the solver
        of the last solve of the same Problem and passes the new data to its ``update`` (the KKT
        structure and its symbolic factorisation are reused; Clarabel has no iterate warm start).
        cvxpy builds a new solver when the update is refused (another sparsity pattern, a setting
        that cannot change). cvxpy applies a call's options on top of the kept solver's settings, so
        every solve of a kept Clarabel solver passes all of Clarabel's settings (its defaults, then
        ``options``, then the call's ``extra_options``): the options of one solve never stay in
        force for the next (see :func:`clarabel_defaults`)."""
        name = str(solver).upper()
        if name not in cp.installed_solvers():
            raise ValueError(f"solver {solver!r} is not installed for cvxpy; installed: {cp.installed_solvers()}")
        self.name = name
        self.options = dict(options or {})
        self.keep_solver = keep_solver
        self._base = {**clarabel_defaults(), **self.options} if keep_solver and name == "CLARABEL" else self.options
        #: True after a solve of a kept solver that ended without an answer (inaccurate, solver error):
        #: the next solve builds a new solver (cvxpy warm_start=False), which is kept from then on
        self._rebuild = False

    @property
    def settings(self) -> dict:
        """The options every solve passes (for a kept Clarabel solver: all of Clarabel's settings,
        its defaults under this call's options)."""
        return dict(self._base)

    def solve(self, problem: cp.Problem, extra_options: dict | None = None) -> tuple[SolveStatus, float, str]:
        """Solve ``problem``; return (canonical status, solver time in s, detail); cvxpy's SolverError
        and a solver's panic (:func:`is_solver_panic`) are the status ERROR. ``extra_options``
        override this call's options for this solve only (e.g. a rung of the Clarabel retry ladder).

        The solver time is ``problem.solver_stats.solve_time`` when the solver reports it, else
        the wall time of ``Problem.solve`` (which then includes cvxpy's parameter application).
        """
        start = time.perf_counter()
        warm, self._rebuild = self.keep_solver and not self._rebuild, False
        try:
            with warnings.catch_warnings():
                # cvxpy warns "Solution may be inaccurate"; the status already says so
                warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)
                problem.solve(solver=self.name, warm_start=warm,
                              **(self._base if not extra_options else {**self._base, **extra_options}))
        except cp.error.SolverError as exc:
            self._rebuild = self.keep_solver
            return SolveStatus.ERROR, time.perf_counter() - start, f"SolverError: {exc}"
        except BaseException as exc:  # a solver's Rust panic is a BaseException, not an Exception
            if not is_solver_panic(exc):
                raise
            self._rebuild = self.keep_solver
            return SolveStatus.ERROR, time.perf_counter() - start, f"PanicException: {exc}"
        wall = time.perf_counter() - start
        stats = problem.solver_stats
        elapsed = stats.solve_time if stats is not None and stats.solve_time is not None else wall
        status = map_status(problem.status)
        # a kept solver keeps the equilibration and state of its first setup through cvxpy's update;
        # when it gives no answer, the next solve starts from a new one (found on massera2017: a solver
        # updated from the previous step stalled "AlmostSolved" where a new one solved the step)
        self._rebuild = self.keep_solver and status in RETRIED
        return status, float(elapsed), str(problem.status)


__all__ = ["STATUS_MAP", "SolverCall", "all_finite", "clarabel_defaults", "is_solver_panic", "map_status"]
