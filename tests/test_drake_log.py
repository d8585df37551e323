"""Drake's log below WARNING is kept off stderr by the command line, and what it said is in the step
record: a Clarabel solve forced to end "InsufficientProgress" (min_terminate_step_length 0.99, every
step it takes is shorter) logs ``INFO:drake:Clarabel returns InsufficientProgress``."""

from __future__ import annotations

import subprocess
import sys
import textwrap

from tests.guards import GUARD_SECONDS

#: A QP that Clarabel solves in a few steps, forced to stop with InsufficientProgress.
_TRIGGER = """
import logging
import numpy as np
from pydrake.solvers import ClarabelSolver, MathematicalProgram, SolverOptions
prog = MathematicalProgram()
x = prog.NewContinuousVariables(3)
prog.AddQuadraticCost(np.eye(3), np.ones(3), x)
prog.AddLinearConstraint(np.ones((1, 3)), [1.0], [2.0], x)
options = SolverOptions()
options.SetOption(ClarabelSolver().solver_id(), "min_terminate_step_length", 0.99)
result = ClarabelSolver().Solve(prog, None, options)
print(result.get_solver_details().status)
logging.getLogger("drake").warning("a warning of Drake")
"""


def _run(prelude: str) -> subprocess.CompletedProcess:
    code = textwrap.dedent(prelude) + _TRIGGER
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=GUARD_SECONDS, check=True)


def test_drakes_info_lines_reach_stderr_without_the_cli_setup():
    """The trigger works: without the command line's set-up, Drake's INFO line is on stderr."""
    proc = _run("")
    assert proc.stdout.strip() == "InsufficientProgress"
    assert "INFO:drake:Clarabel returns InsufficientProgress" in proc.stderr


def test_the_cli_keeps_drakes_info_lines_off_stderr_and_its_warnings_on_it():
    """The ``amcp`` group's set-up (run before every command) drops Drake's INFO lines, also when pydrake
    is imported after it (pydrake sets the logger's level on import); Drake's warnings still show."""
    proc = _run("from amcp_drake.cli.main import main\nmain.callback()\n")
    assert proc.stdout.strip() == "InsufficientProgress"
    assert "INFO:drake" not in proc.stderr, proc.stderr
    assert "a warning of Drake" in proc.stderr


def test_a_failed_clarabel_solve_names_clarabels_status_in_the_step_record(example_spec, example_design):
    """What the INFO line said is in the record: the step's detail names Clarabel's own status."""
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake",
                       solver_options={"min_terminate_step_length": 0.99})
    traj = simulate(ctrl, sc.x0, sc.theta_star, 1, "zero", seed=0)
    record = traj.records[0]
    assert record.status.value == "solver_error"
    assert "Clarabel: InsufficientProgress" in record.detail, record.detail


def test_a_try_rescued_by_a_retry_names_what_clarabel_returned(example_spec, example_design):
    """A tube QP whose first Clarabel try ends InsufficientProgress and whose re-solve succeeds: the applied
    answer's detail names the try that was not solved and Clarabel's status."""
    from amcp_drake.backends.drake_ import DrakeBackend
    from amcp_drake.backends.drake_solver import DrakeSolver
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    class FirstTryStalls(DrakeSolver):
        """Clarabel whose first solve is forced to stop with InsufficientProgress."""

        calls = 0

        def solve(self, prog, extra_options=None):
            self.calls += 1
            if self.calls == 1:
                extra_options = {**(extra_options or {}), "min_terminate_step_length": 0.99}
            return super().solve(prog, extra_options)

    backend = DrakeBackend()
    backend._solver = FirstTryStalls("clarabel", None)
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend=backend)
    traj = simulate(ctrl, sc.x0, sc.theta_star, 1, "zero", seed=0)
    record = traj.records[0]
    assert record.status.value == "optimal"
    assert "tries not solved: 1 x SolutionResult.kSolverSpecificError (Clarabel: InsufficientProgress)" \
        in record.qp_detail, record.qp_detail
