"""``amcp certify``: exit codes 0 / 1 / 2, the files written (atomically), schema validity, bad input."""

from __future__ import annotations

import gzip
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.certificate.certify import schema
from amcp_drake.certificate.report import OUTPUT_FILES
from amcp_drake.cli import main
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.model.problem_io import save_spec, spec_to_dict
from tests.guards import GUARD_SECONDS

ROOT = Path(__file__).resolve().parents[1]
STEPS = 6


@pytest.fixture(scope="module")
def saved(tmp_path_factory) -> dict:
    """A 6-step Example 1 run saved as trajectory.json.gz (and its dict for tampered copies)."""
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = lorenzen2019_spec()
    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake")
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, STEPS, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)
    folder = tmp_path_factory.mktemp("saved")
    return {"path": traj.save(folder / "trajectory.json.gz"), "dict": json.loads(json.dumps(traj.to_dict()))}


def invoke(*args: str):
    return CliRunner().invoke(main, ["certify", *map(str, args)], catch_exceptions=False)


def written(out: Path, others: tuple[str, ...] = ()) -> dict:
    """The bundle in ``out``: asserts exactly the three files (plus ``others``), returns certificate.json
    validated against the schema."""
    assert sorted(p.name for p in out.iterdir()) == sorted(OUTPUT_FILES + others)
    data = json.loads((out / "certificate.json").read_text())
    jsonschema.validate(data, schema())
    assert (out / "report.html").read_text().startswith("<!DOCTYPE html>")
    with gzip.open(out / "trajectory.json.gz", "rt") as handle:
        assert json.load(handle)["format"] == "amcp-trajectory"
    return data


def no_leftovers(folder: Path) -> None:
    """No hidden staging directory anywhere below ``folder``."""
    assert [p for p in folder.rglob(".*")] == []


def write_trajectory(data: dict, path: Path) -> Path:
    path.write_text(json.dumps(data))
    return path


# -- exit 0 ------------------------------------------------------------------------------------------
MULTIPLIER_CLAIMS = {"multipliers_nonneg", "multipliers_15c", "multipliers_15d"}


@pytest.mark.parametrize(("given", "solved", "claims"), [([], "vertex", 33), (["--formulation", "plain"], "plain", 36)])
def test_default_run_certifies_example_1(tmp_path, given, solved, claims):
    """No options but --out: Example 1, its scenario (50 steps, seed 0), Drake, the default --formulation
    auto (the vertex form for Example 1); every claim holds, the three Λ claims listed as not applicable
    (the vertex form has no multipliers). With --formulation plain the Λ claims are checked and hold."""
    out = tmp_path / "out"
    result = invoke("--out", out, *given)
    assert result.exit_code == 0, result.output
    data = written(out)
    assert data["verdict"] == "pass" and data["passed"] is True
    run = data["run"]
    assert (run["steps"], run["seed"], run["backend"]) == (50, 0, "drake")
    assert run["x0"] == [2.0, 3.0] and run["theta_star"] == [0.8, 0.2, -0.5]
    assert run["formulation"] == solved and (run["formulation_reason"] is None) == bool(given)
    assert f"CERTIFIED: all {claims} claims hold" in result.stdout and len(data["claims"]) == claims
    checked = {c["id"] for c in data["claims"]}
    unclaimed = {c["id"]: c["reason"] for c in run["not_claimed"]}
    if solved == "plain":
        assert MULTIPLIER_CLAIMS <= checked and not MULTIPLIER_CLAIMS & set(unclaimed)
    else:
        assert not MULTIPLIER_CLAIMS & checked and MULTIPLIER_CLAIMS <= set(unclaimed)
        assert all(unclaimed[i].startswith("not applicable (vertex form has no multipliers)") for i in MULTIPLIER_CLAIMS)
    for claim in data["claims"]:
        assert claim["id"] in result.stdout
    # the robust baseline beside the run: recorded apart from the claims, its adaptive cost that of the
    # saved trajectory (recomputed here), its robust run as long as the adaptive one
    baseline = data["figures"]["robust_baseline"]
    with gzip.open(out / "trajectory.json.gz", "rt") as handle:
        traj = json.load(handle)
    spec = lorenzen2019_spec()
    x, u = traj["x"][:-1], traj["u"]
    cost = sum(float(np.dot(xk, spec.problem.Q @ xk) + np.dot(uk, spec.problem.R @ uk)) for xk, uk in zip(x, u))
    assert baseline["adaptive"]["cost"] == pytest.approx(cost, rel=1e-12)
    assert baseline["robust"]["steps"] == baseline["adaptive"]["steps"] == 50
    assert "robust baseline (not part of the verdict): cost" in result.stdout
    assert not [c for c in data["claims"] if "baseline" in c["id"]]
    no_leftovers(tmp_path)


