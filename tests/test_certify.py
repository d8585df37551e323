"""Certificates: an honest run passes every claim; each tampering fails exactly the claims
that logically depend on the tampered quantity, and every other claim still passes.

The claims are not independent: Theorem 14 (iii) (x_k, u_k) ∈ Z, for instance, *follows* from the
tube claims, so a state outside Z must also break a tube claim. Each tampering below is chosen to
be as surgical as the mathematics allows, and its docstring says why each expected claim fails.
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from amcp_drake.certificate.certify import certify, schema
from amcp_drake.certificate.claims import theta_vertices
from amcp_drake.model.errors import TrajectoryError
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.model.status import SolveStatus
from amcp_drake.online.simulate import Trajectory
from tests.guards import GUARD_SECONDS
from tests.recorded_runs import example_1_recorded, fresh

STEPS = 8
ROOT = Path(__file__).resolve().parents[1]

#: Every claim id, in report order (docs/certificate.md lists the same ids).
ALL_IDS = [
    "design.terminal_cost_16", "design.assumption_8", "design.x0_contractive", "design.x0_robustly_invariant",
    "design.w_bar_f_bar_recomputed", "design.x_f_non_empty", "design.x_f_invariant", "design.x_f_in_z",
    "design.mu_condition_11", "design.x0_vertices",
    "theta_star_in_Theta", "w_in_W", "model_consistent", "data_consistency", "control_law", "mu_precondition",
    "recursive_feasibility", "theta_star_in_Theta_k", "theta_hat_in_Theta", "state_input_constraints",
    "Theta0_contains_Theta", "Theta_k_nested", "Theta_k_lower_inclusion",
    "lms_update", "lemma5",
    "tube_contains_state", "tube_contains_next_state", "tube_propagation", "tube_constraints", "tube_alpha_nonneg",
    "terminal_set", "multipliers_nonneg", "multipliers_15c", "multipliers_15d",
    "cost_value", "qp_optimality",
]


@pytest.fixture(scope="module")
def spec():
    return lorenzen2019_spec()


@pytest.fixture(scope="module")
def controller(spec):
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC

    return AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake")


@pytest.fixture(scope="module")
def recorded(spec, controller) -> dict:
    """An 8-step run of Example 1 (seed 0), as the JSON dict of its trajectory file."""
    return example_1_recorded(spec, controller, STEPS)


@pytest.fixture(scope="module")
def baseline(recorded, spec):
    return certify(fresh(recorded), spec)


def assert_fails_exactly(cert, expected: set[str]) -> None:
    failed = set(cert.ids("fail"))
    assert failed == expected, f"failed {sorted(failed)}, expected {sorted(expected)}"
    assert cert.ids("not_run") == [], cert.ids("not_run")
    assert set(cert.ids("pass")) == set(ALL_IDS) - expected
    assert cert.verdict == "fail" and not cert.passed


# -- the honest run -----------------------------------------------------------------------------
def test_untampered_run_passes_every_claim(baseline):
    assert baseline.ids() == ALL_IDS
    assert baseline.ids("fail") == [] and baseline.ids("not_run") == []
    assert baseline.passed and baseline.verdict == "pass"
    # the margins are real numbers with the documented meaning, not placeholders
    assert baseline.claim("lemma5").margin > 0
    assert baseline.claim("theta_star_in_Theta_k").margin == pytest.approx(0.2, abs=1e-6)  # 1 − θ*_1 (θ*_1 = 0.8)
    assert baseline.claim("state_input_constraints").margin > 0
    assert abs(baseline.claim("multipliers_15d").margin) < 1e-9
    for c in baseline.claims:
        assert c.tolerance >= 0 and c.margin >= -c.tolerance


def test_figures_show_learning(baseline):
    f = baseline.figures
    assert f["final_state_norm"] < 0.5 * f["initial_state_norm"]
    assert f["theta_width_final"][0] < f["theta_width_initial"][0]  # Θ_k shrinks in θ1
    assert f["theta_hat_error_final"] < f["theta_hat_error_initial"]
    assert len(baseline.series["lemma5_lhs"]) == STEPS


def test_certificate_json_validates_against_schema(baseline):
    data = json.loads(json.dumps(baseline.to_dict(), allow_nan=False))
    jsonschema.Draft202012Validator.check_schema(schema())
    jsonschema.validate(data, schema())
    assert [c["id"] for c in data["claims"]] == ALL_IDS
    # the schema is not vacuous: it rejects a verdict that disagrees with `passed` and unknown statuses
    bad = json.loads(json.dumps(data))
    bad["passed"] = False
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema())
    bad = json.loads(json.dumps(data))
    bad["claims"][0]["status"] = "probably"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, schema())


# -- tampering ------------------------------------------------------------------------------------
def test_theta_star_moved_outside_theta_k(recorded, spec):
    """θ* moved to a point of Θ outside Θ_T, with w_k recomputed so that the states still follow (1).

    Expected: θ* ∈ Θ_k fails, and w_k ∈ W fails: Θ_T contains Θ ∩ Δ_1 ∩ ... ∩ Δ_T (Lemma 3, whose
    inclusions still hold), so a θ outside Θ_T lies outside some Δ_k, i.e. its implied w_(k-1) ∉ W.
    Lemma 5 still holds: its proof needs only θ* ∈ Θ, (1), (12) and μ‖D‖² <= 1, not w ∈ W.
    """
    tr = fresh(recorded)
    pr, T = tr.problem, STEPS
    moved = np.array([0.2, 0.2, -0.5])
    last = tr.records[-1]
    assert np.all(pr.H_theta @ moved <= pr.h_theta) and np.max(last.H_theta @ moved - last.h_theta) > 0.1
    tr.theta_star = moved
    tr.w = np.array([tr.x[k + 1] - pr.A_of(moved) @ tr.x[k] - pr.B_of(moved) @ tr.u[k] for k in range(T)])
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"theta_star_in_Theta_k", "w_in_W"})
    assert cert.claim("theta_star_in_Theta_k").data["worst_step"] >= 1


def test_theta_k_shrunk_away_from_theta_star(recorded, spec):
    """The last set estimate Θ_T cut below θ*_1 (h row θ1 <= 0.75 < 0.8).

    Expected: θ* ∈ Θ_k fails at k = T, and the Lemma 3 inclusion Θ_(T-1) ∩ Δ_T ⊆ Θ_T fails (θ* lies in
    the left side, as the untouched data show). A smaller Θ_T still satisfies every tube claim.
    """
    tr = fresh(recorded)
    h = tr.records[-1].h_theta.copy()
    assert tr.records[-1].H_theta[0].tolist() == [1.0, 0.0, 0.0]
    h[0] = 0.75
    tr.records[-1].h_theta = h
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"theta_star_in_Theta_k", "Theta_k_lower_inclusion"})
    assert cert.claim("theta_star_in_Theta_k").data["worst_step"] == STEPS
    assert cert.claim("theta_star_in_Theta_k").margin == pytest.approx(-0.05, abs=1e-9)
    assert cert.claim("Theta_k_lower_inclusion").data["worst_step"] == STEPS


def test_state_pushed_outside_z(recorded, spec):
    """x_T pushed to x2 = x2 − 0.6 < −0.3 (outside Z), with u_T = K x_T + v_0|T kept consistent (21).

    Expected, each forced by the others holding:
    * (x_k, u_k) ∈ Z fails at T (the tampering);
    * x_T ∈ X_0|T fails: X_0|T satisfies (15a), so it lies in x2 >= −0.3;
    * x_T ∈ X_1|T-1 fails for the same reason (X_1|T-1 satisfies (15a) at l = 1);
    * the states no longer follow (1) with the recorded w_(T-1) ∈ W;
    * θ̂_T no longer follows (12): the LMS step uses x_T;
    * the recorded cost of step T is no longer (17): the nominal prediction (18) starts at x_T;
    * the recorded tube of step T is not a minimiser of the QP (20) at the new x_T: it is not even
      feasible for it ((15b) holds x_T), so qp_optimality fails on primal infeasibility.
    Θ_(T-1) ∩ Δ_T is then empty, so the Lemma 3 inclusion holds vacuously (reported in its detail), and the
    model-consistency claim fails at T. The two guarantees that rest on consistent data, (x_k, u_k) ∈ Z and
    x_T ∈ X_1|T-1, are then not run, their own check's failure at T kept in their data (found_status).
    """
    tr = fresh(recorded)
    T, last = STEPS, tr.records[-1]
    x = tr.x[T].copy()
    x[1] -= 0.6
    assert x[1] < -0.3 and np.max(np.abs(x)) <= spec.design.mu_state_bound
    tr.x[T] = x
    last.x = x.copy()
    last.u = tr.design.K @ x + last.v[0]
    cert = certify(tr, spec)
    rests = {"state_input_constraints", "tube_contains_next_state"}
    failed = {"tube_contains_state", "model_consistent", "data_consistency", "lms_update", "cost_value", "qp_optimality"}
    assert set(cert.ids("fail")) == failed and set(cert.ids("not_run")) == rests
    assert set(cert.ids("pass")) == set(ALL_IDS) - failed - rests and cert.verdict == "fail"
    assert cert.claim("data_consistency").data["first_failing_step"] == T
    assert cert.claim("qp_optimality").data["worst_step"] == T
    for claim_id in rests:
        assert cert.claim(claim_id).data["found_status"] == "fail"
    z_claim = cert.claim("state_input_constraints")
    assert z_claim.data["per_step"][-1][0] == T
    assert z_claim.data["found_margin"] == pytest.approx(1.0 + x[1] / 0.3, abs=1e-9)  # row x2 >= −0.3: −x2/0.3 <= 1
    assert cert.claim("Theta_k_lower_inclusion").data["empty_steps"] == [T]


def test_negative_multiplier_is_caught_only_by_the_sign_check(recorded, spec):
    """Λ^0_(0|3)[0, 0] made negative, with the same amount taken from Λ[0, 1] (rows +e1 and −e1 of H_θ).

    Then Λ H_θ is unchanged, so (15d) still holds, and Λ h_θ only decreases, so (15c) still holds:
    without Λ >= 0 this Λ would "prove" a false bound (the pitfall of design.md). Exactly Λ >= 0 fails.
    """
    tr = fresh(recorded)
    rec = tr.records[3]
    assert rec.H_theta[0].tolist() == [1.0, 0.0, 0.0] and rec.H_theta[1].tolist() == [-1.0, 0.0, 0.0]
    lam = rec.Lambda.copy()
    shift = lam[0, 0, 0, 0] + 0.3
    lam[0, 0, 0, 0] -= shift
    lam[0, 0, 0, 1] -= shift
    rec.Lambda = lam
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"multipliers_nonneg"})
    assert cert.claim("multipliers_nonneg").data["worst_step"] == 3
    assert cert.claim("multipliers_nonneg").margin <= -0.3 + 1e-12


def test_negative_multiplier_alone_also_breaks_15d(recorded, spec):
    """Λ^0_(0|3)[0, 0] := −0.3 alone changes Λ H_θ, so (15d) fails too; (15c) holds (h_θ,0 > 0: Λ h shrinks)."""
    tr = fresh(recorded)
    rec = tr.records[3]
    assert rec.h_theta[0] > 0
    lam = rec.Lambda.copy()
    lam[0, 0, 0, 0] = -0.3
    rec.Lambda = lam
    assert_fails_exactly(certify(tr, spec), {"multipliers_nonneg", "multipliers_15d"})


def test_theta_hat_moved_breaks_lemma5(recorded, spec):
    """θ̂_T moved (inside Θ) to [−0.9, −0.9, 0.9], far from θ*: the term (1/μ)‖θ̂_T − θ*‖² of Lemma 5
    alone exceeds the right side at m = T−1, so Lemma 5 fails; θ̂_T no longer follows (12) either
    (Lemma 5 is a consequence of (12)); the recorded cost of step T is no longer (17), whose
    nominal prediction (18) uses θ̂_T; and for the same reason the recorded v is no longer the
    minimiser of (20) at step T (qp_optimality). Nothing else uses θ̂_T."""
    tr = fresh(recorded)
    moved = np.array([-0.9, -0.9, 0.9])
    mu = tr.design.mu
    rhs = np.sum((tr.records[0].theta_hat - tr.theta_star) ** 2) / mu + np.sum(tr.w ** 2)
    assert np.sum((moved - tr.theta_star) ** 2) / mu > rhs  # the tampering must break the inequality
    tr.records[-1].theta_hat = moved
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"lemma5", "lms_update", "cost_value", "qp_optimality"})
    assert cert.claim("qp_optimality").data["worst_step"] == STEPS
    assert cert.claim("lemma5").data["worst_step"] == STEPS - 1
    assert cert.claim("cost_value").data["worst_step"] == STEPS
    assert cert.claim("lms_update").data["worst_step"] == STEPS


def test_theta_hat_moved_outside_theta(recorded, spec):
    """θ̂_T moved outside Θ (θ̂_1 = 1.05 > 1; closer to θ*_1 = 0.8 than the recorded 0.49, so Lemma 5
    still holds): θ̂_k ∈ Θ fails; θ̂_T no longer follows (12) (lms_update); the cost of step T (17)
    and the optimality of its recorded decision read θ̂_T and fail with it."""
    tr = fresh(recorded)
    moved = tr.records[-1].theta_hat.copy()
    moved[0] = 1.05
    tr.records[-1].theta_hat = moved
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"theta_hat_in_Theta", "lms_update", "cost_value", "qp_optimality"})
    assert cert.claim("theta_hat_in_Theta").data["worst_step"] == STEPS
    assert cert.claim("theta_hat_in_Theta").margin == pytest.approx(-0.05, abs=1e-12)


def test_theta_star_moved_outside_theta(recorded, spec):
    """θ* moved outside Θ (θ*_1 = 1.02 > 1), w_k recomputed so that the states still follow (1):
    θ* ∈ Θ fails (Assumption 1), θ* ∈ Θ_k fails (Θ_k ⊆ Θ_0 = Θ), and w_k ∈ W fails (Θ_T ⊇
    Θ ∩ Δ_1 ∩ … ∩ Δ_T, so a θ outside Θ_T lies outside some Δ_k: its implied w_(k−1) is outside W)."""
    tr = fresh(recorded)
    pr = tr.problem
    moved = np.array(tr.theta_star, float)
    moved[0] = 1.02
    tr.theta_star = moved
    tr.w = np.array([tr.x[k + 1] - pr.A_of(moved) @ tr.x[k] - pr.B_of(moved) @ tr.u[k] for k in range(STEPS)])
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"theta_star_in_Theta", "theta_star_in_Theta_k", "w_in_W"})
    assert cert.claim("theta_star_in_Theta").margin == pytest.approx(-0.02, abs=1e-12)


def test_theta_0_recorded_smaller_than_theta(recorded, spec):
    """The recorded Θ_0 cut to θ_1 <= 0.95 (Θ = [−1, 1]³; θ*_1 = 0.8 stays inside): the premise of
    Lemma 3, Θ ⊆ Θ_0, fails; Θ_1 (θ_1 <= 1) is no longer inside the recorded Θ_0 (nesting (10)); the
    QP of step 0 rebuilt with the recorded Θ_0 is another program, for which the recorded decision
    is not optimal. The tube claims still hold: (15c)-(15d) on a smaller Θ_0 are weaker."""
    tr = fresh(recorded)
    assert tr.records[0].H_theta[0].tolist() == [1.0, 0.0, 0.0]
    h = tr.records[0].h_theta.copy()
    h[0] = 0.95
    tr.records[0].h_theta = h
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"Theta0_contains_Theta", "Theta_k_nested", "qp_optimality"})
    assert cert.claim("Theta0_contains_Theta").margin == pytest.approx(-0.05, abs=1e-9)
    assert cert.claim("qp_optimality").data["worst_step"] == 0


def test_tube_no_longer_contains_state(recorded, spec):
    """X_0|3 = {z_0} ⊕ α_0 X0 shrunk towards its vertex farthest from x_3 (z_0 shifted, α_0 scaled by 0.3),
    with Λ_0|3 replaced by the same convex combinations of the recorded multipliers.

    The new cross-section lies inside the old one and its vertices are convex combinations of the old
    vertices, so (5b), (5c), (15c), (15d) and Λ >= 0 all still hold; only x_3 ∈ X_0|3 (15b) fails, and
    with it the optimality of the recorded decision of step 3 for (20), which it no longer satisfies.
    """
    tr = fresh(recorded)
    k, s = 3, 0.3
    rec = tr.records[k]
    X0v = np.asarray(tr.design.X0_vertices)
    verts = rec.z[0] + rec.alpha[0] * X0v
    far = int(np.argmax(np.linalg.norm(verts - tr.x[k], axis=1)))
    z, alpha, lam = rec.z.copy(), rec.alpha.copy(), rec.Lambda.copy()
    z[0] = (1 - s) * verts[far] + s * rec.z[0]
    alpha[0] = s * rec.alpha[0]
    lam[0] = (1 - s) * rec.Lambda[0, far][None] + s * rec.Lambda[0]
    rec.z, rec.alpha, rec.Lambda = z, alpha, lam
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"tube_contains_state", "qp_optimality"})
    assert cert.claim("tube_contains_state").data["worst_step"] == k
    assert cert.claim("qp_optimality").data["worst_step"] == k


def test_a_recorded_x0_vertex_off_the_vertex_fails_the_vertex_list(recorded, spec):
    """The QP's vertex list x^1..x^v of (14) with x^1 moved outwards by 0.1 % (it is then no vertex
    of X0 = {H_x x <= 1}): the vertex-list claim fails, and so do the claims that read x^j from the
    record, i.e. (15c) and (15d) recomputed with the recorded Λ^j and the moved x^1, and the
    optimality of the recorded decision (its rows are rebuilt from the same list). Every claim that
    works on X0's vertices recomputed by Qhull still passes."""
    data = json.loads(json.dumps(recorded))
    data["design"]["X0_vertices"][0] = [1.001 * v for v in data["design"]["X0_vertices"][0]]
    cert = certify(Trajectory.from_dict(data), spec)
    assert_fails_exactly(cert, {"design.x0_vertices", "multipliers_15c", "multipliers_15d", "qp_optimality"})
    assert cert.claim("design.x0_vertices").margin == pytest.approx(
        -1e-3 * np.linalg.norm(recorded["design"]["X0_vertices"][0]), rel=1e-6)


