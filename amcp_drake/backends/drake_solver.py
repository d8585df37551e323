"""One Drake solver with its options and the status map of Drake's results (the Drake backend's
counterpart of ``amcp_reference.solver_call``). Its own module so that every Drake program
(``drake_``, ``drake_tube``, ``drake_vertex``) imports it without importing each other."""

from __future__ import annotations

import time
from collections import Counter

import numpy as np
from pydrake.solvers import (
    ClarabelSolver,
    ClpSolver,
    CsdpSolver,
    IpoptSolver,
    MathematicalProgram,
    OsqpSolver,
    ScsSolver,
    SolutionResult,
    SolverOptions,
)

from amcp_drake.model.arrays import all_finite
from amcp_drake.model.status import SolveStatus

#: Drake's SolutionResult -> canonical status.
STATUS_MAP = {
    SolutionResult.kSolutionFound: SolveStatus.OPTIMAL,
    SolutionResult.kInfeasibleConstraints: SolveStatus.INFEASIBLE,
    SolutionResult.kInfeasibleOrUnbounded: SolveStatus.INFEASIBLE,
    SolutionResult.kUnbounded: SolveStatus.UNBOUNDED,
    SolutionResult.kDualInfeasible: SolveStatus.UNBOUNDED,
    SolutionResult.kIterationLimit: SolveStatus.INACCURATE,
    SolutionResult.kSolverSpecificError: SolveStatus.ERROR,
    SolutionResult.kInvalidInput: SolveStatus.ERROR,
    SolutionResult.kSolutionResultNotSet: SolveStatus.ERROR,
}

#: Violation above which a constraint is named in the diagnostics of a failed QP (20): well
#: above Clarabel's feasibility tolerance (1e-8), so round-off is not reported.
INFEASIBLE_NAME_TOL = 1e-6

#: Clarabel statuses (solver details) that Drake reports as success but that are not exact.
_CLARABEL_INACCURATE = {"AlmostSolved", "AlmostPrimalInfeasible", "AlmostDualInfeasible"}

SOLVERS = {
    "clarabel": ClarabelSolver,
    "osqp": OsqpSolver,
    "scs": ScsSolver,
    "clp": ClpSolver,
    "csdp": CsdpSolver,
    "ipopt": IpoptSolver,
}


def finite_or_raise(name: str, *arrays: np.ndarray) -> None:
    for arr in arrays:
        if not all_finite(arr):
            raise ValueError(f"{name}: non-finite coefficient passed to Drake (it would abort the interpreter)")


class DrakeSolver:
    """One Drake solver with options; ``status`` maps a result to the canonical status."""

    def __init__(self, name: str, options: dict | None) -> None:
        key = name.lower()
        if key not in SOLVERS:
            raise ValueError(f"solver {name!r} unknown to the Drake backend; choose one of {sorted(SOLVERS)}")
        self.name = key
        self.solver = SOLVERS[key]()
        if not self.solver.available() or not self.solver.enabled():
            raise ValueError(f"Drake solver {name!r} is not available or not enabled (license?)")
        self.option_values = dict(options or {})
        self.options = self._solver_options(self.option_values)

    def _solver_options(self, values: dict) -> SolverOptions:
        opts = SolverOptions()
        for opt, value in values.items():
            opts.SetOption(self.solver.solver_id(), opt, value)
        return opts

    def solve(self, prog: MathematicalProgram, extra_options: dict | None = None):
        """Solve ``prog``; ``extra_options`` override this solver's options for this call only."""
        options = self.options if not extra_options else self._solver_options({**self.option_values, **extra_options})
        start = time.perf_counter()
        result = self.solver.Solve(prog, None, options)
        return result, time.perf_counter() - start

    def describe(self, result) -> str:
        """Drake's result code of ``result`` and, for Clarabel when it did not end "Solved", Clarabel's own
        status (e.g. ``SolutionResult.kSolverSpecificError (Clarabel: NumericalError)``): what Drake
        otherwise says only in an INFO line of its log (:mod:`.drake_log`)."""
        text = str(result.get_solution_result())
        if self.name == "clarabel":
            own = getattr(result.get_solver_details(), "status", None)
            if own and own != "Solved":
                text += f" (Clarabel: {own})"
        return text

    def status(self, result) -> SolveStatus:
        # is_success() is Drake's solution_result == kSolutionFound (STATUS_MAP: OPTIMAL), 0.2 µs against
        # ~1 µs for hashing the pybind11 enum into STATUS_MAP (called once per QP)
        if not result.is_success():
            return STATUS_MAP.get(result.get_solution_result(), SolveStatus.ERROR)
        if self.name == "clarabel":
            details = result.get_solver_details()
            if getattr(details, "status", "Solved") in _CLARABEL_INACCURATE:
                return SolveStatus.INACCURATE
        return SolveStatus.OPTIMAL


def tries_note(described: list[str]) -> str:
    """The solves of one problem that did not end "optimal", for ``MPCSolution.detail``: each distinct
    :meth:`DrakeSolver.describe` text with its count (e.g. ``tries not solved: 2 x
    SolutionResult.kSolverSpecificError (Clarabel: NumericalError)``); "" when there were none."""
    if not described:
        return ""
    counts = Counter(described)
    return "tries not solved: " + ", ".join(f"{n} x {text}" for text, n in counts.items())


def infeasible_constraint_names(result, prog: MathematicalProgram, tol: float = INFEASIBLE_NAME_TOL) -> tuple[str, ...]:
    """Descriptions of the constraints violated by more than ``tol`` at the solver's last iterate
    (Drake's ``GetInfeasibleConstraintNames``): a diagnostic for a step that failed. A failed
    report returns () and must never hide the status of the step."""
    try:
        return tuple(result.GetInfeasibleConstraintNames(prog, tol))
    except Exception:  # noqa: BLE001 - diagnostics only
        return ()


__all__ = ["SOLVERS", "STATUS_MAP", "DrakeSolver", "finite_or_raise", "infeasible_constraint_names", "tries_note"]