def test_saved_trajectory_is_rechecked_without_running(saved, tmp_path, monkeypatch):
    import amcp_drake.online.simulate

    monkeypatch.setattr(amcp_drake.online.simulate, "simulate", lambda *a, **k: pytest.fail("the loop was run again"))
    out = tmp_path / "out"
    result = invoke("--trajectory", saved["path"], "--out", out)
    assert result.exit_code == 0, result.output
    data = written(out)
    assert data["run"]["steps"] == STEPS and data["verdict"] == "pass"
    assert "robust_baseline" not in data["figures"]  # a re-check runs nothing, not even the baseline


def test_a_robust_run_has_no_baseline_beside_it(tmp_path):
    """--update none is the robust baseline itself: nothing to compare, and the report says so."""
    out = tmp_path / "out"
    result = invoke("--update", "none", "--steps", 3, "--out", out)
    assert result.exit_code == 0, result.output
    data = written(out)
    assert data["run"]["update"] == "none" and "robust_baseline" not in data["figures"]
    assert "robust baseline itself" in (out / "report.html").read_text()
    assert "robust baseline (not part of the verdict)" not in result.stdout


def test_second_run_replaces_the_bundle(saved, tmp_path):
    out = tmp_path / "out"
    assert invoke("--trajectory", saved["path"], "--out", out).exit_code == 0
    first = json.loads((out / "certificate.json").read_text())["created"]
    (out / "certificate.json").write_text("{}")  # a stale file must be replaced, not kept
    assert invoke("--trajectory", saved["path"], "--out", out).exit_code == 0
    assert json.loads((out / "certificate.json").read_text())["created"] >= first
    written(out)
    no_leftovers(tmp_path)


def test_other_files_in_out_are_kept(saved, tmp_path):
    """`amcp compare` writes amcp-out/compare.json by default: certifying into the same folder keeps it."""
    out = tmp_path / "amcp-out"
    out.mkdir()
    (out / "compare.json").write_text('{"mine": true}')
    assert invoke("--trajectory", saved["path"], "--out", out).exit_code == 0
    written(out, others=("compare.json",))
    assert json.loads((out / "compare.json").read_text()) == {"mine": True}
    no_leftovers(tmp_path)


# -- exit 1 ------------------------------------------------------------------------------------------
def test_failed_claim_exits_1_and_writes_the_bundle(saved, tmp_path):
    """A trajectory whose multiplier Λ^0_(0|2)[0,0] was made negative (Λ H_θ kept): exit 1, the
    bundle is still written, and it says which claim failed."""
    data = json.loads(json.dumps(saved["dict"]))
    lam = data["records"][2]["Lambda"]
    shift = lam[0][0][0][0] + 0.25
    lam[0][0][0][0] -= shift
    lam[0][0][0][1] -= shift
    path = write_trajectory(data, tmp_path / "tampered.json")
    out = tmp_path / "out"
    result = invoke("--trajectory", path, "--out", out)
    assert result.exit_code == 1, result.output
    cert = written(out)
    assert cert["verdict"] == "fail"
    assert [c["id"] for c in cert["claims"] if c["status"] == "fail"] == ["multipliers_nonneg"]
    assert "NOT CERTIFIED: 1 claim(s) failed: multipliers_nonneg" in result.stdout
    assert "CERTIFIED: all" not in result.stdout


