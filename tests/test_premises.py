"""Premises never launder a verdict: an x_0 outside Z is a premise not met (never a failed theorem), and a
premise not met never hides a failure of the recorded data (certificate/premises.py)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.certificate.certify import certify
from amcp_drake.certificate.premises import DATA_CLAIMS, state_rows_at_x0
from amcp_drake.cli import main
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.online.simulate import Trajectory
from tests.recorded_runs import as_recorded, example_1_recorded

#: Example 1's state constraint x_2 >= −0.3 is the row (0, −10/3) x <= 1 of (4).
X2_MIN = -0.3


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
    return example_1_recorded(spec, controller, 6)


def run_from(spec, controller, x0, steps: int = 3) -> dict:
    from amcp_drake.online.simulate import simulate

    return as_recorded(simulate(controller, x0, spec.scenario.theta_star, steps, "uniform", seed=0,
                                mu_state_bound=spec.design.mu_state_bound))


def premise(cert, pid: str = "initial_feasibility") -> dict:
    return {p["id"]: p for p in cert.premises}[pid]


# -- x_0 outside Z ----------------------------------------------------------------------------------
@pytest.mark.parametrize("factor, outside", [(2.0, True), (0.5, False), (-2.0, False)])
def test_the_state_rows_of_z_at_x0_are_judged_at_their_round_off(factor, outside):
    """x_0 = (2, −0.3 − δ) against x_2 >= −0.3 with δ = factor × the round-off bound of the evaluation: twice
    outside it is outside, half of it is round-off, inside is inside; the margin is −δ (rows of unit norm)."""
    F, G = np.array([[0.0, -10.0 / 3.0], [0.0, 0.0]]), np.array([[0.0], [1.0]])
    _, tol, _ = state_rows_at_x0(F, G, np.array([2.0, X2_MIN]))
    assert 0 < tol < 1e-14
    margin, tol_here, row = state_rows_at_x0(F, G, np.array([2.0, X2_MIN - factor * tol]))
    assert row == 0 and tol_here == pytest.approx(tol, rel=1e-6)
    assert margin == pytest.approx(-factor * tol, rel=0.1)
    assert (margin < -tol_here) == outside


def test_rows_with_an_input_are_left_to_the_lp():
    """A row that involves u (here u <= 1 and x_1 + u <= 1) is not a state row: no verdict from it alone."""
    assert state_rows_at_x0(np.array([[0.0, 0.0], [1.0, 0.0]]), np.array([[1.0], [1.0]]), np.array([5.0, 5.0])) is None


def test_x0_1e_7_outside_z_is_a_premise_not_met_never_a_failed_theorem(spec, controller):
    """A real run from x_0 = (2, −0.3 − 1e-7): the QP is infeasible at step 0. The verdict is premise_not_met,
    the premise's margin is −1e-7, and recursive feasibility is not claimed (the LP's tolerance alone, 1e-6
    before, found this start "feasible" and blamed Theorem 14 (i))."""
    data = run_from(spec, controller, [2.0, X2_MIN - 1e-7])
    cert = certify(Trajectory.from_dict(data), spec)
    assert cert.verdict == "premise_not_met" and cert.ids("fail") == []
    first = premise(cert)
    assert first["status"] == "not_met" and first["margin"] == pytest.approx(-1e-7, rel=1e-6)
    assert "recursive_feasibility" in {c["id"] for c in cert.not_claimed}


def test_x0_1e_7_inside_z_is_certified(spec, controller):
    """Just inside, x_0 = (2, −0.3 + 1e-7): the premise is met and every claim holds."""
    cert = certify(Trajectory.from_dict(run_from(spec, controller, [2.0, X2_MIN + 1e-7])), spec)
    assert premise(cert)["status"] == "met"
    assert cert.verdict == "pass", [c.data["id"] for c in cert.claims if c.status != "pass"]


def test_x0_outside_z_is_a_premise_not_met_even_when_a_solver_answered_step_0(spec, controller):
    """A run from just inside Z whose x_0 is moved 2e-7 outside afterwards (u_0 = K x_0 + v_0 and w_0 adjusted so
    that the data stay consistent): step 0 has an applied answer, which a solver could return within its own
    tolerance, yet 𝔻(x_0, Θ_0) ≠ ∅ is impossible outside Z: the premise is not met, no claim fails."""
    data = run_from(spec, controller, [2.0, X2_MIN + 1e-7])
    pr = spec.problem
    x0 = np.array([2.0, X2_MIN - 1e-7])
    u0 = np.asarray(data["design"]["K"], float) @ x0 + np.asarray(data["records"][0]["v"][0], float)
    theta = np.asarray(data["theta_star"], float)
    w0 = np.asarray(data["x"][1], float) - pr.A_of(theta) @ x0 - pr.B_of(theta) @ u0
    data["x"][0] = data["records"][0]["x"] = x0.tolist()
    data["u"][0] = data["records"][0]["u"] = u0.tolist()
    data["w"][0] = w0.tolist()
    cert = certify(Trajectory.from_dict(data), spec)
    assert 0 in [r.k for r in Trajectory.from_dict(data).records if r.v is not None]
    assert {"model_consistent", "control_law", "w_in_W"} <= set(cert.ids("pass"))
    assert premise(cert)["status"] == "not_met" and premise(cert)["margin"] == pytest.approx(-1e-7, rel=1e-6)
    assert cert.verdict == "premise_not_met" and cert.ids("fail") == []


# -- a premise never hides a data failure ---------------------------------------------------------
def laundered(recorded: dict) -> dict:
    """The recorded run with K = (0, −3) (breaks Assumption 8: the premise) and x_3 moved by 0.01 in the state
    array and its record (the states no longer follow (1), and u_3 ≠ K x_3 + v_0|3)."""
    data = json.loads(json.dumps(recorded))
    data["design"]["K"] = [[0.0, -3.0]]
    data["x"][3][0] += 0.01
    data["records"][3]["x"][0] = data["x"][3][0]
    return data


def test_a_premise_not_met_never_hides_a_data_failure(recorded, spec):
    """Assumption 8 is broken by the tampered gain and the states violate (1): the premise is reported not met,
    and the data claims fail in the claims (verdict fail), never moved to "not claimed"."""
    cert = certify(Trajectory.from_dict(laundered(recorded)), spec)
    assert premise(cert, "assumption_8")["status"] == "not_met"
    assert {"model_consistent", "control_law"} <= set(cert.ids("fail"))
    assert not DATA_CLAIMS & {c["id"] for c in cert.not_claimed}
    assert cert.verdict == "fail" and not cert.passed


def test_the_laundering_tamper_exits_1_with_the_data_claim_failing(recorded, tmp_path):
    """The same file through `amcp certify --trajectory`: exit 1 (a claim failed), never 3 (premise not met)."""
    path = tmp_path / "laundered.json"
    path.write_text(json.dumps(laundered(recorded)))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(path), "--out", str(out)])
    assert result.exit_code == 1, result.output
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "fail"
    failed = {c["id"] for c in cert["claims"] if c["status"] == "fail"}
    assert "model_consistent" in failed
    assert "model_consistent" not in {c["id"] for c in cert["run"]["not_claimed"]}


def test_an_infeasible_start_never_excuses_a_design_claim(spec, controller):
    """The run from x_0 1e-7 outside Z with the recorded X0 vertex list moved by 1e-3 at one vertex: the premise
    x_0 ∈ 𝔻 is not met, but the design's claims do not rest on x_0, so the wrong vertex list fails (verdict
    fail), never "not claimed"."""
    data = run_from(spec, controller, [2.0, X2_MIN - 1e-7])
    data["design"]["X0_vertices"][0][0] += 1e-3
    cert = certify(Trajectory.from_dict(data), spec)
    assert premise(cert)["status"] == "not_met"
    assert "design.x0_vertices" in cert.ids("fail")
    assert "design.x0_vertices" not in {c["id"] for c in cert.not_claimed}
    assert cert.verdict == "fail"


# -- x_0 just outside the feasible region (inside Z) ------------------------------------------------
def qp_feasible(controller, x0) -> bool:
    """Whether the controller's QP (20) answers at x_0 on its first step (the QP decides, not the premise's LP)."""
    from amcp_drake.model.status import SolveStatus

    controller.reset()
    _, record = controller.step(np.asarray(x0, float))
    return record.status is SolveStatus.OPTIMAL


@pytest.fixture(scope="module")
def region_edge(controller) -> np.ndarray:
    """The edge of the feasible region of (20) on the line x_2 = 3 beyond x_0 = (2, 3), by bisection of the
    QP's feasibility (to 1e-11); x_2 = 3 is far inside Z (x_2 >= −0.3)."""
    inside, outside = 2.0, 40.0
    assert qp_feasible(controller, [inside, 3.0]) and not qp_feasible(controller, [outside, 3.0])
    while outside - inside > 1e-11:
        middle = 0.5 * (inside + outside)
        inside, outside = (middle, outside) if qp_feasible(controller, [middle, 3.0]) else (inside, middle)
    return np.array([0.5 * (inside + outside), 3.0])


def test_a_start_just_beyond_the_qps_edge_is_a_premise_not_met(spec, controller, region_edge):
    """A real run from x_0 1e-6 beyond the QP's own edge along x_1 (inside Z): the QP is infeasible at step 0 and
    the independent LP's slack there is a few 1e-8 below 0 (rows of unit norm; the region's boundary is shallow in
    this direction), well below −LP_TOL: the premise is not met, recursive feasibility is not failed (with the
    former LP tolerance of 1e-6 the start counted as feasible and Theorem 14 (i) was blamed)."""
    from amcp_drake.model.tolerances import PREMISE_LP_TOL as LP_TOL

    data = run_from(spec, controller, (region_edge + np.array([1e-6, 0.0])).tolist(), steps=2)
    assert len(data["records"]) == 1 and data["records"][0]["status"] != "optimal"
    cert = certify(Trajectory.from_dict(data), spec)
    first = premise(cert)
    assert first["status"] == "not_met" and -1e-6 < first["margin"] < -10 * LP_TOL, first
    assert cert.verdict == "premise_not_met" and cert.ids("fail") == []
    assert "recursive_feasibility" in {c["id"] for c in cert.not_claimed}
