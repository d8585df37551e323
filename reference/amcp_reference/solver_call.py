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


def all_finite(*arrays: Any) -> bool:
    """True when every entry of every array is finite."""
    return all(np.all(np.isfinite(np.asarray(a, float))) for a in arrays)


class SolverCall:
    """A cvxpy solver name plus options; :meth:`solve` never raises ``SolverError``."""

    def __init__(self, solver: str, options: dict | None, keep_solver: bool = False) -> None:
        """``keep_solver``: solve with cvxpy's ``warm_start=True``, which for Clarabel keeps the solver
        of the last solve of the same Problem and passes the new data to its ``update`` (the KKT
        structure and its symbolic factorisation are reused; Clarabel has no iterate warm start).
        cvxpy builds a new solver when the update is refused (another sparsity pattern, a setting
        that cannot change)."""
        name = str(solver).upper()
        if name not in cp.installed_solvers():
            raise ValueError(f"solver {solver!r} is not installed for cvxpy; installed: {cp.installed_solvers()}")
        self.name = name
        self.options = dict(options or {})
        self.keep_solver = keep_solver

    def solve(self, problem: cp.Problem, extra_options: dict | None = None) -> tuple[SolveStatus, float, str]:
        """Solve ``problem``; return (canonical status, solver time in s, detail). ``extra_options``
        override this call's options for this solve only (e.g. a rung of the Clarabel retry ladder).

        The solver time is ``problem.solver_stats.solve_time`` when the solver reports it, else
        the wall time of ``Problem.solve`` (which then includes cvxpy's parameter application).
        """
        start = time.perf_counter()
        try:
            with warnings.catch_warnings():
                # cvxpy warns "Solution may be inaccurate"; the status already says so
                warnings.filterwarnings("ignore", message="Solution may be inaccurate", category=UserWarning)
                problem.solve(solver=self.name, warm_start=self.keep_solver,
                              **(self.options if not extra_options else {**self.options, **extra_options}))
        except cp.error.SolverError as exc:
            return SolveStatus.ERROR, time.perf_counter() - start, f"SolverError: {exc}"
        wall = time.perf_counter() - start
        stats = problem.solver_stats
        elapsed = stats.solve_time if stats is not None and stats.solve_time is not None else wall
        return map_status(problem.status), float(elapsed), str(problem.status)


__all__ = ["STATUS_MAP", "SolverCall", "all_finite", "map_status"]