@pytest.mark.parametrize("t", [1e-4, 1e8])
def test_a_run_in_micro_or_mega_units_passes_every_claim(t):
    """Example 1 written in states x̃ = t x (x0, the disturbances and design.mu_state_bound with it):
    the design in those units, an 8-step run and its certificate, which passes every claim. An
    absolute tolerance of 1e-8 on the X0 vertex-list claim fails at t = 1e8 (vertices of size 3e7), and a
    design that is not unit-free gives another design (t = 1e-4) or none (t = 1e8)."""
    from dataclasses import replace

    from amcp_drake.model.state_units import scale_states
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence, simulate

    spec = lorenzen2019_spec()
    T = np.full(spec.problem.n, t)
    problem = scale_states(spec.problem, T)
    options = replace(spec.design, mu_state_bound=spec.design.mu_state_bound * t)
    scaled = replace(spec, problem=problem, design=options)
    w = disturbance_sequence(spec.problem, "uniform", STEPS, 0) * T
    traj = simulate(AdaptiveMPC(problem, design(problem, options, backend="drake"), backend="drake"),
                    T * np.asarray(spec.scenario.x0), spec.scenario.theta_star, STEPS, w,
                    mu_state_bound=options.mu_state_bound)
    cert = certify(traj, scaled)
    assert cert.ids("fail") == [] and cert.ids("not_run") == []
    assert cert.ids() == ALL_IDS and cert.passed


