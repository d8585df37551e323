"""AdaptiveMPCSystem(on_inconsistent=...) on Example 1 in a Drake Diagram, with one disturbance 10x the size
of W at step KICK (the data then contradict Θ and W at step KICK + 1): "stop" ends the run there, "reset"
goes on from Θ_k = Θ, and the certificate finds the contradiction at exactly the steps the system reports.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pydrake")

from pydrake.systems.analysis import Simulator, SimulatorStatus  # noqa: E402

from amcp_drake.certificate.certify import certify  # noqa: E402
from amcp_drake.model.errors import ProblemError  # noqa: E402
from amcp_drake.systems.closed_loop import closed_loop  # noqa: E402
from amcp_drake.systems.controller_system import AdaptiveMPCSystem  # noqa: E402
from amcp_drake.systems.plant import RecordedDisturbance, drake_plant  # noqa: E402

STEPS, KICK = 12, 4


def kicked_run(spec, offline, on_inconsistent: str):
    """The Diagram of Example 1 with w_k = 0 but w_KICK = 10x the size of W along x_1."""
    problem, sc = spec.problem, spec.scenario
    W = np.zeros((STEPS, problem.n))
    W[KICK, 0] = 10 * float(np.max(np.abs(problem.w_vertices())))
    system = AdaptiveMPCSystem(problem, offline, on_inconsistent=on_inconsistent)
    loop = closed_loop(system, drake_plant(problem, sc.theta_star), RecordedDisturbance(W))
    simulator = Simulator(loop.diagram)
    loop.plant.GetMyMutableContextFromRoot(simulator.get_mutable_context()).SetDiscreteState(np.asarray(sc.x0, float))
    simulator.Initialize()
    status = simulator.AdvanceTo(STEPS * system.period)
    root = simulator.get_context()
    return system, root, status, system.trajectory(root, theta_star=sc.theta_star, w=W)


def test_stop_ends_the_run_at_the_contradicting_step(example_spec, example_design):
    system, root, status, traj = kicked_run(example_spec, example_design, "stop")
    assert status.reason() == SimulatorStatus.ReturnReason.kReachedTerminationCondition
    assert traj.stop_reason == f"inconsistent data at step {KICK + 1}" and traj.steps == KICK + 1
    assert system.run(root).resets == ()
    cert = certify(traj)
    assert cert.claim("data_consistency").data["failing_steps"] == [KICK + 1]
    assert cert.claim("w_in_W").status == "fail"


def test_reset_goes_on_from_theta_and_the_certificate_finds_the_same_step(example_spec, example_design):
    system, root, status, traj = kicked_run(example_spec, example_design, "reset")
    assert status.reason() == SimulatorStatus.ReturnReason.kReachedBoundaryTime
    assert traj.steps == STEPS and traj.stop_reason == "completed"
    assert system.run(root).resets == (KICK + 1,) and traj.meta["theta_resets"] == [KICK + 1]
    reset = traj.records[KICK + 1]
    assert np.array_equal(reset.h_theta, example_design.h_theta0)
    assert np.array_equal(reset.theta_hat, traj.records[KICK].theta_hat)  # θ̂ kept, no update from the dropped data
    assert np.any(traj.records[-1].h_theta < reset.h_theta - 1e-6)  # Θ_k shrinks again after the reset
    cert = certify(traj)
    assert cert.claim("data_consistency").data["failing_steps"] == [KICK + 1]
    assert cert.claim("Theta_k_nested").status == "fail"
    assert cert.claim("state_input_constraints").status == "pass"


def test_on_inconsistent_must_be_stop_or_reset(example_spec, example_design):
    with pytest.raises(ProblemError, match="on_inconsistent"):
        AdaptiveMPCSystem(example_spec.problem, example_design, on_inconsistent="continue")
