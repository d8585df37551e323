"""The report says how often θ̂_k lay outside Θ_k (allowed by (12), removed by Remark 7's projection onto
Θ_k): the count equals one computed here from the recorded rows, the tolerance is tested at its edge,
and a run projected onto Θ_k reports none."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from amcp_drake.certificate.certify import certify
from amcp_drake.certificate.report import render_report
from amcp_drake.certificate.report_groups import theta_hat_outside_theta_k
from amcp_drake.model.tolerances import PROJECTION_TOL as THETA_HAT_OUTSIDE_TOL


def _outside_here(traj) -> int:
    return sum(float(np.max(np.asarray(r.H_theta) @ np.asarray(r.theta_hat) - np.asarray(r.h_theta))) > 1e-7
               for r in traj.records)


def test_the_report_counts_the_steps_with_theta_hat_outside_theta_k(example_run):
    """Example 1 keeps θ̂_k in Θ_k; three records are given a θ̂ at a vertex of Θ beyond Θ_k's row 0."""
    records = list(example_run.records)
    moved_at = [5, 9, 20]
    for k in moved_at:
        H, h = np.asarray(records[k].H_theta, float), np.asarray(records[k].h_theta, float)
        outside = 1.1 * h[0] * H[0] / (H[0] @ H[0]) if h[0] > 0 else None
        assert outside is not None and float(np.max(H @ outside - h)) > 1e-3
        records[k] = dataclasses.replace(records[k], theta_hat=outside)
    traj = dataclasses.replace(example_run, records=records)
    expected = _outside_here(traj)
    assert expected == len(moved_at) + _outside_here(example_run)
    page = render_report(traj, certify(traj))
    line = re.search(r'<p id="theta-hat-outside">(.*?)</p>', page, re.S).group(1)
    assert f'<span class="count">{expected}</span> of {len(traj.records)} steps' in line
    assert "--projection Theta_k" in line


def _with_theta_hat(traj, k: int, theta_hat: np.ndarray):
    records = list(traj.records)
    records[k] = dataclasses.replace(records[k], theta_hat=theta_hat)
    return dataclasses.replace(traj, records=[records[k]])


@pytest.mark.parametrize("factor, counted", [(2.0, True), (0.5, False)])
def test_the_outside_tolerance_at_its_edge(example_run, factor, counted):
    """θ̂ put on the facet of row 0 of a recorded Θ_k (an LP maximising that row), then moved out along the
    row's normal by factor × the tolerance."""
    from scipy.optimize import linprog

    r = example_run.records[3]
    H, h = np.asarray(r.H_theta, float), np.asarray(r.h_theta, float)
    res = linprog(-H[0], A_ub=H, b_ub=h, bounds=[(None, None)] * H.shape[1], method="highs")
    moved = res.x + factor * THETA_HAT_OUTSIDE_TOL * H[0] / (H[0] @ H[0])
    assert abs(float(np.max(H @ moved - h)) - factor * THETA_HAT_OUTSIDE_TOL) < 1e-3 * THETA_HAT_OUTSIDE_TOL
    got = theta_hat_outside_theta_k(_with_theta_hat(example_run, 3, moved))
    assert got.steps == 1 and got.outside == int(counted)


def test_a_run_projected_onto_theta_k_reports_theta_hat_inside_at_every_step(example_spec, example_design):
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", options=OnlineOptions(projection="Theta_k"))
    traj = simulate(ctrl, sc.x0, sc.theta_star, 12, "uniform", seed=0, mu_state_bound=example_spec.design.mu_state_bound)
    assert _outside_here(traj) == 0
    line = re.search(r'<p id="theta-hat-outside">(.*?)</p>', render_report(traj, certify(traj)), re.S).group(1)
    assert f'at all\n  <span class="count">{len(traj.records)}</span> steps' in line