def test_failed_qp_fails_recursive_feasibility(recorded, spec):
    """A run whose QP failed at step 5 (the loop stops there, as simulate does): exactly recursive
    feasibility fails; steps 0-4 are still checked and pass."""
    tr = fresh(recorded)
    k = 5
    tr.records = tr.records[:k + 1]
    rec = tr.records[k]
    rec.status = SolveStatus.INFEASIBLE
    rec.u = rec.v = rec.z = rec.alpha = rec.Lambda = rec.cost = None
    tr.x, tr.u, tr.w = tr.x[:k + 1], tr.u[:k], tr.w[:k]
    tr.stop_reason = f"step {k}: status infeasible"
    cert = certify(tr, spec)
    assert_fails_exactly(cert, {"recursive_feasibility"})
    feas = cert.claim("recursive_feasibility")
    assert feas.data["worst_step"] == k and feas.margin == -1.0


def test_an_infeasible_start_is_a_premise_not_met_never_a_failed_theorem(spec, controller):
    """A real run that is infeasible at k = 0 (x0 = (0, −1) violates x2 >= −0.3, so no tube around it fits in Z):
    Theorem 14 assumes 𝔻(x_0, Θ_0) ≠ ∅, so the verdict is premise_not_met (not fail, not pass), the independent LP
    margin is negative, recursive feasibility and the claims about steps that never happened are not claimed."""
    from amcp_drake.online.simulate import simulate

    traj = simulate(controller, [0.0, -1.0], spec.scenario.theta_star, 3, "uniform", seed=0,
                    mu_state_bound=spec.design.mu_state_bound)
    assert len(traj.records) == 1 and traj.records[0].status is not SolveStatus.OPTIMAL
    cert = certify(traj, spec)
    assert cert.verdict == "premise_not_met" and not cert.passed
    assert cert.ids("fail") == [] and cert.ids("not_run") == []
    [premise] = cert.premises_not_met
    assert premise["id"] == "initial_feasibility" and premise["margin"] < -1e-3
    assert "amcp coverage" in premise["hint"]
    unclaimed = {c["id"]: c["reason"] for c in cert.not_claimed}
    assert {"recursive_feasibility", "w_in_W", "lemma5", "tube_propagation", "multipliers_15c"} <= set(unclaimed)
    assert unclaimed["recursive_feasibility"] == "premise not met: initial feasibility"
    assert "recursive_feasibility" not in cert.ids()
    jsonschema.validate(cert.to_dict(), schema())