def test_claim_not_run_exits_1_and_never_says_pass(saved, tmp_path):
    """A run of a problem that is not a built-in example and records no μ box: the (11) check cannot
    run. The verdict is 'incomplete', the exit code 1, and nothing claims the run is certified."""
    data = json.loads(json.dumps(saved["dict"]))
    # no longer Example 1's data, yet the same Θ (a facet row and its offset scaled by 2): the QP (20),
    # its minimiser and every other claim are unchanged, so only (11) is at issue (a changed R, the
    # earlier variant, also moves the minimiser of (17), which qp_optimality rightly reports)
    data["problem"]["Theta"]["H"][0] = [2.0 * a for a in data["problem"]["Theta"]["H"][0]]
    data["problem"]["Theta"]["h"][0] *= 2.0
    data["problem"]["name"] = "example1-variant"
    data["mu_state_bound"] = None
    data["design"]["mu_state_bound"] = None  # the design records its μ box too
    path = write_trajectory(data, tmp_path / "variant.json")
    out = tmp_path / "out"
    result = invoke("--trajectory", path, "--out", out)
    assert result.exit_code == 1, result.output
    cert = written(out)
    assert cert["verdict"] == "incomplete" and cert["passed"] is False
    assert [c["id"] for c in cert["claims"] if c["status"] != "pass"] == ["design.mu_condition_11"]
    assert "NOT CERTIFIED (incomplete)" in result.stdout and "CERTIFIED: all" not in result.stdout


def test_an_infeasible_scenario_exits_3_premise_not_met(tmp_path):
    """A problem file whose scenario starts outside Z: the QP is infeasible at k = 0. Theorem 14 assumes
    𝔻(x_0, Θ_0) ≠ ∅, so this is a premise not met (exit 3, with the LP margin and a pointer to amcp coverage),
    never a failed claim of Theorem 14."""
    spec = lorenzen2019_spec()
    data = spec_to_dict(spec)
    data["scenario"]["x0"] = [0.0, -1.0]
    problem = tmp_path / "infeasible.json"
    problem.write_text(json.dumps(data))
    out = tmp_path / "out"
    result = invoke(problem, "--steps", 3, "--out", out)
    assert result.exit_code == 3, result.output
    cert = written(out)
    assert cert["verdict"] == "premise_not_met" and cert["passed"] is False and cert["counts"]["fail"] == 0
    assert "recursive_feasibility" not in [c["id"] for c in cert["claims"]]
    premise = next(p for p in cert["premises"] if p["id"] == "initial_feasibility")
    assert premise["status"] == "not_met" and premise["margin"] < 0
    assert "PREMISE NOT MET: initial feasibility" in result.stdout and f"margin {premise['margin']:.3e}" in result.stdout
    assert "amcp coverage" in result.stdout
    assert "NOT CERTIFIED (premise not met)" in result.stdout and "claim(s) failed" not in result.stdout
    report = (out / "report.html").read_text()
    assert 'id="premise-initial_feasibility" class="fail" data-status="not_met"' in report
    assert 'class="verdict premise_not_met">premise_not_met<' in report


def test_a_given_gain_breaking_assumption_8_exits_3_premise_not_met(tmp_path):
    """design.K = (0, −3) with some P in the problem file: A(θ) + B(θ)K has spectral radius 1.12 at a vertex of Θ.
    The design cannot be made and nothing is run: a premise the user's design breaks (exit 3), not a failed claim."""
    spec = lorenzen2019_spec()
    data = spec_to_dict(spec)
    data["design"]["K"], data["design"]["P"] = [[0.0, -3.0]], [[1.0, 0.0], [0.0, 1.0]]
    problem = tmp_path / "bad_gain.json"
    problem.write_text(json.dumps(data))
    out = tmp_path / "out"
    result = invoke(problem, "--steps", 3, "--out", out)
    assert result.exit_code == 3, result.output
    assert "PREMISE NOT MET: Assumption 8" in result.stdout and "spectral radius" in result.stdout
    assert "1.1199" in result.stdout and not out.exists()


