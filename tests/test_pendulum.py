"""The nonlinear plant worked example (amcp_drake/systems/pendulum.py): an inverted pendulum as a discrete
Drake ``MultibodyPlant``, its model affine in mass and damping from Drake's ``Linearize``, W from the
sampled linearisation error, and the closed loop in Drake's Simulator certified as a measured run.

References are independent of the code under test: the plant's one-step map and its linearisation are
compared with the closed-form discrete update of a point-mass pendulum (semi-implicit Euler with the hinge
damping implicit, as Drake's discrete solver integrates a single joint without contact).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydrake.systems.analysis import SimulatorStatus

from amcp_drake.certificate.certify import certify
from amcp_drake.model.errors import ProblemError
from amcp_drake.online.simulate import Trajectory
from amcp_drake.systems.controller_system import AdaptiveMPCSystem
from amcp_drake.systems.pendulum import (
    Pendulum,
    PendulumSpec,
    affine_family,
    pendulum_problem,
    run_pendulum,
)

ROOT = Path(__file__).resolve().parents[1]
NEEDS_THETA_STAR_OR_W = {"theta_star_in_Theta", "w_in_W", "model_consistent", "theta_star_in_Theta_k", "lemma5"}
STEPS = 25
#: W as a fraction of the covering W at which the data contradict the model on this run, and a fraction
#: 3x larger at which they do not (the run's own linearisation error lies between).
W_TOO_SMALL, W_JUST_ENOUGH = 0.001, 0.003


def closed_form_step(spec: PendulumSpec, x, u, theta) -> np.ndarray:
    """x⁺ of the point-mass pendulum, q = 0 upright: v⁺ = (v + h (g/l sin q + u/(m l²))) / (1 + h b/(m l²)),
    q⁺ = q + h v⁺."""
    m, b = spec.physical(theta)
    h, g, ell = spec.dt, spec.gravity, spec.length
    inertia = m * ell**2
    v_next = (x[1] + h * (g / ell * np.sin(x[0]) + u[0] / inertia)) / (1 + h * b / inertia)
    return np.array([x[0] + h * v_next, v_next])


def closed_form_linearisation(spec: PendulumSpec, theta) -> tuple[np.ndarray, np.ndarray]:
    m, b = spec.physical(theta)
    h, g, ell = spec.dt, spec.gravity, spec.length
    inertia = m * ell**2
    c = 1 + h * b / inertia
    dv = np.array([h * g / ell / c, 1 / c])
    A = np.array([[1 + h * dv[0], h * dv[1]], dv])
    B = np.array([[h * h / (inertia * c)], [h / (inertia * c)]])
    return A, B


@pytest.fixture(scope="module")
def pendulum() -> Pendulum:
    return Pendulum(PendulumSpec())


@pytest.fixture(scope="module")
def covered():
    return run_pendulum(STEPS)


@pytest.fixture(scope="module")
def too_small():
    return run_pendulum(STEPS, w_scale=W_TOO_SMALL)


def test_the_plant_is_the_pendulum_of_the_docs(pendulum):
    rng = np.random.default_rng(1)
    for _ in range(20):
        x, u, th = rng.uniform(-0.5, 0.5, 2), rng.uniform(-4, 4, 1), rng.uniform(-1, 1, 2)
        assert np.allclose(pendulum.step(x, u, th), closed_form_step(pendulum.spec, x, u, th), rtol=0, atol=1e-12)


def test_linearise_and_the_affine_family_match_the_closed_form(pendulum):
    spec = pendulum.spec
    for th in ([0.0, 0.0], [1.0, -1.0], [-0.3, 0.7]):
        A, B = pendulum.linearise(th)
        A_ref, B_ref = closed_form_linearisation(spec, th)
        assert np.allclose(A, A_ref, rtol=0, atol=1e-12) and np.allclose(B, B_ref, rtol=0, atol=1e-12)
    A0, B0, A, B = affine_family(pendulum)
    A_ref0, B_ref0 = closed_form_linearisation(spec, [0.0, 0.0])
    assert np.allclose(A0, A_ref0, atol=1e-12) and np.allclose(B0, B_ref0, atol=1e-12)
    for i in range(2):
        e = np.eye(2)[i]
        diff = [np.subtract(*pair) / 2 for pair in zip(closed_form_linearisation(spec, e),
                                                      closed_form_linearisation(spec, -e), strict=True)]
        assert np.allclose(A[i], diff[0], atol=1e-12) and np.allclose(B[i], diff[1], atol=1e-12)


def test_W_covers_the_linearisation_error_at_points_it_was_not_estimated_on(pendulum):
    problem, _, err = pendulum_problem(pendulum.spec)
    half = 1 / np.abs(problem.H_w).max(axis=0)
    assert np.allclose(half, pendulum.spec.margin * err.max_abs, rtol=1e-12)
    A0, B0, A, B = problem.A0, problem.B0, problem.A, problem.B
    s = pendulum.spec
    rng = np.random.default_rng(12345)  # not the estimate's seed
    hi = np.array([s.q_max, s.v_max, s.u_max, 1.0, 1.0])
    worst = np.zeros(2)
    for z in rng.uniform(-hi, hi, size=(300, 5)):
        x, u, th = z[:2], z[2:3], z[3:]
        e = closed_form_step(s, x, u, th) - (A0 + np.tensordot(th, A, 1)) @ x - (B0 + np.tensordot(th, B, 1)) @ u
        worst = np.maximum(worst, np.abs(e))
    assert np.all(worst <= half)
    # the estimate's value is the closed-form error at the point where it found it
    for i, point in enumerate(err.argmax):
        z = np.array(point)
        x, u, th = z[:2], z[2:3], z[3:]
        e = closed_form_step(s, x, u, th) - (A0 + np.tensordot(th, A, 1)) @ x - (B0 + np.tensordot(th, B, 1)) @ u
        assert abs(e[i]) == pytest.approx(err.max_abs[i], rel=1e-9)


def test_the_closed_loop_in_drake_certifies_as_a_measured_run(covered):
    traj = covered.trajectory
    assert traj.theta_star is None and traj.w is None
    assert traj.steps == STEPS and traj.stop_reason == "completed"
    assert traj.meta["simulator"] == "drake"
    assert covered.reason == SimulatorStatus.ReturnReason.kReachedBoundaryTime
    cert = certify(traj)
    assert cert.verdict == "pass"
    consistency = cert.claim("data_consistency")
    assert consistency.status == "pass" and consistency.margin > 0
    for claim in cert.claims:
        if claim.data["id"] in NEEDS_THETA_STAR_OR_W:
            assert claim.status == "not_applicable"
    # the linearisation error of the run, with the true parameter, lies in W (what W was chosen for)
    pr, th = covered.problem, covered.theta_true
    X = np.array([r.x for r in traj.records])
    U = np.array([r.u for r in traj.records[:-1]])
    w = X[1:] - X[:-1] @ pr.A_of(th).T - U @ pr.B_of(th).T
    assert np.max(w @ pr.H_w.T) <= 1.0
    # and it matches the closed-form plant step by step
    for k in range(STEPS):
        assert np.allclose(X[k + 1], closed_form_step(PendulumSpec(), X[k], U[k], th), atol=1e-12)


def test_a_W_that_does_not_cover_the_error_stops_cleanly_and_the_certificate_says_where(too_small, tmp_path):
    traj = too_small.trajectory
    assert traj.stop_reason.startswith("inconsistent data at step ")
    k = int(traj.stop_reason.rsplit(" ", 1)[1])
    assert 1 <= k < STEPS and traj.steps == k
    # the Simulator returned early at t_k, by the controller's termination, not an exception
    assert too_small.reason == SimulatorStatus.ReturnReason.kReachedTerminationCondition
    assert too_small.time == pytest.approx(k * PendulumSpec().dt, abs=1e-12)
    cert = certify(traj)
    assert cert.verdict == "fail"
    consistency = cert.claim("data_consistency")
    assert consistency.status == "fail" and consistency.margin < 0
    assert consistency.data["worst_step"] == k and consistency.data["failing_steps"] == [k]
    assert cert.claim("recursive_feasibility").status == "not_run"
    # the command line certifies the saved partial run: exit 1, no traceback
    path = tmp_path / "pendulum.json.gz"
    traj.save(path)
    done = subprocess.run([sys.executable, "-m", "amcp_drake.cli", "certify", "--trajectory", str(path),
                           "--out", str(tmp_path / "out")], capture_output=True, text=True)
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr + done.stdout


def test_a_W_three_times_larger_keeps_the_data_consistent():
    cert = certify(run_pendulum(STEPS, w_scale=W_JUST_ENOUGH).trajectory)
    assert cert.claim("data_consistency").status == "pass"


def test_the_reset_recovery_goes_on_and_the_certificate_reports_the_contradiction(too_small, tmp_path):
    run = run_pendulum(STEPS, w_scale=W_TOO_SMALL, on_inconsistent="reset")
    traj = run.trajectory
    k = too_small.trajectory.steps
    assert traj.steps == STEPS and traj.stop_reason == "completed"
    assert traj.meta["theta_resets"][0] == k
    rec = traj.records[k]
    # the step taken again from Θ_k = Θ: no Δ_k at this step, so Θ_k is Θ_0 exactly
    assert np.array_equal(rec.H_theta, run.design.H_theta) and np.array_equal(rec.h_theta, run.design.h_theta0)
    cert = certify(traj)
    consistency = cert.claim("data_consistency")
    assert consistency.status == "fail" and consistency.data["worst_step"] == k
    # the certificate, recomputing Θ_(k−1) ∩ Δ_k from the records, finds the contradictions exactly where the
    # controller reset Θ_k
    assert consistency.data["failing_steps"] == traj.meta["theta_resets"]
    assert cert.claim("Theta_k_nested").status == "fail"
    assert cert.verdict == "fail"
    # the file keeps the reset steps, and certifies the same
    path = tmp_path / "reset.json.gz"
    traj.save(path)
    again = Trajectory.load(path)
    assert again.meta["theta_resets"] == traj.meta["theta_resets"]
    assert certify(again).claim("data_consistency").data["worst_step"] == k


@pytest.mark.parametrize(("args", "code"), [(["25", "0.001"], 1), (["many"], 2), (["25", "1", "ignore"], 2)])
def test_the_example_script_exits_with_the_certificate_s_code(args, code):
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "pendulum_in_drake.py"), *args],
                          capture_output=True, text=True)
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr + done.stdout


@pytest.mark.parametrize(("field", "kwargs"), [("x0", {"x0": (np.nan, 0.0)}), ("theta_true", {"theta_true": (1.5, 0.0)}),
                                               ("steps", {"steps": 0}), ("w_scale", {"w_scale": -1.0})])
def test_bad_arguments_of_the_example_name_the_field(field, kwargs):
    args = {"steps": 5, **kwargs}
    with pytest.raises(ProblemError, match=field):
        run_pendulum(args.pop("steps"), **args)


def test_on_inconsistent_is_checked(covered):
    with pytest.raises(ProblemError, match="on_inconsistent"):
        AdaptiveMPCSystem(controller=None, problem=covered.problem, design=covered.design, on_inconsistent="ignore")


def test_the_how_to_blocks_run_as_written_and_build_the_module_s_problem(capsys):
    """The Python blocks of docs/how-to/nonlinear-plant.md, run in order, build the problem that
    pendulum_problem() builds (an implementation of their own) and certify the run: "pass"."""
    import re

    text = (ROOT / "docs" / "how-to" / "nonlinear-plant.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) == 4
    ns: dict = {}
    exec(compile("\n".join(blocks), "nonlinear-plant.md", "exec"), ns)
    problem, _, _ = pendulum_problem()
    for name in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G"):
        assert np.allclose(getattr(ns["problem"], name), getattr(problem, name), rtol=1e-12, atol=1e-15), name
    assert capsys.readouterr().out.split()[0] == "pass"