def test_an_unsolved_first_step_from_a_feasible_start_fails_theorem_14(recorded, spec):
    """Step 0 recorded as infeasible although x0 = (2, 3) is inside the feasible region (the recorded run solved it):
    the premise is met (the LP margin is positive) and recursive feasibility fails: a premise is never used to
    excuse a QP that should have been solved."""
    tr = fresh(recorded)
    tr.records = tr.records[:1]
    rec = tr.records[0]
    rec.status = SolveStatus.INFEASIBLE
    rec.u = rec.v = rec.z = rec.alpha = rec.Lambda = rec.cost = None
    tr.x, tr.u, tr.w = tr.x[:1], tr.u[:0], tr.w[:0]
    tr.stop_reason = "step 0: status infeasible"
    cert = certify(tr, spec)
    assert cert.verdict == "fail" and cert.claim("recursive_feasibility").status == "fail"
    first = {p["id"]: p for p in cert.premises}["initial_feasibility"]
    assert first["status"] == "met" and first["margin"] > 0


@pytest.mark.parametrize("factor, verdict", [(2.0, "premise_not_met"), (0.5, "fail")])
def test_the_initial_feasibility_premise_at_its_edge(recorded, spec, monkeypatch, factor, verdict):
    """The premise's threshold alone: step 0 recorded unsolved and the independent LP's slack stubbed to
    −factor × LP_TOL (the LP itself is checked against the QP on whole regions by tests/test_coverage.py). Outside
    the tolerance the premise is not met; inside it the start counts as feasible and the unsolved step is a failed
    Theorem 14 (i)."""
    from amcp_drake.certificate.feasible_region import TubeLP
    from amcp_drake.model.tolerances import PREMISE_LP_TOL as LP_TOL

    assert LP_TOL <= 1e-8  # a start 1e-7 outside the feasible region is never within it
    monkeypatch.setattr(TubeLP, "margin", lambda self, x0, options=None: -factor * LP_TOL)
    tr = fresh(recorded)
    tr.records = tr.records[:1]
    rec = tr.records[0]
    rec.status = SolveStatus.INFEASIBLE
    rec.u = rec.v = rec.z = rec.alpha = rec.Lambda = rec.cost = None
    tr.x, tr.u, tr.w = tr.x[:1], tr.u[:0], tr.w[:0]
    tr.stop_reason = "step 0: status infeasible"
    cert = certify(tr, spec)
    first = {p["id"]: p for p in cert.premises}["initial_feasibility"]
    assert first["tolerance"] == LP_TOL and first["margin"] == -factor * LP_TOL
    assert first["status"] == ("not_met" if verdict == "premise_not_met" else "met")
    assert cert.verdict == verdict


