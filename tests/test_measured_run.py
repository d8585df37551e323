"""Certificates of measured runs: a trajectory with θ* and w unknown (both null).

Example 1's run with ``theta_star`` and ``w`` set to null certifies with every claim that needs them
``not_applicable`` and every other claim exactly as on the simulated run; moving one state x_k by 10× the
size of W makes the model-consistency claim fail first at step k. The consistency margin (the signed
Chebyshev radius of Θ_(k−1) ∩ Δ_k) is checked against a case solved by hand, at its tolerance, and the
controller's record path for an empty Θ_(k−1) ∩ Δ_k gives a partial trajectory that certifies.
"""

from __future__ import annotations

import gzip
import json
import re
from types import SimpleNamespace

import jsonschema
import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.certificate.certify import certify, schema
from amcp_drake.certificate.claims import RunView
from amcp_drake.certificate.consistency import data_consistency, signed_chebyshev_radius
from amcp_drake.cli import main
from amcp_drake.model.errors import InconsistentDataError, ProblemError, TrajectoryError
from amcp_drake.online.controller import AdaptiveMPC, is_inconsistent
from amcp_drake.online.measured import measured_trajectory
from amcp_drake.online.simulate import Trajectory
from tests.conftest import scalar_problem
from tests.recorded_runs import as_recorded

#: The documented tolerance of data_consistency (θ units, rows of unit norm), written here.
CONSISTENCY_TOL = 1e-7
#: The claims that need θ* or the disturbances w_k (docs/certificate.md, "Measured runs").
NEEDS_THETA_STAR_OR_W = {"theta_star_in_Theta", "w_in_W", "model_consistent", "theta_star_in_Theta_k", "lemma5"}
#: The step whose state is moved in the contradicting copy.
MOVED = 20


@pytest.fixture(scope="module")
def simulated(example_run) -> dict:
    """Example 1, 50 steps, seed 0 (the run of ``amcp certify --example lorenzen2019``) as its file's dict."""
    return as_recorded(example_run)


@pytest.fixture(scope="module")
def measured(simulated) -> dict:
    """The same file with θ* and w unknown."""
    return {**json.loads(json.dumps(simulated)), "theta_star": None, "w": None}


def w_size(problem) -> float:
    """max ‖w‖_∞ over W (from the vertices of W)."""
    return float(np.max(np.abs(problem.w_vertices())))


def moved(measured: dict, problem, k: int) -> dict:
    """``measured`` with x_k (and its record's copy) moved by 10× the size of W along x_1."""
    data = json.loads(json.dumps(measured))
    step = 10 * w_size(problem)
    data["x"][k][0] += step
    data["records"][k]["x"][0] += step
    return data


def certify_file(tmp_path, data: dict, name: str):
    path = tmp_path / f"{name}.json"
    path.write_text(json.dumps(data))
    out = tmp_path / f"{name}-out"
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(path), "--out", str(out)],
                                catch_exceptions=False)
    cert = json.loads((out / "certificate.json").read_text()) if (out / "certificate.json").exists() else None
    if cert is not None:
        jsonschema.validate(cert, schema())
    return result, cert, out


# -- the Example 1 trajectory, θ* and w unknown ------------------------------------------------------
def test_the_example_1_run_with_theta_star_and_w_unknown_certifies_as_a_measured_run(tmp_path, simulated, measured,
                                                                                    example_spec):
    result, cert, out = certify_file(tmp_path, measured, "measured")
    assert result.exit_code == 0, result.output
    assert cert["verdict"] == "pass" and cert["run"]["measured"] is True and cert["run"]["theta_star"] is None
    status = {c["id"]: c for c in cert["claims"]}
    assert {i for i, c in status.items() if c["status"] == "not_applicable"} == NEEDS_THETA_STAR_OR_W
    for claim_id in NEEDS_THETA_STAR_OR_W:
        assert status[claim_id]["margin"] is None and "θ* and w unknown" in status[claim_id]["detail"]
    # every other claim is judged exactly as on the simulated run of the same file (none needs θ* or w)
    reference = certify(Trajectory.from_dict(json.loads(json.dumps(simulated))), example_spec).to_dict()
    assert reference["verdict"] == "pass"
    others = [c for c in reference["claims"] if c["id"] not in NEEDS_THETA_STAR_OR_W]
    assert [(c["id"], c["status"], c["margin"]) for c in others] == \
        [(c["id"], c["status"], c["margin"]) for c in cert["claims"] if c["id"] not in NEEDS_THETA_STAR_OR_W]
    applicable = len(reference["claims"]) - len(NEEDS_THETA_STAR_OR_W)
    assert cert["counts"] == {"pass": applicable, "fail": 0, "not_run": 0, "not_applicable": 5}
    assert status["data_consistency"]["status"] == "pass" and status["data_consistency"]["margin"] > 0
    assert f"CERTIFIED (measured run): all {applicable} applicable claims hold; 5 need θ* and w" in result.output
    # the report lists the not-applicable claims with the reason
    html = (out / "report.html").read_text()
    rows = dict(re.findall(r'data-claim-id="([^"]+)" data-status="([^"]+)"', html))
    assert {i for i, s in rows.items() if s == "not_applicable"} == NEEDS_THETA_STAR_OR_W
    assert html.count("θ* and w unknown") >= len(NEEDS_THETA_STAR_OR_W)
    with gzip.open(out / "trajectory.json.gz", "rt") as handle:
        saved = json.load(handle)
    assert saved["theta_star"] is None and saved["w"] is None


