"""The controller as a Drake System (amcp_drake.systems): ports, state in the Context, a Diagram with
the Drake plant of (1) reproducing amcp.simulate, bad wiring as typed errors, clean stops."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("pydrake")

from pydrake.systems.analysis import Simulator  # noqa: E402

from amcp_drake.certificate.certify import certify  # noqa: E402
from amcp_drake.model.errors import InconsistentDataError, ProblemError  # noqa: E402
from amcp_drake.online.controller import AdaptiveMPC  # noqa: E402
from amcp_drake.online.simulate import disturbance_sequence, simulate  # noqa: E402
from amcp_drake.systems.closed_loop import closed_loop, simulate_in_drake  # noqa: E402
from amcp_drake.systems.controller_system import AdaptiveMPCSystem  # noqa: E402
from amcp_drake.systems.plant import RecordedDisturbance, drake_plant  # noqa: E402

STEPS = 20
#: The Drake plant's affine update (Eigen) and problem.step (numpy) round differently; the runs agree
#: to this (measured: 2.2e-16 in x, 3.3e-16 in h_θ over 20 steps of Example 1).
SAME_RUN = 1e-9


def _max_diff(a, b) -> float:
    return max((float(np.max(np.abs(np.asarray(p, float) - np.asarray(q, float)))) for p, q in zip(a, b)),
               default=0.0)


def _assert_same_run(drake, builtin) -> None:
    assert drake.stop_reason == builtin.stop_reason and len(drake.records) == len(builtin.records)
    assert drake.x.shape == builtin.x.shape and drake.u.shape == builtin.u.shape
    assert _max_diff(drake.x, builtin.x) <= SAME_RUN
    assert _max_diff(drake.u, builtin.u) <= SAME_RUN
    assert _max_diff([r.h_theta for r in drake.records], [r.h_theta for r in builtin.records]) <= SAME_RUN
    assert _max_diff([r.theta_hat for r in drake.records], [r.theta_hat for r in builtin.records]) <= SAME_RUN
    assert [r.status for r in drake.records] == [r.status for r in builtin.records]


@pytest.fixture(scope="module")
def builtin_run(example_spec, example_design):
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, "drake")
    return simulate(ctrl, sc.x0, sc.theta_star, STEPS, "uniform", seed=0)


def test_a_drake_diagram_reproduces_simulate_and_its_certificate(example_spec, example_design, builtin_run):
    """Plant + controller + disturbance run by Drake's Simulator: x, u, h_θ, θ̂ as amcp.simulate's with the
    same disturbances (to SAME_RUN), Drake's logger of x agrees, and the certificate has the same verdict,
    the same claims with the same statuses and margins (to SAME_RUN)."""
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, "drake")
    drake = simulate_in_drake(ctrl, sc.x0, sc.theta_star, STEPS, "uniform", seed=0)
    _assert_same_run(drake, builtin_run)
    assert np.array_equal(drake.w, builtin_run.w)
    assert drake.meta["simulator"] == "drake" and builtin_run.meta.get("simulator", "amcp") == "amcp"
    a, b = certify(drake), certify(builtin_run)
    assert a.verdict == b.verdict == "pass"
    assert [(c.name, c.status) for c in a.claims] == [(c.name, c.status) for c in b.claims]
    for ca, cb in zip(a.claims, b.claims):
        if ca.margin is not None and np.isfinite(ca.margin):
            assert abs(ca.margin - cb.margin) <= SAME_RUN * max(1.0, abs(cb.margin)), ca.name


def _loop(example_spec, example_design, x0, w, period=None):
    system = AdaptiveMPCSystem(example_spec.problem, example_design, period=period)
    loop = closed_loop(system, drake_plant(example_spec.problem, example_spec.scenario.theta_star, period),
                       RecordedDisturbance(w, period))
    simulator = Simulator(loop.diagram)
    loop.plant.GetMyMutableContextFromRoot(simulator.get_mutable_context()).SetDiscreteState(np.asarray(x0, float))
    simulator.Initialize()
    return loop, simulator


def test_two_contexts_of_one_diagram_are_two_independent_runs(example_spec, example_design):
    """Two Simulators of one Diagram (one controller, two Contexts) advanced interleaved, period 0.1 s:
    each run equals simulate from its own x0 with the same disturbances; the logged x is the run's x."""
    pr, sc = example_spec.problem, example_spec.scenario
    steps, period = 8, 0.1
    W = disturbance_sequence(pr, "uniform", steps, 3)
    starts = (np.array([2.0, 3.0]), np.array([-1.5, 2.0]))
    loop, first = _loop(example_spec, example_design, starts[0], W, period)
    second = Simulator(loop.diagram)
    loop.plant.GetMyMutableContextFromRoot(second.get_mutable_context()).SetDiscreteState(starts[1])
    second.Initialize()
    for k in range(1, steps + 1):
        for sim in (first, second):
            sim.AdvanceTo(k * period)
    for x0, sim in zip(starts, (first, second)):
        drake = loop.controller.trajectory(sim.get_context(), theta_star=sc.theta_star, w=W)
        alone = simulate(AdaptiveMPC(pr, example_design, "drake"), x0, sc.theta_star, steps, W)
        _assert_same_run(drake, alone)
        log = loop.x_log.FindLog(sim.get_context())
        assert np.allclose(log.sample_times(), period * np.arange(steps + 1), rtol=0, atol=1e-12)
        assert _max_diff(log.data().T, alone.x) <= SAME_RUN
        assert drake.meta["period"] == period