def test_a_design_breaking_11_is_a_premise_not_met(recorded, spec, baseline):
    """The recorded design's μ raised until 1 − μ sup‖D‖² = −0.1 (a user's design breaking (11)): the verdict is
    premise_not_met, the (11) check is a premise with that margin, and the run claims it breaks (Lemma 5,
    (12) with the recorded θ̂) are not claimed, never failed."""
    data = json.loads(json.dumps(recorded))
    margin = baseline.claim("design.mu_condition_11").margin
    sup = (1.0 - margin) / data["design"]["mu"]          # from the passing run: 1 − μ sup = margin
    data["design"]["mu"] = 1.1 / sup
    cert = certify(Trajectory.from_dict(data), spec)
    assert cert.verdict == "premise_not_met" and not cert.passed and cert.ids("fail") == []
    [premise] = cert.premises_not_met
    assert premise["id"] == "mu_condition_11" and premise["margin"] == pytest.approx(-0.1, rel=1e-9)
    assert "design.mu_condition_11" not in cert.ids()
    assert all(c["reason"] == "premise not met: mu condition (11)" for c in cert.not_claimed)
    jsonschema.validate(cert.to_dict(), schema())


@pytest.mark.parametrize("shift, status", [(0.0, "not_met"), (-1e-12, "met"), (1e-12, "not_met")])
def test_the_11_premise_is_strict(recorded, spec, shift, status):
    """(11) is strict, 1/μ > sup‖D‖²: the certificate's own re-check of a recorded μ with μ·sup‖D‖² = 1 exactly
    (margin 0) finds the premise not met, as just outside (1 + 1e-12); just inside (1 − 1e-12) it is met."""
    from amcp_drake.offline.result import regressor_bound

    data = json.loads(json.dumps(recorded))
    sup, _ = regressor_bound(spec.problem, spec.design.mu_state_bound)
    mu = 1.0 / sup
    for _ in range(8):  # the float μ on the boundary (a few ulps from 1/sup)
        if 1.0 - mu * sup == 0.0:
            break
        mu = float(np.nextafter(mu, np.inf if mu * sup < 1.0 else -np.inf))
    assert 1.0 - mu * sup == 0.0
    data["design"]["mu"] = mu * (1.0 + shift)
    cert = certify(Trajectory.from_dict(data), spec)
    premise = {p["id"]: p for p in cert.premises}["mu_condition_11"]
    assert premise["status"] == status, premise
    assert premise["margin"] == pytest.approx(-shift, abs=1e-15)
    assert (cert.verdict == "premise_not_met") == (status == "not_met")