def test_one_state_moved_by_ten_times_w_fails_the_consistency_claim_at_that_step(tmp_path, measured, example_spec):
    result, cert, _ = certify_file(tmp_path, moved(measured, example_spec.problem, MOVED), "moved")
    assert result.exit_code == 1, result.output
    claim = {c["id"]: c for c in cert["claims"]}["data_consistency"]
    assert claim["status"] == "fail" and claim["extra"]["first_failing_step"] == MOVED
    per_step = dict((k, m) for k, m in claim["per_step"])
    assert all(per_step[k] > 0 for k in range(1, MOVED))  # the data before it are consistent
    assert per_step[MOVED] < -CONSISTENCY_TOL
    assert cert["verdict"] == "fail" and cert["run"]["measured"] is True


def test_the_consistency_claim_holds_on_the_simulated_run(example_run):
    claim = certify(example_run).claim("data_consistency")
    assert claim.status == "pass" and claim.margin > 0
    assert [k for k, _ in claim.data["per_step"]] == list(range(1, example_run.steps + 1))


def test_only_one_of_theta_star_and_w_null_is_refused_naming_the_field(tmp_path, simulated):
    for field in ("theta_star", "w"):
        data = {**json.loads(json.dumps(simulated)), field: None}
        with pytest.raises(TrajectoryError, match=field):
            Trajectory.from_dict(data)
        path = tmp_path / f"{field}.json"
        path.write_text(json.dumps(data))
        out = tmp_path / f"{field}-out"
        result = CliRunner().invoke(main, ["certify", "--trajectory", str(path), "--out", str(out)])
        assert result.exit_code == 2 and field in result.output and not out.exists()


# -- the consistency margin, by hand ----------------------------------------------------------------
def test_signed_chebyshev_radius_of_boxes_and_disjoint_intervals():
    box = (np.vstack([np.eye(2), -np.eye(2)]), np.array([1.0, 2.0, 1.0, 2.0]))  # [-1, 1] × [-2, 2]
    assert signed_chebyshev_radius(*box) == pytest.approx(1.0, abs=1e-9)
    # [-1, 1] ∩ [3, 5] = ∅: each row must be relaxed by 1 (half the gap of 2) to meet
    H, h = np.array([[1.0], [-1.0], [1.0], [-1.0]]), np.array([1.0, 1.0, 5.0, -3.0])
    assert signed_chebyshev_radius(H, h) == pytest.approx(-1.0, abs=1e-9)
    # the scale of a row does not change the set or its radius
    assert signed_chebyshev_radius(H * [[3.0], [1.0], [1.0], [7.0]], h * [3.0, 1.0, 1.0, 7.0]) == \
        pytest.approx(-1.0, abs=1e-9)


def scalar_view(gap: float) -> RunView:
    """One transition of x+ = (0.5 + 0.2θ)x + u + w, |w| <= 0.1, from x_0 = 1, u_0 = 0, Θ_0 = [-1, 1]:
    Δ_1 = [(x_1 − 0.6)/0.2, (x_1 − 0.4)/0.2]; x_1 = 0.8 + 0.4·gap puts its lower end at 1 + 2·gap, so the
    signed Chebyshev radius of Θ_0 ∩ Δ_1 is −gap (half the gap between the intervals)."""
    problem = scalar_problem()
    record = SimpleNamespace(H_theta=np.array([[1.0], [-1.0]]), h_theta=np.array([1.0, 1.0]))
    traj = SimpleNamespace(problem=problem, x=np.array([[1.0], [0.8 + 0.4 * gap]]), u=np.array([[0.0]]),
                           records=[record, record])
    return RunView(traj)


@pytest.mark.parametrize("factor, status", [(0.5, "pass"), (2.0, "fail"), (-0.5, "pass")])
def test_consistency_tolerance_just_inside_and_outside(factor, status):
    gap = factor * CONSISTENCY_TOL
    claim = data_consistency(scalar_view(gap))
    assert claim.margin == pytest.approx(-gap, abs=1e-12)
    assert claim.status == status
    assert claim.data["first_failing_step"] == (1 if status == "fail" else None)


