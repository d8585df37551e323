"""A backend defect is reported as a backend defect: never hidden behind a checked fallback, never blamed
on the paper's claims.

Each test runs Example 1 with a Drake backend whose answers are wrong in one way (tests/tampered_backends.py,
subclasses of the real backend registered as "drake" for the test) and shows: the run is still safe (the
answer checks reject the wrong answers and a checked fallback answers); the paper's claims pass on the
applied answers; the trajectory records, step by step and as data, which answers were the backend's and
which were not; the certificate's ``solver_answers`` section and its backend-conformance line report them;
``amcp certify`` and ``amcp compare`` exit 1 naming the backend and the failed check.
"""

from __future__ import annotations

import json

import jsonschema
import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.backends import available_backends
from amcp_drake.certificate.certify import certify, schema
from amcp_drake.cli import main
from amcp_drake.model.options import OnlineOptions
from amcp_drake.online import answers
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate
from tests import tampered_backends as tb

STEPS = 8


def _run(spec, design, options=None, steps=STEPS, disturbance="uniform"):
    sc = spec.scenario
    ctrl = AdaptiveMPC(spec.problem, design, backend="drake", options=options)
    return simulate(ctrl, sc.x0, sc.theta_star, steps, disturbance, seed=0, mu_state_bound=spec.design.mu_state_bound)


def _outcomes(traj, problem):
    return [answers.of(r, problem) for r in traj.records]


def _safe(traj, cert):
    """Every step applied an input, and the paper's claims about the run hold on the applied answers."""
    assert traj.stop_reason == "completed" and len(traj.u) == STEPS
    assert all(r.u is not None for r in traj.records)
    assert cert.claim("recursive_feasibility").status == "pass"
    assert cert.claim("state_input_constraints").status == "pass"
    assert cert.claim("theta_star_in_Theta_k").status == "pass"
    assert cert.verdict == "pass", (cert.ids("fail"), cert.ids("not_run"))
    data = cert.to_dict()
    jsonschema.validate(data, schema())
    return data


def test_an_honest_run_records_every_answer_as_the_backends_own(example_spec, example_design):
    traj = _run(example_spec, example_design)
    assert all(r.answers is not None for r in traj.records)
    # the backend's own answers (a first try or its own re-solve: which one is this machine's solver's business)
    assert [e["outcome"] in ("first", "resolved") for e in _outcomes(traj, "tube_qp")] == [True] * (STEPS + 1)
    assert [e and e["outcome"] for e in _outcomes(traj, "set_update")] == [None] + ["first"] * STEPS
    cert = certify(traj, example_spec)
    data = _safe(traj, cert)
    assert data["backend_conformance"] == "pass"
    tube = data["solver_answers"]["problems"]["tube_qp"]
    assert (tube["answers"], tube["first"] + tube["resolved"], tube["fallback"], tube["not_solved"]) == (STEPS + 1,) * 2 + (0, 0)


@pytest.mark.parametrize("cls, check", [
    (tb.WrongTubeDrake, "tube "),                       # v shifted by 0.5: fails a row of (15)
    (tb.NoLambdaNBoundDrake, "tube Lambda >= 0"),       # Λ_N >= 0 dropped
    (tb.NoTerminalSetDrake, "tube terminal set"),       # the terminal constraint dropped
    (tb.WrongVertexDrake, "tube (15c)"),                # a facet judged by the wrong vertex of X0
])
def test_a_wrong_tube_qp_answer_is_a_backend_defect_not_a_failed_theorem(example_spec, example_design, monkeypatch,
                                                                         cls, check):
    tb.use_as_drake(monkeypatch, cls)
    traj = _run(example_spec, example_design)
    qp = _outcomes(traj, "tube_qp")
    # every plain-form answer was rejected by a check of (15), and the vertex form answered (checked)
    assert all(e["outcome"] == "fallback" and e["kind"] == "vertex_form" and e["check"].startswith(check)
               for e in qp), qp
    # the applied v is the vertex form's, not the shifted one: the shift never reached the plant
    for r in traj.records:
        assert r.Lambda is None and np.all(np.isfinite(r.v))
    cert = certify(traj, example_spec)
    data = _safe(traj, cert)
    assert {c["id"] for c in data["run"]["not_claimed"]} >= {"multipliers_nonneg", "multipliers_15c", "multipliers_15d"}
    assert data["backend_conformance"] == "fail" and cert.conformance == "fail"
    tube = data["solver_answers"]["problems"]["tube_qp"]
    assert (tube["first"], tube["fallback"]) == (0, STEPS + 1)
    assert tube["kinds"][0]["steps"] == list(range(STEPS + 1))
    assert data["solver_answers"]["rejected_steps"] == list(range(STEPS + 1))
    assert f"drake answered 0 of {STEPS + 1} tube QPs (20) itself" in data["solver_answers"]["summary"]


@pytest.mark.parametrize("cls, kind, check", [
    (tb.WrongSetUpdateDrake, "highs_support_lps", "set update nested h <= h_prev (10)"),
    (tb.StaleSetUpdateDrake, "highs_support_lps", "set update nested h <= h_prev (10)"),
    (tb.IgnoresLastDataRowDrake, "highs_support_lps", "set update maximisers feasible and tight"),
    (tb.ReuseIgnoresLastRowDrake, "highs_support_lps", "set update maximisers feasible and tight"),
])
def test_a_wrong_set_update_answer_is_a_backend_defect(example_spec, example_design, monkeypatch, cls, kind, check):
    tb.use_as_drake(monkeypatch, cls)
    traj = _run(example_spec, example_design)
    rejected = [e for e in _outcomes(traj, "set_update") if e is not None and e["outcome"] != "first"]
    assert rejected and all(e == answers.entry("set_update", "fallback", kind, check) for e in rejected), rejected
    if cls is tb.WrongSetUpdateDrake:  # every answer is wrong
        assert len(rejected) == STEPS
    cert = certify(traj, example_spec)
    data = _safe(traj, cert)
    assert cert.claim("Theta_k_lower_inclusion").status == "pass" and cert.claim("Theta_k_nested").status == "pass"
    assert data["backend_conformance"] == "fail"
    assert data["solver_answers"]["problems"]["set_update"]["fallback"] == len(rejected)


