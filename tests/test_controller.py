"""The online loop (docs/explanation/paper.md §2-§4, §6) on named reference problems whose answers are
computed by hand in the test, on Example 1, and its failure behaviour."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize

from amcp_drake.model.errors import InconsistentDataError, ProblemError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import DesignOptions
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate

from .conftest import scalar_problem

#: Clarabel solves to ~1e-8; answers computed by hand are exact.
SOLVER_TOL = 1e-6


@pytest.fixture(scope="module")
def scalar():
    problem = scalar_problem()
    return problem, design(problem, DesignOptions(x0_facets=2))


def test_scalar_set_update_and_lms_match_the_hand_computation(scalar):
    problem, d = scalar
    ctrl = AdaptiveMPC(problem, d)
    x0 = 1.5
    u0, rec0 = ctrl.step(np.array([x0]))
    assert rec0.status is SolveStatus.OPTIMAL
    x1 = (0.5 + 0.2 * 0.6) * x0 + u0[0] + 0.03  # θ* = 0.6, w = 0.03
    _, rec1 = ctrl.step(np.array([x1]))
    # by hand: x1 - 0.5 x0 - u0 - w = 0.2 θ x0 with |w| <= 0.1
    lo = (x1 - 0.5 * x0 - u0[0] - 0.1) / (0.2 * x0)
    hi = (x1 - 0.5 * x0 - u0[0] + 0.1) / (0.2 * x0)
    assert rec1.set_status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(rec1.h_theta, [min(hi, 1.0), -max(lo, -1.0)], atol=SOLVER_TOL)
    # projected LMS (12) by hand: θ̃ = θ̂ + μ D (x1 - x̂1), D = 0.2 x0, x̂1 = (0.5 + 0.2 θ̂) x0 + u0
    theta_tilde = 0.0 + d.mu * 0.2 * x0 * (x1 - 0.5 * x0 - u0[0])
    assert rec1.theta_hat[0] == pytest.approx(np.clip(theta_tilde, -1, 1), abs=1e-12)


def test_scalar_qp_optimum_equals_the_unconstrained_lq_optimum_when_constraints_are_slack(scalar):
    problem, d = scalar
    ctrl = AdaptiveMPC(problem, d)
    x0 = 0.4
    _, rec = ctrl.step(np.array([x0]))
    K, P, N = d.K[0, 0], d.P[0, 0], problem.N
    a, b = 0.5, 1.0  # A(θ̂0), B(θ̂0) with θ̂0 = 0

    def cost(v):  # (17)-(18) written out by hand
        x, total = x0, 0.0
        for l in range(N):
            u = K * x + v[l]
            total += x * x + u * u
            x = a * x + b * u
        return total + P * x * x

    best = minimize(cost, np.zeros(N), method="BFGS", options={"gtol": 1e-12})
    assert rec.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(rec.v.ravel(), best.x, atol=1e-5)
    assert rec.cost == pytest.approx(best.fun, abs=1e-7)


def test_scalar_tube_contains_the_state_and_is_robust(scalar):
    problem, d = scalar
    ctrl = AdaptiveMPC(problem, d)
    _, rec = ctrl.step(np.array([2.0]))
    z, alpha, v = rec.z[:, 0], rec.alpha, rec.v[:, 0]
    lo0, hi0 = z[0] + alpha[0] * d.X0_vertices.min(), z[0] + alpha[0] * d.X0_vertices.max()
    assert lo0 - SOLVER_TOL <= 2.0 <= hi0 + SOLVER_TOL
    # every vertex of X_{l|k}, every θ ∈ {-1, 1}, every w ∈ {-0.1, 0.1} lands in X_{l+1|k}
    for l in range(problem.N):
        for xj in d.X0_vertices[:, 0]:
            x = z[l] + alpha[l] * xj
            for theta in (-1.0, 1.0):
                for w in (-0.1, 0.1):
                    nxt = (0.5 + 0.2 * theta) * x + (d.K[0, 0] * x + v[l]) + w
                    assert z[l + 1] + alpha[l + 1] * d.X0_vertices.min() - SOLVER_TOL <= nxt
                    assert nxt <= z[l + 1] + alpha[l + 1] * d.X0_vertices.max() + SOLVER_TOL


def test_example_1_closed_loop_meets_the_issue_3_claims(example_spec, example_run):
    traj = example_run
    pr, theta_star = example_spec.problem, example_spec.scenario.theta_star
    assert traj.stop_reason == "completed" and traj.steps == 50
    assert all(r.status is SolveStatus.OPTIMAL for r in traj.records)
    assert max(pr.in_Z(x, u) for x, u in zip(traj.x, traj.u)) <= 1e-9
    for r in traj.records:
        assert np.max(r.H_theta @ theta_star - r.h_theta) <= 1e-9, f"θ* left Θ_{r.k}"
    h = np.array([r.h_theta for r in traj.records])
    assert np.all(np.diff(h, axis=0) <= 1e-7), "Θ_k grew"
    widths = h[:, 0::2] + h[:, 1::2]  # box Θ: rows (e_i, -e_i) give interval widths
    assert widths[-1].sum() < widths[0].sum() - 0.5
    assert np.max(np.abs(traj.x)) <= example_spec.design.mu_state_bound  # Lemma 5 precondition region
    assert all("solver" in r.times and "total" in r.times for r in traj.records)


def test_exact_update_is_inside_the_fixed_complexity_set(example_spec, example_design):
    from amcp_drake.model import polytope

    sc = example_spec.scenario
    runs = {}
    for mode in ("fixed", "exact"):
        ctrl = AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(update=mode))
        runs[mode] = simulate(ctrl, sc.x0, sc.theta_star, 12, "uniform", seed=3)
    fixed, exact = runs["fixed"].records[-1], runs["exact"].records[-1]
    assert np.max(exact.H_theta @ sc.theta_star - exact.h_theta) <= 1e-9
    verts = polytope.vertices(exact.H_theta, exact.h_theta)
    assert np.max(fixed.H_theta @ verts.T - fixed.h_theta[:, None]) <= 1e-6
    assert len(exact.h_theta) > len(fixed.h_theta)


def test_window_of_one_equals_the_fixed_complexity_update(example_spec, example_design):
    sc = example_spec.scenario
    runs = [simulate(AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(update=mode, window=1)),
                     sc.x0, sc.theta_star, 6, "uniform", seed=1) for mode in ("fixed", "window")]
    for a, b in zip(runs[0].records, runs[1].records):
        np.testing.assert_allclose(a.h_theta, b.h_theta, atol=SOLVER_TOL)


def test_projection_onto_theta_k_keeps_the_estimate_in_theta_k(example_spec, example_design):
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(projection="Theta_k"))
    traj = simulate(ctrl, sc.x0, sc.theta_star, 15, "vertices", seed=2)
    for r in traj.records:
        assert np.max(r.H_theta @ r.theta_hat - r.h_theta) <= 1e-7


def test_contradicting_data_raise_an_error_naming_the_step(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design)
    ctrl.step(np.array([2.0, 3.0]))
    with pytest.raises(InconsistentDataError, match="step 1") as info:
        ctrl.step(np.array([40.0, -20.0]))
    assert "W" in str(info.value) and "inflate" in str(info.value)


def test_a_disturbance_outside_W_stops_the_run_with_the_partial_trajectory(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design)
    w = np.zeros((5, 2))
    w[2] = [3.0, -3.0]  # far outside W = {|w|_inf <= 0.1}
    with pytest.raises(InconsistentDataError, match="step 3") as info:
        simulate(ctrl, [2.0, 3.0], [0.8, 0.2, -0.5], 5, w)
    assert info.value.trajectory.steps == 3


def test_infeasible_start_is_a_status_not_an_exception(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design)
    traj = simulate(ctrl, [0.0, -5.0], [0.8, 0.2, -0.5], 5, "zero")  # x2 >= -0.3 violated
    assert traj.steps == 0
    assert traj.records[0].status is SolveStatus.INFEASIBLE
    assert traj.stop_reason.startswith("step 0")
    assert traj.records[0].u is None


def test_bad_simulation_arguments_are_problem_errors(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design)
    with pytest.raises(ProblemError, match="x0"):
        simulate(ctrl, [1.0], [0.8, 0.2, -0.5], 5)
    with pytest.raises(ProblemError, match="theta_star"):
        simulate(ctrl, [1.0, 1.0], [3.0, 0.2, -0.5], 5)
    with pytest.raises(ProblemError, match="disturbance"):
        simulate(ctrl, [1.0, 1.0], [0.8, 0.2, -0.5], 5, np.zeros((4, 2)))
    with pytest.raises(ProblemError, match="online.update"):
        OnlineOptions(update="magic")


def test_trajectory_round_trip(tmp_path, example_run):
    path = example_run.save(tmp_path / "t.json.gz")
    back = Trajectory.load(path)
    np.testing.assert_array_equal(back.x, example_run.x)
    np.testing.assert_array_equal(back.records[7].Lambda, example_run.records[7].Lambda)
    assert back.records[7].status is SolveStatus.OPTIMAL
    assert back.design.to_dict() == example_run.design.to_dict()


def test_robust_baseline_keeps_theta_and_the_estimate_fixed(example_spec, example_design):
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(update="none"))
    traj = simulate(ctrl, sc.x0, sc.theta_star, 8, "uniform", seed=0)
    assert traj.all_solved
    for r in traj.records:
        np.testing.assert_array_equal(r.h_theta, example_design.h_theta0)
        np.testing.assert_array_equal(r.theta_hat, example_spec.problem.theta_hat0)