def test_a_design_breaking_assumption_8_is_a_premise_not_met(recorded, spec):
    """The run replayed with K = (0, −3) (a user's gain; A_cl has spectral radius 1.12 at a vertex of Θ) on the
    recorded v_0|k and w_k, so that the file is consistent (u_k = K x_k + v_0|k, the states follow (1)):
    Assumption 8 is a premise not met, the data claims pass, and every claim built on that K that fails
    ((16), X0, X_f, the tubes) is not claimed, never failed."""
    data = replayed_with_gain(recorded, spec, [[0.0, -3.0]])
    cert = certify(Trajectory.from_dict(data), spec)
    assert cert.verdict == "premise_not_met" and cert.ids("fail") == []
    [premise] = cert.premises_not_met
    A0, B0 = np.asarray(spec.problem.A0), np.asarray(spec.problem.B0)
    radius = max(float(np.max(np.abs(np.linalg.eigvals(spec.problem.A_of(t) + spec.problem.B_of(t) @ np.array([[0.0, -3.0]])))))
                 for t in theta_vertices(spec.problem.H_theta, spec.problem.h_theta))
    assert radius > 1.0 and A0.shape == (2, 2) and B0.shape == (2, 1)
    assert premise["id"] == "assumption_8" and premise["margin"] == pytest.approx(1.0 - radius, abs=1e-12)
    assert {"model_consistent", "control_law", "w_in_W", "theta_star_in_Theta"} <= set(cert.ids("pass"))
    unclaimed = {c["id"] for c in cert.not_claimed}
    assert "design.terminal_cost_16" in unclaimed


def replayed_with_gain(recorded: dict, spec, K: list[list[float]]) -> dict:
    """A copy of ``recorded`` whose design gain is ``K`` and whose inputs and states are replayed with it on the
    recorded v_0|k, θ* and w_k: u_k = K x_k + v_0|k and x_(k+1) by (1), in the arrays and the records alike."""
    data = json.loads(json.dumps(recorded))
    data["design"]["K"] = K
    Km, pr = np.asarray(K, float), spec.problem
    x = [np.asarray(data["x"][0], float)]
    for k, rec in enumerate(data["records"]):
        rec["x"] = x[k].tolist()
        if rec.get("v") is None:
            continue
        u = Km @ x[k] + np.asarray(rec["v"][0], float)
        rec["u"] = u.tolist()
        if k < len(data["u"]):
            data["u"][k] = u.tolist()
            x.append(pr.step(x[k], u, np.asarray(data["theta_star"], float), np.asarray(data["w"][k], float)))
    data["x"] = [xk.tolist() for xk in x]
    return data


def test_not_run_is_not_a_pass(recorded):
    """Without the μ box (Z is unbounded in x) the (11) design check cannot run: the verdict is
    'incomplete', not 'pass', although no claim failed. The box travels with the trajectory twice (the
    run's and the design's record); both are removed."""
    tr = fresh(recorded)
    assert tr.mu_state_bound is not None and tr.design.mu_state_bound is not None
    tr.mu_state_bound = None
    tr.design = dataclasses.replace(tr.design, mu_state_bound=None)
    cert = certify(tr)  # no problem spec either
    assert cert.ids("fail") == []
    assert cert.ids("not_run") == ["design.mu_condition_11"]
    assert cert.claim("design.mu_condition_11").margin is None
    assert cert.verdict == "incomplete" and not cert.passed
    assert cert.to_dict()["passed"] is False


# -- malformed input ---------------------------------------------------------------------------------
@pytest.mark.parametrize("tamper, message", [
    (lambda d: d["records"][2].update(Lambda=[[0.0]]), r"records\[2\]\.Lambda has shape"),
    (lambda d: d["x"][3].__setitem__(0, float("nan")), r"x has NaN"),
    (lambda d: d["records"][4]["x"].__setitem__(1, 9.0), r"records\[4\]\.x differs from x\[4\]"),
    (lambda d: d.update(u=d["u"][:-2]), r"x: expected 7 states \(one more than the 6 inputs in u\); received 9 states"),
    (lambda d: d["records"][1].update(k=7), r"records\[1\]\.k: expected 1 \(records are numbered 0, 1, \.\.\. in order\); received 7"),
], ids=["Lambda-shape", "nan-state", "duplicate-mismatch", "missing-inputs", "step-index"])
def test_malformed_trajectory_raises(recorded, tamper, message):
    data = json.loads(json.dumps(recorded))
    tamper(data)
    with pytest.raises(TrajectoryError, match=message):
        certify(Trajectory.from_dict(data))


def test_problem_spec_must_match_the_trajectory(recorded, spec):
    other = spec.problem.with_changes(R=[[2.0]])
    from amcp_drake.model.problem import ProblemSpec

    with pytest.raises(TrajectoryError, match="different problem"):
        certify(fresh(recorded), ProblemSpec(other, spec.design, spec.scenario))


# -- helpers and independence ------------------------------------------------------------------------
def test_theta_vertices_of_flat_sets():
    """Flat Θ_k (exact update with disturbances at vertices of W) are enumerated in their affine hull."""
    H = np.vstack([np.eye(3), -np.eye(3)])
    square = theta_vertices(H, np.array([1, 1, 0.5, 1, 1, -0.5]))
    assert sorted(map(tuple, np.round(square, 12))) == [(-1, -1, 0.5), (-1, 1, 0.5), (1, -1, 0.5), (1, 1, 0.5)]
    segment = theta_vertices(H, np.array([0.2, 1, 0.5, -0.2, 1, -0.5]))
    assert sorted(map(tuple, np.round(segment, 12))) == [(0.2, -1, 0.5), (0.2, 1, 0.5)]
    point = theta_vertices(H, np.array([0.2, 0.1, 0.5, -0.2, -0.1, -0.5]))
    np.testing.assert_allclose(point, [[0.2, 0.1, 0.5]], atol=1e-12)
    assert theta_vertices(H, np.array([0.2, 0.1, 0.5, -0.3, -0.1, -0.5])) is None  # empty