def test_a_wrong_projection_is_a_backend_defect(example_spec, example_design, monkeypatch):
    tb.use_as_drake(monkeypatch, tb.WrongProjectionDrake)
    # projections onto Θ_k (Remark 7) under vertex disturbances: θ̃ leaves Θ_k at steps 2, 6, 7, 8
    traj = _run(example_spec, example_design, OnlineOptions(projection="Theta_k"), disturbance="vertices")
    proj = [e for e in _outcomes(traj, "projection") if e is not None]
    assert proj and all(e["outcome"] == "fallback" and e["kind"] == "least_distance" for e in proj), proj
    cert = certify(traj, example_spec)
    _safe(traj, cert)
    # the checked least-distance projection is a projection: (12) is checked on it, not skipped
    steps = {k for k, _ in cert.claim("lms_update").data["per_step"]}
    assert {r.k for r in traj.records if answers.of(r, "projection")} <= steps
    assert cert.conformance == "fail"


def test_a_wrong_redundancy_answer_of_the_exact_update_is_a_backend_defect(example_spec, example_design, monkeypatch):
    tb.use_as_drake(monkeypatch, tb.LowSupportDrake)
    traj = _run(example_spec, example_design, OnlineOptions(update="exact"))
    exact = [e for e in _outcomes(traj, "exact_update") if e is not None]
    assert any(e["outcome"] == "fallback" and e["kind"] == "removed_rows_kept" for e in exact), exact
    cert = certify(traj, example_spec)
    _safe(traj, cert)
    assert cert.conformance == "fail"


def test_a_trajectory_without_provenance_is_reported_as_unknown_never_as_first_answers(example_spec, example_design,
                                                                                      tmp_path):
    data = _run(example_spec, example_design).to_dict()
    for r in data["records"]:
        del r["answers"]
    traj = Trajectory.from_dict(json.loads(json.dumps(data)))
    assert all(r.answers is None for r in traj.records)
    cert = certify(traj, example_spec)
    assert cert.verdict == "pass" and cert.conformance == "unknown"
    section = cert.to_dict()["solver_answers"]
    assert section["provenance"] == "unknown" and section["problems"] == {}
    assert section["summary"] == [f"provenance of the solver answers unknown at {STEPS + 1} step(s) (a trajectory "
                                  "recorded without it): whether drake answered them itself is not known"]


def test_malformed_provenance_is_a_trajectory_error_naming_the_record(example_spec, example_design):
    from amcp_drake.model.errors import TrajectoryError

    data = json.loads(json.dumps(_run(example_spec, example_design, steps=2).to_dict()))
    data["records"][1]["answers"] = [{"problem": "tube_qp", "outcome": "maybe", "kind": "", "check": ""}]
    with pytest.raises(TrajectoryError, match=r"records\[1\].*outcome"):
        Trajectory.from_dict(data)


def test_amcp_certify_exits_1_naming_the_backend_and_the_check(monkeypatch, tmp_path):
    tb.use_as_drake(monkeypatch, tb.WrongTubeDrake)
    out = tmp_path / "cert"
    result = CliRunner().invoke(main, ["certify", "--steps", "4", "--formulation", "plain", "--out", str(out)],
                                catch_exceptions=False)  # the tampered backend is the plain form's
    assert result.exit_code == 1, result.output
    assert "CERTIFIED: all" in result.output  # the paper's claims hold on the applied answers
    assert "BACKEND CONFORMANCE FAILED: drake" in result.output
    assert "drake answered 0 of 5 tube QPs (20) itself" in result.output and "failed: tube (15c)" in result.output
    data = json.loads((out / "certificate.json").read_text())
    assert data["verdict"] == "pass" and data["backend_conformance"] == "fail"
    assert 'id="backend-conformance"' in (out / "report.html").read_text()


@pytest.mark.skipif("cvxpy" not in available_backends(), reason="cvxpy backend not installed")
@pytest.mark.parametrize("cls, problem, check", [(tb.WrongTubeDrake, "tube_qp", "tube (15c)"),
                                                 (tb.WrongSetUpdateDrake, "set_update", "set update nested h")])
def test_amcp_compare_exits_1_naming_the_step_backend_and_check(monkeypatch, tmp_path, cls, problem, check):
    tb.use_as_drake(monkeypatch, cls)
    out = tmp_path / "compare.json"
    args = ["compare", "--steps", "3", "--quiet", "--formulation", "plain", "--out", str(out)]  # the plain form tampered
    result = CliRunner().invoke(main, args, catch_exceptions=False)
    assert result.exit_code == 1, result.output
    assert f"drake needed help on its {problem} answer (fallback" in result.output
    assert f"failed check: {check}" in result.output
    assert "backends DISAGREE" in result.output
    data = json.loads(out.read_text())
    assert data["agree"] is False and data["answer_mismatches"]
    assert {m["backend"] for m in data["answer_mismatches"]} == {"drake"}
    # the applied answers agree (the fallback answered): only the provenance tells the defect
    assert all(d["agree"] for d in data["differences"] if d["step"] is not None)
    accepted = CliRunner().invoke(main, [*args, "--allow-fallbacks"], catch_exceptions=False)
    assert accepted.exit_code == 0, accepted.output
    assert "accepted (--allow-fallbacks): step" in accepted.output