def test_a_fresh_context_starts_a_fresh_run(example_spec, example_design):
    """The same Simulator reset to a fresh default Context runs the same run again, to the bit."""
    W = disturbance_sequence(example_spec.problem, "uniform", 5, 1)
    loop, sim = _loop(example_spec, example_design, [2.0, 3.0], W)
    sim.AdvanceTo(5.0)
    once = loop.controller.trajectory(sim.get_context())
    sim.reset_context(loop.diagram.CreateDefaultContext())
    assert loop.controller.run(sim.get_context()).steps == 0
    loop.plant.GetMyMutableContextFromRoot(sim.get_mutable_context()).SetDiscreteState(np.array([2.0, 3.0]))
    sim.Initialize()
    sim.AdvanceTo(5.0)
    again = loop.controller.trajectory(sim.get_context())
    assert again.measured and once.measured
    assert np.array_equal(once.x, again.x) and np.array_equal(once.u, again.u)
    assert all(np.array_equal(a.h_theta, b.h_theta) for a, b in zip(once.records, again.records))


def test_the_output_is_a_zero_order_hold_of_the_input_computed_at_the_update(example_spec, example_design,
                                                                             builtin_run):
    """u on [t_k, t_{k+1}) is u_k, computed from x(t_k): evaluated between two updates, it is the
    u_k of simulate."""
    W = np.asarray(builtin_run.w, float)
    loop, sim = _loop(example_spec, example_design, builtin_run.x[0], W, period=0.5)
    for k in range(3):
        sim.AdvanceTo(0.5 * k + 0.25)
        ctx = loop.controller.GetMyContextFromRoot(sim.get_context())
        u = loop.controller.get_u_output_port().Eval(ctx)
        assert np.max(np.abs(u - builtin_run.u[k])) <= SAME_RUN


def test_bad_wiring_is_a_typed_error_naming_the_port(example_spec, example_design):
    """A plant of the wrong size, an unconnected input and a non-finite state: ProblemError naming the
    port and what it received; the Simulator raises it, no other exception."""
    from amcp_drake.model.examples import get_example

    pr = example_spec.problem
    system = AdaptiveMPCSystem(pr, example_design)
    other = get_example("massera2017")  # n = 3
    wrong = drake_plant(other.problem, other.scenario.theta_star)
    with pytest.raises(ProblemError, match=r"input port 'x' of AdaptiveMPCSystem.*size 2.*size 3"):
        closed_loop(system, wrong, RecordedDisturbance(np.zeros((1, 3))))
    plant = drake_plant(pr, example_spec.scenario.theta_star)
    with pytest.raises(ProblemError, match=r"input port 'w'.*size 2.*size 3"):
        closed_loop(AdaptiveMPCSystem(pr, example_design), plant, RecordedDisturbance(np.zeros((1, 3))))
    # nothing connected to x
    ctx = system.CreateDefaultContext()
    with pytest.raises(ProblemError, match="input port 'x'.*nothing connected"):
        system.measured_state(ctx)
    # a non-finite state on the input port, through the Simulator
    lone = AdaptiveMPCSystem(pr, example_design)
    sim = Simulator(lone)
    lone.get_x_input_port().FixValue(sim.get_mutable_context(), np.array([np.nan, 0.0]))
    with pytest.raises(ProblemError, match=r"input port 'x'.*finite state vector of length 2.*nan"):
        sim.AdvanceTo(0.0 + 1.0)