def test_certify_runs_without_any_backend(recorded, tmp_path):
    """The certificate never uses the backend that ran the loop: it passes with Drake and cvxpy made
    unimportable."""
    path = fresh(recorded).save(tmp_path / "t.json.gz")
    code = (
        "import sys\n"
        "sys.modules['pydrake'] = None\nsys.modules['cvxpy'] = None\n"
        "from amcp_drake.online.simulate import Trajectory\nfrom amcp_drake.certificate.certify import certify\n"
        f"c = certify(Trajectory.load({str(path)!r}))\n"
        "assert not any(m.startswith(('pydrake', 'cvxpy')) and sys.modules[m] for m in sys.modules)\n"
        "print(c.verdict)\n"
    )
    env_path = f"{ROOT}:{ROOT / 'reference'}:{ROOT / 'properties'}"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=GUARD_SECONDS,
                         env={**os.environ, "PYTHONPATH": env_path})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "pass"


def test_a_loose_solver_is_not_trusted(spec, monkeypatch):
    """SCS (first-order, default accuracy ~1e-4) reports every step as optimal. The controller's answer
    checks refuse it (status inaccurate, the failed row in the detail; the vertex form with SCS fails too,
    so the run stops). With those checks switched off, the certificate does not take the solver's word
    either: the recomputed residuals violate the tube and multiplier claims by more than QP_TOL, and the
    verdict is fail although recursive feasibility (the solver's own status) passes."""
    from amcp_drake.model.status import SolveStatus
    from amcp_drake.offline.design import design
    from amcp_drake.online import answer_checks
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    d = design(spec.problem, spec.design, backend="drake")
    sc = spec.scenario
    traj = simulate(AdaptiveMPC(spec.problem, d, backend="drake", solver="scs"), sc.x0, sc.theta_star, 5, "uniform",
                    seed=0, mu_state_bound=spec.design.mu_state_bound)
    first = traj.records[0]
    assert first.status is SolveStatus.INACCURATE and first.u is None
    from amcp_drake.online import answers

    e = answers.of(first, "tube_qp")            # the vertex form with SCS was tried and refused too
    assert (e["outcome"], e["kind"]) == ("not_solved", "vertex_form") and e["check"], e
    assert certify(traj, spec).claim("recursive_feasibility").status == "fail"

    monkeypatch.setattr(answer_checks, "failures", lambda checks: [])  # the controller trusts the solver
    traj = simulate(AdaptiveMPC(spec.problem, d, backend="drake", solver="scs"), sc.x0, sc.theta_star, 5, "uniform",
                    seed=0, mu_state_bound=spec.design.mu_state_bound)
    assert traj.all_solved  # the solver claims success everywhere
    cert = certify(traj, spec)
    assert cert.claim("recursive_feasibility").status == "pass"
    failed = set(cert.ids("fail"))
    assert {"tube_propagation", "multipliers_15c"} <= failed, sorted(failed)
    assert cert.verdict == "fail"


def test_robust_baseline_is_not_certified_for_the_adaptive_claims(spec):
    """Update mode 'none' (Θ_k ≡ Θ_0, θ̂_k ≡ θ̂0) makes no claim about (12) or Lemma 5: those are listed
    as not claimed, with the reason, and are not among the checked claims; its Theorem 14 and tube
    claims are checked and hold, so its verdict is pass."""
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake",
                       options=OnlineOptions(update="none"))
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, 5, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)
    cert = certify(traj, spec)
    assert cert.ids("fail") == [] and cert.ids("not_run") == []
    assert [c["id"] for c in cert.not_claimed] == ["mu_precondition", "lms_update", "lemma5"]
    assert all("robust baseline" in c["reason"] for c in cert.not_claimed)
    assert not {"mu_precondition", "lms_update", "lemma5"} & set(cert.ids())
    assert cert.claim("Theta_k_nested").status == "pass" and cert.claim("tube_propagation").status == "pass"
    assert cert.verdict == "pass"
    jsonschema.validate(json.loads(json.dumps(cert.to_dict(), allow_nan=False)), schema())


# -- known answers: the vectorised checks against plain loops -----------------------------------------
def test_propagation_margin_matches_a_brute_force_loop(recorded, spec, baseline):
    """tube_propagation's worst margin equals a plain loop over l, vertices of X_(l|k), Θ_k and W."""
    from amcp_drake.model import polytope

    tr = fresh(recorded)
    pr, d = tr.problem, tr.design
    X0v = polytope.vertices(d.H_x, np.ones(len(d.H_x)))
    W_v = pr.w_vertices()
    worst = {}
    for rec in tr.records:
        theta_v = polytope.vertices(rec.H_theta, rec.h_theta)
        margin = np.inf
        for l in range(pr.N):
            for xv in X0v:
                x = rec.z[l] + rec.alpha[l] * xv
                u = d.K @ x + rec.v[l]
                for th in theta_v:
                    for w in W_v:
                        image = pr.A_of(th) @ x + pr.B_of(th) @ u + w
                        margin = min(margin, rec.alpha[l + 1] - np.max(d.H_x @ (image - rec.z[l + 1])))
        worst[rec.k] = margin
    claim = baseline.claim("tube_propagation")
    assert dict((k, v) for k, v in claim.data["per_step"]) == pytest.approx(worst, abs=1e-12)
    assert claim.margin == pytest.approx(min(worst.values()), abs=1e-12)