# -- a user's loop around AdaptiveMPC.step ------------------------------------------------------------
def user_loop(spec, offline, steps: int, disturbance: np.ndarray, jump: tuple[int, np.ndarray] | None = None):
    """The true system (1) with θ* of the scenario, stepped by hand; ``jump`` adds a state offset after step k."""
    pr, sc = spec.problem, spec.scenario
    ctrl = AdaptiveMPC(pr, offline, backend="drake")
    x, records = np.asarray(sc.x0, float), []
    for k in range(steps):
        u, record = ctrl.step(x, on_inconsistent="record")
        records.append(record)
        if u is None:
            break
        x = pr.step(x, u, sc.theta_star, disturbance[k])
        if jump is not None and jump[0] == k:
            x = x + jump[1]
    else:
        records.append(ctrl.step(x, on_inconsistent="record")[1])
    return ctrl, records


def test_a_users_loop_gives_the_trajectory_of_the_built_in_simulator(example_spec, example_design, example_run):
    steps = 12
    ctrl, records = user_loop(example_spec, example_design, steps, example_run.w)
    traj = measured_trajectory(ctrl, records)
    assert traj.measured and traj.stop_reason == "completed" and traj.meta["simulator"] == "user_loop"
    np.testing.assert_array_equal(traj.x, example_run.x[: steps + 1])
    np.testing.assert_array_equal(traj.u, example_run.u[:steps])
    cert = certify(Trajectory.from_dict(as_recorded(traj)))  # through the file format
    assert cert.verdict == "pass" and set(cert.ids("not_applicable")) == NEEDS_THETA_STAR_OR_W


def test_an_empty_intersection_is_recorded_and_the_partial_run_certifies(example_spec, example_design, tmp_path):
    steps, k = 10, 4
    jump = 10 * w_size(example_spec.problem) * np.array([1.0, 0.0])
    ctrl, records = user_loop(example_spec, example_design, steps, np.zeros((steps, 2)), (k - 1, jump))
    last = records[-1]
    assert last.k == k and last.u is None and is_inconsistent(last)
    traj = measured_trajectory(ctrl, records)
    assert traj.stop_reason == f"inconsistent data at step {k}" and traj.steps == k and len(traj.records) == k + 1
    path = traj.save(tmp_path / "partial.json.gz")  # the file layout accepts the recorded event
    cert = certify(Trajectory.load(path))
    consistency = cert.claim("data_consistency")
    assert consistency.status == "fail" and consistency.data["first_failing_step"] == k
    feasibility = cert.claim("recursive_feasibility")  # step k was not solved: explained by the data
    assert feasibility.status == "not_run" and feasibility.data["found_status"] == "fail"
    assert cert.verdict == "fail"
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(path), "--out", str(tmp_path / "o")])
    assert result.exit_code == 1, result.output


def test_the_default_still_raises_and_a_bad_option_is_refused(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake")
    ctrl.step(np.array([2.0, 3.0]))
    with pytest.raises(ProblemError, match="on_inconsistent"):
        ctrl.step(np.array([2.0, 3.0]), on_inconsistent="ignore")
    with pytest.raises(InconsistentDataError, match="step 1"):
        ctrl.step(np.array([40.0, -20.0]))


def test_records_that_do_not_form_one_run_are_refused_naming_the_record(example_spec, example_design, example_run):
    ctrl, records = user_loop(example_spec, example_design, 3, example_run.w)
    with pytest.raises(ProblemError, match=r"records\[1\]\.k"):
        measured_trajectory(ctrl, [records[0], records[2]])
    with pytest.raises(ProblemError, match="records"):
        measured_trajectory(ctrl, [])


def test_the_how_to_loop_runs_as_written_and_certifies(tmp_path, monkeypatch):
    """The Python block of docs/how-to/certify-measured-run.md, run as written (in a scratch folder)."""
    from pathlib import Path

    page = Path(__file__).resolve().parents[1] / "docs" / "how-to" / "certify-measured-run.md"
    (block,) = re.findall(r"```python\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S)
    monkeypatch.chdir(tmp_path)
    scope: dict = {}
    exec(compile(block, str(page), "exec"), scope)  # noqa: S102 - the documented snippet itself
    cert = scope["cert"]
    assert cert.verdict == "pass" and cert.counts()["not_applicable"] == len(NEEDS_THETA_STAR_OR_W)
    assert cert.counts() == {"pass": 31, "fail": 0, "not_run": 0, "not_applicable": 5}  # as the page prints
    assert Trajectory.load(tmp_path / "measured.json.gz").measured


def test_a_recorded_inconsistent_step_with_an_input_is_refused_naming_the_field(example_spec, example_design):
    """The file layout: "inconsistent data at step K" with K + 1 records needs the last one without an input."""
    steps, k = 6, 3
    jump = 10 * w_size(example_spec.problem) * np.array([1.0, 0.0])
    ctrl, records = user_loop(example_spec, example_design, steps, np.zeros((steps, 2)), (k - 1, jump))
    data = as_recorded(measured_trajectory(ctrl, records))
    assert data["stop_reason"] == f"inconsistent data at step {k}" and len(data["records"]) == k + 1
    Trajectory.from_dict(json.loads(json.dumps(data)))  # as written: accepted
    data["records"][k]["u"] = [0.0]
    with pytest.raises(TrajectoryError, match=rf"records\[{k}\]\.u"):
        Trajectory.from_dict(data)