def test_inconsistent_data_stop_the_run_cleanly_and_the_partial_run_is_certifiable(example_spec, example_design):
    """Disturbances 10 times outside W from step 3 on: Θ_(k−1) ∩ Δ_k = ∅ at step 4; the Simulator
    returns early (reached termination) without an exception, the trajectory ends with the recorded
    event, and a second AdvanceTo does not step again. simulate_in_drake raises as simulate does."""
    pr, sc = example_spec.problem, example_spec.scenario
    W = disturbance_sequence(pr, "uniform", 8, 0)
    W[3:] = 10.0 * pr.w_vertices()[0]
    loop, sim = _loop(example_spec, example_design, sc.x0, W)
    status = sim.AdvanceTo(8.0)
    assert status.reason().name == "kReachedTerminationCondition"
    assert "inconsistent data at step 4" in status.FormatMessage()
    run = loop.controller.run(sim.get_context())
    assert run.stopped == "inconsistent data at step 4" and run.steps == 5
    sim.AdvanceTo(12.0)
    assert loop.controller.run(sim.get_context()).steps == 5
    traj = loop.controller.trajectory(sim.get_context())
    assert traj.stop_reason == "inconsistent data at step 4" and traj.measured and traj.steps == 4
    cert = certify(traj)
    [consistency] = [c for c in cert.claims if c.data.get("id") == "data_consistency"]
    assert cert.verdict == "fail" and not consistency.passed and consistency.data["first_failing_step"] == 4
    with pytest.raises(InconsistentDataError) as err:
        simulate_in_drake(AdaptiveMPC(pr, example_design, "drake"), sc.x0, sc.theta_star, 8, W)
    assert err.value.trajectory.stop_reason == "inconsistent data at step 4"


@pytest.mark.slow
def test_the_cli_runs_the_plant_in_drake_on_request(tmp_path):
    """``--simulator drake``: run and certify exit 0 with the trajectory saying Drake ran it; compare in
    independent mode runs both loops in Drake; lockstep refuses it (exit 2, naming the option)."""
    import json

    from click.testing import CliRunner

    from amcp_drake.cli import main
    from amcp_drake.online.simulate import Trajectory

    runner = CliRunner()
    run = runner.invoke(main, ["run", "--steps", "4", "--simulator", "drake", "--save", str(tmp_path / "t.json")])
    assert run.exit_code == 0, run.output
    assert Trajectory.load(tmp_path / "t.json").meta["simulator"] == "drake"
    cert = runner.invoke(main, ["certify", "--steps", "4", "--simulator", "drake", "--out", str(tmp_path / "c")])
    assert cert.exit_code == 0, cert.output
    assert json.loads((tmp_path / "c" / "certificate.json").read_text())["run"]["simulator"] == "drake"
    indep = runner.invoke(main, ["compare", "--mode", "independent", "--steps", "3", "--simulator", "drake",
                                 "--quiet", "--out", str(tmp_path / "cmp.json")])
    assert indep.exit_code == 0, indep.output
    assert json.loads((tmp_path / "cmp.json").read_text())["simulator"] == "drake"
    lock = runner.invoke(main, ["compare", "--steps", "3", "--simulator", "drake", "--out", str(tmp_path / "l.json")])
    assert lock.exit_code == 2 and "--simulator" in lock.output and not (tmp_path / "l.json").exists()


def test_the_how_to_loop_runs_and_certifies(capsys):
    """The Python block of docs/how-to/drake-plant.md runs as written and prints the verdict "pass"."""
    import re
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "how-to" / "drake-plant.md").read_text()
    [block] = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    exec(compile(block, "drake-plant.md", "exec"), {})
    assert capsys.readouterr().out.split() == ["pass"]


def test_the_period_is_the_problems_sample_time_when_it_has_one(example_spec, example_design):
    """Problem.dt = 0.05: the controller's update and the plant's update run every 0.05 s; without dt, 1 s."""
    from dataclasses import replace

    timed = replace(example_spec.problem, dt=0.05)
    assert AdaptiveMPCSystem(timed, example_design).period == 0.05
    assert AdaptiveMPCSystem(example_spec.problem, example_design).period == 1.0
    plant = drake_plant(timed, example_spec.scenario.theta_star)
    affine = plant.GetSubsystemByName("affine")
    assert affine.time_period() == 0.05
    with pytest.raises(ProblemError, match="period"):
        AdaptiveMPCSystem(example_spec.problem, example_design, period=0.0)


def test_bench_runs_the_drake_diagram_beside_amcps_simulator():
    """``amcp bench --only drake``: both loops complete in lockstep, their states agree (the same closed
    loop), and the CPU ratio and the QP solver's ratio are reported (not asserted: CPU time varies)."""
    from amcp_drake.studies.bench import BenchSettings, format_summary, run_benchmarks

    result = run_benchmarks(BenchSettings.quick_settings(only="drake", steps=4))
    loop = result["drake_loop"]
    assert result["example"] is None and loop["status"] == "completed" and loop["max_abs_dx"] <= SAME_RUN
    assert loop["builtin_cpu_ms"]["n"] == loop["drake_cpu_ms"]["n"] == 3
    assert loop["cpu_ratio"] > 0 and loop["qp_solver_ratio"] > 0 and loop["met"] in (True, False)
    assert len(format_summary(result).splitlines()) == 1   # the summary has the Drake loop's line and no other