def test_lemma5_series_matches_direct_sums(recorded, baseline):
    """Both sides of Lemma 5 at every m equal the sums written out term by term."""
    tr = fresh(recorded)
    pr, mu, star = tr.problem, tr.design.mu, tr.theta_star
    hats = [r.theta_hat for r in tr.records]
    lhs, rhs = [], []
    for m in range(STEPS):
        x_tilde = [pr.A_of(star) @ tr.x[k] + pr.B_of(star) @ tr.u[k]
                   - (pr.A_of(hats[k]) @ tr.x[k] + pr.B_of(hats[k]) @ tr.u[k]) for k in range(m + 1)]
        lhs.append(np.sum((hats[m + 1] - star) ** 2) / mu + sum(float(v @ v) for v in x_tilde))
        rhs.append(np.sum((hats[0] - star) ** 2) / mu + sum(float(tr.w[k] @ tr.w[k]) for k in range(m + 1)))
    assert baseline.series["lemma5_lhs"] == pytest.approx(lhs, abs=1e-12)
    assert baseline.series["lemma5_rhs"] == pytest.approx(rhs, abs=1e-12)
    assert baseline.claim("lemma5").margin == pytest.approx(min(np.array(rhs) - np.array(lhs)), abs=1e-12)


def test_regression_campaign_0_126_lower_inclusion_with_short_delta_rows():
    """The 200-problem campaign (seed 0, problem 126: vertex disturbances, Δ rows of norm 7e-3) once
    failed Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1} by 2.7e-6 because the check's LPs ran on unnormalised rows."""
    from pathlib import Path

    import numpy as np

    from amcp_drake.certificate.certify import certify
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.simulate import Trajectory

    data = Path(__file__).parent / "data"
    traj = Trajectory.load(data / "campaign-0-126-trajectory.json.gz")
    spec = load_spec(data / "campaign-0-126-problem.json")
    claims = {c.name: c for c in certify(traj, spec).claims}
    inclusion = claims["Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1}"]
    assert inclusion.status == "pass", inclusion.margin
    # and the check still has teeth on this run: cut Θ_{k+1} at the worst step by 1e-5 in every row
    k = inclusion.data["worst_step"]
    traj.records[k].h_theta = np.asarray(traj.records[k].h_theta) - 1e-5
    assert {c.name: c for c in certify(traj, spec).claims}["Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1}"].status == "fail"


#: Sizes of the memory test of the tube certificate: vertices of the X0 polygon and of W, and the most
#: bytes the checks may allocate (chunks of 16 MiB; forming every (vertex of X_(l|k), vertex of Θ_k,
#: vertex of W, row) at once and every pairwise distance of the vertex list needed 553 MiB).
MEMORY_X0_VERTICES = 300
MEMORY_W_VERTICES = 50
TUBE_CERTIFICATE_BYTES = 48 * 2**20


def test_tube_certificate_memory_does_not_multiply_the_vertex_counts(spec, controller):
    """tube propagation (5b) takes the largest over W row by row (max_w [H_x]_i w, exact) and the vertices of
    X_(l|k) in chunks; the X0 vertex list compares the two sets in chunks: neither forms an array of the product of
    the vertex counts of X0, Θ_k and W (a generated 6-state design with 3,975 vertices of X0, 8 of Θ and 95 of W
    needed 4 GiB per prediction step). Checked against a loop over W here."""
    import tracemalloc
    from types import SimpleNamespace

    from amcp_drake.certificate.tube import _propagation_margin, x0_vertex_list
    from amcp_drake.model import polytope

    pr, d0 = spec.problem, controller.design
    angles = 2 * np.pi * np.arange(MEMORY_X0_VERTICES) / MEMORY_X0_VERTICES
    H_x = np.column_stack([np.cos(angles), np.sin(angles)]) / 0.5
    X0v = polytope.vertices(H_x, np.ones(len(H_x)))
    design = dataclasses.replace(d0, H_x=H_x, X0_vertices=X0v)
    view = SimpleNamespace(problem=pr, design=design)
    rng = np.random.default_rng(3)
    W_v = rng.uniform(-0.1, 0.1, (MEMORY_W_VERTICES, pr.n))
    w_bar = np.max(H_x @ W_v.T, axis=1)
    N = 2
    z, alpha, v = rng.uniform(-0.5, 0.5, (N + 1, pr.n)), rng.uniform(0.1, 1.0, N + 1), rng.uniform(-0.2, 0.2, (N, pr.m))
    step = SimpleNamespace(N=N, z=z, alpha=alpha, v=v, vertices=lambda l: z[l] + alpha[l] * X0v)
    theta_v = polytope.vertices(pr.H_theta, pr.h_theta)
    tracemalloc.start()
    try:
        margin = _propagation_margin(view, step, theta_v, W_v, w_bar)
        vertex_list = x0_vertex_list(view)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    expected = np.inf
    for l in range(N):
        X = z[l] + alpha[l] * X0v
        U = X @ d0.K.T + v[l]
        for th in theta_v:
            images = X @ pr.A_of(th).T + U @ pr.B_of(th).T - z[l + 1]
            for w in W_v:
                expected = min(expected, alpha[l + 1] - float(np.max((images + w) @ H_x.T)))
    assert margin == pytest.approx(expected, abs=1e-12)
    assert vertex_list.passed
    assert peak < TUBE_CERTIFICATE_BYTES, f"the tube certificate allocated {peak / 2**20:.0f} MiB"