# -- exit 2 ------------------------------------------------------------------------------------------
def _bad_inputs(tmp: Path, saved: dict) -> dict[str, tuple[list[str], str]]:
    malformed = tmp / "malformed.json"
    malformed.write_text('{"format": "amcp-trajectory", "version": 1, ')
    not_traj = tmp / "problem-as-trajectory.json"
    save_spec(lorenzen2019_spec(), not_traj)
    bad_shape = json.loads(json.dumps(saved["dict"]))
    bad_shape["records"][1]["Lambda"] = [[1.0]]
    shape_file = write_trajectory(bad_shape, tmp / "bad-shape.json")
    bad_problem = tmp / "bad-problem.json"
    bad_problem.write_text("[1, 2")
    no_scenario = spec_to_dict(lorenzen2019_spec())
    del no_scenario["scenario"]
    no_scenario_file = tmp / "no-scenario.json"
    no_scenario_file.write_text(json.dumps(no_scenario))
    other = spec_to_dict(lorenzen2019_spec())
    other["cost"]["R"] = [[2.0]]
    other_file = tmp / "other.json"
    other_file.write_text(json.dumps(other))
    a_file = tmp / "a-file"
    a_file.write_text("x")
    traj = str(saved["path"])
    return {
        "missing-trajectory": (["--trajectory", str(tmp / "nope.json.gz")], "cannot be read"),
        "malformed-json": (["--trajectory", str(malformed)], "expected valid JSON"),
        "not-a-trajectory": (["--trajectory", str(not_traj)], "not a trajectory file"),
        "bad-record-shape": (["--trajectory", str(shape_file)], r"records\[1\]\.Lambda has shape"),
        "trajectory-of-other-problem": ([str(other_file), "--trajectory", traj], "different problem"),
        "run-option-with-trajectory": (["--trajectory", traj, "--steps", "3"], "--steps"),
        "missing-problem": ([str(tmp / "nope.json")], "readable problem file"),
        "malformed-problem": ([str(bad_problem)], "valid JSON"),
        "problem-without-scenario": ([str(no_scenario_file)], "scenario"),
        "unknown-example": (["--example", "nope"], "lorenzen2019"),
        "out-is-a-file": (["--trajectory", traj, "--out", str(a_file)], "is a file"),
        "zero-steps": (["--steps", "0"], "0 is not in the range"),
    }


BAD = ["missing-trajectory", "malformed-json", "not-a-trajectory", "bad-record-shape", "trajectory-of-other-problem",
       "run-option-with-trajectory", "missing-problem", "malformed-problem", "problem-without-scenario",
       "unknown-example", "out-is-a-file", "zero-steps"]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_exits_2_without_output(case, saved, tmp_path):
    args, message = _bad_inputs(tmp_path, saved)[case]
    before = sorted(p.name for p in tmp_path.rglob("*"))
    if "--out" not in args:
        args = [*args, "--out", str(tmp_path / "out")]
    result = CliRunner().invoke(main, ["certify", *args])
    assert result.exit_code == 2, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert re.search(message, result.output), result.output
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing written, nothing removed


# -- atomic writing, lazy imports --------------------------------------------------------------------
def test_interrupted_write_keeps_the_previous_bundle(saved, tmp_path, monkeypatch):
    """A failure (here: Ctrl-C while rendering the report) leaves the previous bundle untouched and no
    half-written directory behind."""
    import amcp_drake.certificate.report

    out = tmp_path / "out"
    assert invoke("--trajectory", saved["path"], "--out", out).exit_code == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(amcp_drake.certificate.report, "render_report", interrupted)
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(saved["path"]), "--out", str(out)])
    assert result.exit_code != 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    no_leftovers(tmp_path)
    fresh_out = tmp_path / "fresh"
    CliRunner().invoke(main, ["certify", "--trajectory", str(saved["path"]), "--out", str(fresh_out)])
    assert not fresh_out.exists()
    no_leftovers(tmp_path)


def test_command_module_imports_no_backend_or_plotting():
    code = ("import sys, amcp_drake.cli.certify, amcp_drake.certificate.certify\n"
            "bad = [m for m in ('pydrake', 'cvxpy', 'matplotlib') if m in sys.modules]\n"
            "assert not bad, bad\n")
    env_path = f"{ROOT}:{ROOT / 'reference'}:{ROOT / 'properties'}"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=GUARD_SECONDS,
                         env={**os.environ, "PYTHONPATH": env_path})
    assert out.returncode == 0, out.stderr


def test_interrupt_during_the_commit_still_completes_it(tmp_path, monkeypatch):
    """Ctrl-C right after the first file was moved: the remaining files are still moved, then the
    interrupt propagates; no mix of old and new files, no staging directory left."""
    import amcp_drake.certificate.report as report

    out = tmp_path / "out"
    staging = out / ".certify-staging-test"
    staging.mkdir(parents=True)
    for name in OUTPUT_FILES:
        (out / name).write_text("old")
        (staging / name).write_text("new")
    real_replace, moved = os.replace, []

    def interrupted_once(src, dst):
        real_replace(src, dst)
        moved.append(dst)
        if len(moved) == 1:
            raise KeyboardInterrupt

    monkeypatch.setattr(report.os, "replace", interrupted_once)
    with pytest.raises(KeyboardInterrupt):
        report._commit(staging, out)
    assert {p.name: p.read_text() for p in out.iterdir()} == {name: "new" for name in OUTPUT_FILES}
