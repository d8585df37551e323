"""The canonical solve status shared by every backend (design.md, Conventions).

Each backend maps its solver's own codes onto :class:`SolveStatus` with one table
(``STATUS_MAP`` in each backend module, in the style of cvxpy's solver interfaces).
"""

from __future__ import annotations

from enum import Enum


class SolveStatus(str, Enum):
    """Outcome of one optimisation problem."""

    OPTIMAL = "optimal"
    INACCURATE = "optimal_inaccurate"
    INFEASIBLE = "infeasible"
    UNBOUNDED = "unbounded"
    ERROR = "solver_error"
    NOT_RUN = "not_run"

    def __str__(self) -> str:  # pragma: no cover - trivial
        return self.value


#: Statuses whose primal solution may be used (cvxpy calls this SOLUTION_PRESENT).
SOLUTION_PRESENT = frozenset({SolveStatus.OPTIMAL})
