"""Adaptive vs robust baseline (amcp_drake.studies.baseline): honest, small versions of docs/baseline.md."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.model.options import OnlineOptions
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate
from amcp_drake.studies.baseline import feasible_grid, run_baseline

SEEDS = [0, 1]
STEPS = 20
GRID = 9


@pytest.fixture(scope="module")
def baseline(example_spec, example_design):
    return run_baseline(example_spec, example_design, seeds=SEEDS, steps=STEPS, grid=GRID)


def test_robust_region_inside_adaptive_region(baseline):
    """Θ_T ⊆ Θ (Lemma 3) => every x0 with 𝔻(x0, Θ) ≠ ∅ has 𝔻(x0, Θ_T) ≠ ∅."""
    assert baseline.feasible_robust.any() and not baseline.feasible_robust.all()  # the box cuts the region
    for fa in baseline.feasible_adaptive:
        assert np.all(fa[baseline.feasible_robust])


def test_robust_run_keeps_theta_and_estimate(example_spec, example_design):
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(update="none"), formulation="vertex")
    traj = simulate(ctrl, sc.x0, sc.theta_star, 5, "uniform", seed=3)
    for r in traj.records:
        np.testing.assert_array_equal(r.h_theta, example_design.h_theta0)
        np.testing.assert_array_equal(r.theta_hat, example_spec.problem.theta_hat0)


def test_metrics_match_trajectory(baseline, example_spec, example_design):
    """The recorded cost is Σ_k ‖x_k‖²_Q + ‖u_k‖²_R of the robust run, recomputed independently."""
    sc, pr = example_spec.scenario, example_spec.problem
    ctrl = AdaptiveMPC(pr, example_design, options=OnlineOptions(update="none"), formulation="vertex")
    traj = simulate(ctrl, sc.x0, sc.theta_star, STEPS, sc.disturbance, seed=SEEDS[0])
    cost = sum(float(x @ pr.Q @ x + u @ pr.R @ u) for x, u in zip(traj.x, traj.u))
    assert baseline.robust[0].cost == pytest.approx(cost, rel=1e-9)
    assert all(r.completed for r in baseline.adaptive + baseline.robust)
    # adaptation shrinks Θ: the final offsets are <= the initial ones and strictly smaller somewhere
    for m in baseline.adaptive:
        assert np.all(m.h_theta_final <= example_design.h_theta0 + 1e-9)
        assert np.any(m.h_theta_final < example_design.h_theta0 - 1e-3)


def test_feasible_grid_detects_infeasible_points(example_spec, example_design):
    """x2 < -0.3 violates Z at k = 0, so the QP must be infeasible there (a real negative check)."""
    ctrl = AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(update="none"), formulation="vertex")
    grid = feasible_grid(ctrl, example_design.h_theta0, np.array([0.0, 1.0]), np.array([-0.5, 1.0]))
    assert not grid[0].any() and grid[1].all()


def test_cli_baseline_table():
    from amcp_drake.cli import main

    result = CliRunner().invoke(main, ["baseline", "--seeds", "1", "--steps", "5", "--grid", "5"])
    assert result.exit_code == 0, result.output
    assert "| closed-loop cost" in result.output and "⊆ adaptive region at every grid point and seed: True" in result.output


def test_one_step_tube_closed_form_on_a_box(example_spec, example_design, rng):
    """On a box Θ = [lo, hi], max_θ c·(θ − θ̂) = Σ_i max(c_i (lo_i − θ̂_i), c_i (hi_i − θ̂_i)): the
    vertex-based one-step tube size equals this closed form, and shrinking the box shrinks it."""
    from amcp_drake.studies.baseline import one_step_tube

    pr, d = example_spec.problem, example_design
    H = np.vstack([np.eye(3), -np.eye(3)])
    for _ in range(20):
        x, u = rng.normal(size=2) * 3, rng.normal(size=1)
        lo = -rng.uniform(0.1, 1.0, 3)
        hi = rng.uniform(0.1, 1.0, 3)
        theta_hat = rng.uniform(lo, hi)
        C = np.asarray(d.H_x) @ pr.regressor(x, u)
        expected = np.max(np.sum(np.maximum(C * (lo - theta_hat), C * (hi - theta_hat)), axis=1) + d.w_bar)
        got = one_step_tube(pr, d, x, u, H, np.concatenate([hi, -lo]), theta_hat)
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-12)
        smaller = one_step_tube(pr, d, x, u, H, np.concatenate([0.5 * hi, -0.5 * lo]), 0.5 * theta_hat)
        assert smaller <= got + 1e-12


def test_adaptive_one_step_tube_smaller(baseline):
    """Θ_k ⊆ Θ: the adaptive runs' one-step tube is smaller than the robust runs' (measured, per seed)."""
    for a, r in zip(baseline.adaptive, baseline.robust):
        assert np.isfinite(a.mean_one_step_tube) and np.isfinite(r.mean_one_step_tube)
        assert a.mean_one_step_tube < r.mean_one_step_tube
