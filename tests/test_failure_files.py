"""A failing property example is saved as a complete problem file: the online options
of the run and its exact disturbance array are in problem.json, so that ``amcp certify
problem.json`` repeats the run that failed (a failing lockstep run with the moving-window update
saved without its ``online`` section and with the disturbance kind only would name another run)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("amcp_properties")


def test_a_saved_failure_holds_the_online_options_and_the_disturbance_array(tmp_path, monkeypatch):
    from amcp_drake.model.check_result import CheckResult
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.studies.random_problems import random_case
    from amcp_properties import failures

    monkeypatch.setenv(failures.FAILURE_DIR_ENV, str(tmp_path))
    case = random_case(np.random.default_rng(7), steps=5)
    options = OnlineOptions(update="window", window=3, projection="Theta_k")
    w = np.array(case.w, float)
    w[0] = 0.5 * w[0] + 1e-3  # an array no seed of any disturbance kind would draw
    case = replace(case, options=options, w=w)
    result = CheckResult(name="made up", claim="a claim", status="fail", margin=-1.0, tolerance=0.0, detail="")
    folder = failures.save_failure("test_x", "drake", result, case=case)
    spec = load_spec(folder / "problem.json")
    assert spec.online.update == "window" and spec.online.window == 3 and spec.online.projection == "Theta_k"
    assert spec.scenario.explicit_disturbance
    np.testing.assert_array_equal(np.asarray(spec.scenario.disturbance), w)
    np.testing.assert_array_equal(spec.scenario.x0, case.x0)
    np.testing.assert_array_equal(spec.scenario.theta_star, case.theta_star)


def test_corollary16_floor_follows_the_input_gain_on_a_problem_in_small_state_units():
    """A generated problem in state units 100 times smaller (‖B(θ)‖ ≈ 50) whose disturbance stops at k1 = 7.
    A run of it once settled at ‖x_T‖ = 2.5e-8, above the absolute floor 1e-8 of the convergence check (the
    QPs fix v to ~1e-10, which B multiplies). The floor is 1e-8·max(1, max ‖B(θ)‖): the replayed run passes,
    and so does its last state moved to that documented 2.5e-8, which the absolute floor would not cover;
    the claim's bound is tested at 0.5x (pass) and 2x (fail)."""
    pytest.importorskip("amcp_properties")
    from dataclasses import replace

    from amcp_properties import claims
    from amcp_properties.failures import replay

    traj = replay(Path(__file__).parent / "data" / "corollary16-scaled", "drake")
    zero_from = 7  # the saved case's k1 (its disturbances are all zero: the "zero" kind)
    assert np.all(traj.w[zero_from:] == 0.0) and traj.stop_reason == "completed"
    assert claims.convergence_after_disturbance(traj, zero_from).passed

    def with_last_norm(norm: float):
        x = np.array(traj.x, float)
        x[-1] *= norm / np.linalg.norm(x[-1])
        return replace(traj, x=x)

    settled = with_last_norm(2.5e-8)
    norms = claims.state_norms(settled)
    absolute_bound = claims.CONVERGENCE_TARGET * float(np.max(norms[zero_from:])) + claims.CONVERGENCE_FLOOR
    assert norms[-1] > absolute_bound  # the absolute floor alone would fail this run
    result = claims.convergence_after_disturbance(settled, zero_from)
    assert result.passed, result.detail
    bound = norms[-1] / (1.0 - result.margin)
    assert claims.convergence_after_disturbance(with_last_norm(0.5 * bound), zero_from).passed
    assert not claims.convergence_after_disturbance(with_last_norm(2.0 * bound), zero_from).passed