"""Campaign failures are complete replays.

A deliberately failing run goes through the campaign's own code path (``run_problem`` with a stub
drawing function): Example 1 with a state box for μ (eq. (11)) far smaller than the states the run
visits, so μ is too large and the recorded μ‖D(x_k,u_k)‖² <= 1 and Lemma 5 claims fail — a real
failure of the data, not of a tolerance. The printed replay command, run as a separate process,
must give the same verdict, bit-identical margins and the same trajectory. The saved replay of
campaign problem 0-19 (seed 0) must be faithful to the run it records.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import shlex
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import ProblemSpec, Scenario
from amcp_drake.model.problem_io import load_spec, save_spec
from amcp_drake.online.simulate import Trajectory
from tests.guards import GUARD_SECONDS

DATA = Path(__file__).parent / "data" / "campaign-failures" / "0-19"
STEPS = 4
#: The disturbance of the failing run, written out here (not drawn by the code under test): vertices
#: and one interior point of Example 1's W = [-0.1, 0.1]².
W_SEQUENCE = np.array([[0.1, -0.1], [-0.1, -0.1], [0.03, 0.07], [0.1, 0.1]])
#: A recorded certificate's margin against the replay's, relative (absolute below 1): far below any
#: change of a check's meaning (redefining "X_f non-empty" moved its margin from 87 to 0.85) and above the last
#: bits that move with the installed numpy/scipy (1e-16 relative, measured 2026-11-24).
REPLAY_MARGIN_TOL = 1e-12


def _failing_case():
    """Example 1, x0 = [2, 3], θ* = [0.8, 0.2, -0.5], but μ computed on the box |x_i| <= 0.5 (the run
    starts at |x_2| = 3): (11) does not hold on the visited states."""
    base = lorenzen2019_spec()
    spec = ProblemSpec(base.problem, dataclasses.replace(base.design, mu_state_bound=0.5))
    return SimpleNamespace(spec=spec, x0=np.array([2.0, 3.0]), theta_star=np.array([0.8, 0.2, -0.5]), w=W_SEQUENCE,
                           options=OnlineOptions(update="fixed", projection="Theta_k"),
                           labels={"kind": "mu box too small"}, seed=11)


@pytest.fixture(scope="module")
def failing_run(tmp_path_factory):
    from amcp_drake.studies.campaign import run_problem

    folder = tmp_path_factory.mktemp("failures")
    result = run_problem(4, 2, ("drake", "cvxpy"), str(folder), steps=STEPS, draw=lambda seed, idx, steps: _failing_case())
    assert result["status"] == "fail", result.get("message")
    return result, Path(result["failure_dir"])


def test_the_saved_problem_file_holds_everything_the_run_used(failing_run):
    result, folder = failing_run
    assert folder.name == "4-2"
    data = json.loads((folder / "problem.json").read_text())
    assert data["online"]["projection"] == "Theta_k" and data["online"]["update"] == "fixed"
    assert data["scenario"]["disturbance"] == W_SEQUENCE.tolist()  # the explicit array, not a kind
    assert data["scenario"]["x0"] == [2.0, 3.0] and data["scenario"]["theta_star"] == [0.8, 0.2, -0.5]
    assert data["scenario"]["steps"] == STEPS
    assert data["design"]["mu_state_bound"] == 0.5
    manifest = json.loads((folder / "replay.json").read_text())
    assert manifest["failing_backends"] == ["drake", "cvxpy"]
    assert {run["design_backend"] for run in manifest["runs"].values()} == {"drake"}
    assert result["replay"] == [manifest["runs"][b]["command"] for b in ("drake", "cvxpy")]
    failed = {name for name, c in manifest["runs"]["cvxpy"]["claims"].items() if c["status"] == "fail"}
    assert "μ‖D(x_k,u_k)‖² <= 1" in failed


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_the_printed_command_reproduces_the_failure_bit_for_bit(failing_run, backend):
    result, folder = failing_run
    manifest = json.loads((folder / "replay.json").read_text())
    command = shlex.split(manifest["runs"][backend]["command"])
    assert command[:2] == ["amcp", "certify"]
    proc = subprocess.run([sys.executable, "-m", "amcp_drake", *command[1:]], check=False, capture_output=True, text=True,
                          timeout=GUARD_SECONDS)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "NOT CERTIFIED" in proc.stdout
    cert = json.loads((folder / f"replay-{backend}" / "certificate.json").read_text())
    assert cert["verdict"] == result["verdicts"][backend] == "fail"
    replayed = {c["name"]: {"status": c["status"], "margin": c["margin"]} for c in cert["claims"]}
    assert replayed == result["claims"][backend]  # exact equality of every margin (floats compared with ==)
    recorded = Trajectory.load(folder / f"trajectory-{backend}.json.gz")
    again = Trajectory.load(folder / f"replay-{backend}" / "trajectory.json.gz")
    for name in ("x", "u", "w"):
        np.testing.assert_array_equal(getattr(again, name), getattr(recorded, name))


# -- scenario.disturbance as an explicit sequence ----------------------------------------------------

def _scenario(disturbance, steps=STEPS):
    return Scenario(x0=[2.0, 3.0], theta_star=[0.8, 0.2, -0.5], steps=steps, disturbance=disturbance)


@pytest.mark.parametrize(("disturbance", "field", "words"), [
    (W_SEQUENCE[:3].tolist(), "scenario.disturbance", "4 rows"),
    (W_SEQUENCE.tolist() + [[0.0, 0.0]], "scenario.disturbance", "4 rows"),
    ([[0.1, -0.1], [0.0], [0.0, 0.0], [0.0, 0.0]], "scenario.disturbance[1]", "length 2"),
    ([[0.1, -0.1], [0.0, 0.0], [0.0, 0.2], [0.0, 0.0]], "scenario.disturbance[2]", "a point of W"),
    ([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [float("nan"), 0.0]], "scenario.disturbance[3][0]", "finite"),
    ([[0.0, 0.0], ["a", 0.0], [0.0, 0.0], [0.0, 0.0]], "scenario.disturbance[1]", "real numbers"),
    ({"w": 1}, "scenario.disturbance", "array of 4 rows"),
    ("gaussian", "scenario.disturbance", "array of 4 rows"),
])
def test_an_explicit_disturbance_is_validated_row_by_row(disturbance, field, words):
    problem = lorenzen2019_spec().problem
    with pytest.raises(ProblemError) as info:
        _scenario(disturbance).validate_for(problem)
    assert info.value.field == field
    assert words in str(info.value)


def test_an_explicit_disturbance_round_trips_exactly_and_serves_shorter_runs(tmp_path):
    base = lorenzen2019_spec()
    w = np.array([[0.1, -0.1], [-0.1 / 3, 0.1 / 7], [0.0, 0.0], [1e-17, -0.1]])
    path = save_spec(ProblemSpec(base.problem, base.design, _scenario(w.tolist())), tmp_path / "p.json")
    sc = load_spec(path).scenario
    assert sc.explicit_disturbance
    np.testing.assert_array_equal(sc.disturbance, w)
    np.testing.assert_array_equal(sc.disturbance_for(2), w[:2])
    with pytest.raises(ProblemError, match="at most 4"):
        sc.disturbance_for(5)
    assert load_spec(save_spec(base, tmp_path / "q.json")).scenario.disturbance_for(7) == "uniform"


def test_certify_refuses_more_steps_than_the_explicit_disturbance_has(tmp_path):
    base = lorenzen2019_spec()
    path = save_spec(ProblemSpec(base.problem, base.design, _scenario(W_SEQUENCE.tolist())), tmp_path / "p.json")
    proc = subprocess.run([sys.executable, "-m", "amcp_drake", "certify", str(path), "--steps", "5", "--out",
                           str(tmp_path / "out")], check=False, capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "steps: expected at most 4 (scenario.disturbance is a sequence of 4 rows)" in proc.stderr
    assert not (tmp_path / "out").exists()


# -- the regression replay of campaign problem 0-19 (seed 0) ------------------------------------------

def test_the_replay_of_campaign_problem_0_19_is_faithful_to_the_recorded_run():
    """problem.json of 0-19 holds what the recorded cvxpy run used (online options, x0, θ*, the
    explicit w, steps), and certifying the recorded run against it gives the recorded verdict and the
    recorded margins, among them lms_update −0.5526 (the projection onto Θ_k)."""
    from amcp_drake.certificate.certify import certify

    spec = load_spec(DATA / "problem.json")
    manifest = json.loads((DATA / "replay.json").read_text())
    traj = Trajectory.load(DATA / "trajectory-cvxpy.json.gz")
    assert (manifest["campaign_seed"], manifest["idx"], manifest["failing_backends"]) == (0, 19, ["cvxpy"])
    assert manifest["runs"]["cvxpy"]["command"].startswith("amcp certify tests/data/campaign-failures/0-19/problem.json "
                                                          "--backend cvxpy --design-backend drake")
    sc = spec.scenario
    assert spec.online == traj.options
    assert (spec.online.projection, spec.online.update) == ("Theta_k", "fixed")
    assert sc.explicit_disturbance and sc.steps == traj.steps == 15
    np.testing.assert_array_equal(sc.disturbance, traj.w)
    np.testing.assert_array_equal(sc.x0, traj.x[0])
    np.testing.assert_array_equal(sc.theta_star, traj.theta_star)
    with gzip.open(DATA / "trajectory-cvxpy.json.gz", "rt") as handle:
        assert json.load(handle)["meta"]["disturbance"] == "array"
    cert = certify(traj, spec)
    recorded = manifest["runs"]["cvxpy"]["claims"]
    # statuses exactly; margins to REPLAY_MARGIN_TOL (the last bits of a margin move with the installed
    # numpy/scipy: a fresh environment on 2026-11-24 gave Assumption 8 0.5999876469409562 against the
    # recorded ...956, and cost (17) −8.7e-19 against 0.0)
    replayed = {c.name: c for c in cert.claims if c.name in recorded}
    assert set(replayed) == set(recorded)
    for name, claim in replayed.items():
        assert claim.status == recorded[name]["status"], name
        assert claim.margin == pytest.approx(recorded[name]["margin"], rel=REPLAY_MARGIN_TOL, abs=REPLAY_MARGIN_TOL), name
    assert recorded["θ̂ follows (12)"] == {"status": "fail", "margin": -0.5526238078753245}
