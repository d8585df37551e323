"""The exact update (7) on a thin Θ_k: redundant rows are removed, and only rows that are truly not
implied are put back.

Campaign seed 13 #6 (generator 2, vertex-type disturbances, p = 2): Θ_k is ~1e-6 wide around θ* and
many of its rows cut it by 1e-10..1e-7 only. The re-check of the removed rows used HiGHS at its default
tolerances (primal feasibility 1e-7), whose support values there were up to 9.7e-8 too large (measured
against rational arithmetic), so rows the backend rightly removed were put back (7 of 15 steps).

Expected values come from rational arithmetic written here (:func:`exact_support_2d`), never from the
code under test.
"""

from __future__ import annotations

import json
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from amcp_drake.model.status import SolveStatus

DATA = Path(__file__).parent / "data"
BACKENDS = ("drake", "cvxpy")
#: The set tolerance of the update (answer_checks.SET_NESTED_TOL): a removed row may be exceeded by at
#: most this much on the kept rows (unit rows, θ units).
SET_TOL = 1e-8


def exact_support_2d(H: np.ndarray, h: np.ndarray, d: np.ndarray) -> Fraction:
    """max{d·θ | H θ <= h} in rational arithmetic for a bounded polygon (p = 2): the largest value at a
    feasible intersection of two rows (every float is a rational, so this is exact)."""
    Hq = [[Fraction(float(x)) for x in row] for row in H]
    hq = [Fraction(float(x)) for x in h]
    dq = [Fraction(float(x)) for x in d]
    best = None
    for a in range(len(hq)):
        for b in range(a + 1, len(hq)):
            det = Hq[a][0] * Hq[b][1] - Hq[a][1] * Hq[b][0]
            if det == 0:
                continue
            x = (hq[a] * Hq[b][1] - Hq[a][1] * hq[b]) / det
            y = (Hq[a][0] * hq[b] - hq[a] * Hq[b][0]) / det
            value = dq[0] * x + dq[1] * y
            if (best is None or value > best) and all(r[0] * x + r[1] * y <= c for r, c in zip(Hq, hq)):
                best = value
    assert best is not None, "no vertex: the test data are not a bounded polygon"
    return best


@pytest.fixture(scope="module")
def thin_step():
    """(spec, design, Θ_8 rows, Δ_9 rows) of campaign seed 13 #6 at step 9 (recorded from a Drake run)."""
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.offline.design import design

    spec = load_spec(DATA / "campaign-13-6-problem.json")
    step = json.loads((DATA / "campaign-13-6-exact-step9.json").read_text())
    arrays = {k: np.asarray(v, float) for k, v in step.items() if k != "comment"}
    return spec, design(spec.problem, spec.design, backend="drake"), arrays


@pytest.mark.parametrize("backend", BACKENDS)
def test_exact_update_on_a_thin_set_puts_no_implied_row_back(thin_step, backend):
    """Step 9 of campaign 13 #6: the backend's LPs remove the redundant rows and the re-check puts none
    back (it put back a row 3.5e-10 above its bound by rational arithmetic, 4.0e-8 by HiGHS at its
    defaults). Θ_9 is Θ_8 ∩ Δ_9 within SET_TOL (rational arithmetic) and holds θ*."""
    from amcp_drake.online.controller import AdaptiveMPC, StepRecord

    spec, offline, a = thin_step
    ctrl = AdaptiveMPC(spec.problem, offline, backend=backend, options=spec.online)
    s = ctrl.state.replace(k=9, H_theta=a["H_prev"], h_theta=a["h_prev"]).working()
    record = StepRecord(k=9, x=np.zeros(spec.problem.n), u=None, status=SolveStatus.NOT_RUN,
                        H_theta=s.H_theta, h_theta=s.h_theta, theta_hat=s.theta_hat)
    assert ctrl._update_exact(s, a["H_delta"], a["h_delta"], record)
    from amcp_drake.online import answers

    assert answers.of(record, "exact_update") == answers.entry("exact_update", "first")   # no removed row put back
    assert record.set_status is SolveStatus.OPTIMAL
    H_all = np.vstack([a["H_prev"], a["H_delta"]])
    h_all = np.concatenate([a["h_prev"], a["h_delta"]])
    H_k, h_k = s.H_theta, s.h_theta
    assert len(h_k) < len(h_all)
    assert all(any(np.array_equal(row, b) for b in H_all) for row in H_k)  # rows of (7) only
    # Θ_k ⊆ Θ_(k−1) ∩ Δ_k: every row of the intersection holds on Θ_k (the kept rows are some of those
    # rows, so Θ_k ⊇ Θ_(k−1) ∩ Δ_k too)
    for row, bound in zip(H_all, h_all):
        assert exact_support_2d(H_k, h_k, row) - Fraction(float(bound)) <= Fraction(SET_TOL)
    theta_star = np.asarray(spec.scenario.theta_star, float)
    assert np.all(H_k @ theta_star <= h_k)


def test_highs_re_check_of_a_removed_row_is_exact_on_the_thin_set(thin_step):
    """The re-check's support LP (HiGHS at polytope.HIGHS_CERTIFIED_OPTIONS) against rational arithmetic
    on every row of Θ_8 ∩ Δ_9 with that row left out: exact to 1e-12 (at HiGHS' defaults: 9.7e-8 off)."""
    from amcp_drake.online.controller import removed_row_excess

    _, _, a = thin_step
    H_all = np.vstack([a["H_prev"], a["H_delta"]])
    h_all = np.concatenate([a["h_prev"], a["h_delta"]])
    checked = 0
    for i in range(len(h_all)):
        others = np.arange(len(h_all)) != i
        exact = exact_support_2d(H_all[others], h_all[others], H_all[i]) - Fraction(float(h_all[i]))
        if exact < -1e-6:
            continue  # far from the set: not where the tolerances matter
        checked += 1
        assert abs(removed_row_excess(H_all[others], h_all[others], H_all[i], h_all[i]) - float(exact)) <= 1e-12
    assert checked >= 10


@pytest.mark.parametrize("backend", BACKENDS)
def test_backend_support_lps_are_more_accurate_than_the_redundancy_threshold(thin_step, backend):
    """The support LPs that decide redundancy in (7) (``backend.support``, Clarabel at 1e-10) on every
    row of Θ_8 ∩ Δ_9 with that row left out: within REDUNDANT_ROW_TOL = 1e-9 of rational arithmetic, so
    the decision "exceeded by at most 1e-9" is made by LPs more accurate than it. (cvxpy's, at Clarabel's
    default 1e-8, was 2.6e-9 off on this run.)"""
    from amcp_drake.backends import get_backend
    from amcp_drake.online.controller import REDUNDANT_ROW_TOL

    _, _, a = thin_step
    H_all = np.vstack([a["H_prev"], a["H_delta"]])
    h_all = np.concatenate([a["h_prev"], a["h_delta"]])
    solver = get_backend(backend)
    worst = 0.0
    for i in range(len(h_all)):
        others = np.arange(len(h_all)) != i
        exact = exact_support_2d(H_all[others], h_all[others], H_all[i])
        if exact - Fraction(float(h_all[i])) < -1e-6:
            continue
        worst = max(worst, abs(solver.support(H_all[others], h_all[others], H_all[i:i + 1])[0] - float(exact)))
    assert worst <= REDUNDANT_ROW_TOL


@pytest.mark.parametrize("capacity_step", [1, 8])
def test_drake_plain_form_writes_a_new_theta_k_of_fitting_size_into_its_program(thin_step, monkeypatch,
                                                                               capacity_step):
    """The exact update changes H_θk at most steps. The Drake plain form writes a H_θk that fits the
    program it has (as many rows, or fewer within ROW_CAPACITY_STEP: padded with 0·θ <= 1) into that
    program instead of building a new one, and answers as a program built for that H_θk: same v and
    cost (1e-6), Λ with the true number of columns, every answer check passed. (It used to build a new
    program for every new H_θk.) ``capacity_step`` 8 exercises padding by several rows."""
    import amcp_drake.backends.drake_tube as drake_tube
    from amcp_drake.backends.drake_tube import DrakeTubeMPC
    from amcp_drake.online import answer_checks
    from amcp_drake.online.controller import AdaptiveMPC, StepRecord

    monkeypatch.setattr(drake_tube, "ROW_CAPACITY_STEP", capacity_step)
    spec, offline, a = thin_step
    ctrl = AdaptiveMPC(spec.problem, offline, backend="drake", options=spec.online)
    s = ctrl.state.replace(k=9, H_theta=a["H_prev"], h_theta=a["h_prev"]).working()
    record = StepRecord(k=9, x=np.zeros(spec.problem.n), u=None, status=SolveStatus.NOT_RUN,
                        H_theta=s.H_theta, h_theta=s.h_theta, theta_hat=s.theta_hat)
    ctrl._update_exact(s, a["H_delta"], a["h_delta"], record)
    H9, h9 = s.H_theta, s.h_theta
    x = np.asarray(spec.scenario.x0, float)
    theta_hat = np.asarray(spec.problem.theta_hat0, float)
    mpc = ctrl.mpc
    # Θ_9 with one redundant row more (the box row θ_1 <= 1e3): a program built for q + 1 rows
    H_more, h_more = np.vstack([H9, [[1.0, 0.0]]]), np.concatenate([h9, [1e3]])
    assert mpc.solve(x, h_more, theta_hat, H_theta=H_more).status is SolveStatus.OPTIMAL
    program = mpc.prog
    # then Θ_9 itself (one row fewer), and Θ_9 with its first row scaled by 2 (another H_θ, same set)
    H_scaled, h_scaled = H9.copy(), h9.copy()
    H_scaled[0] *= 2.0
    h_scaled[0] *= 2.0
    for H, h in ((H9, h9), (H_scaled, h_scaled)):
        sol = mpc.solve(x, h, theta_hat, H_theta=H)
        assert mpc.prog is program
        assert sol.status is SolveStatus.OPTIMAL and sol.Lambda.shape[-1] == len(h)
        fresh = DrakeTubeMPC(replace_theta(ctrl.data, H), mpc._solver).solve(x, h, theta_hat, H_theta=H)
        assert abs(sol.cost - fresh.cost) <= 1e-6 and np.max(np.abs(sol.v - fresh.v)) <= 1e-6
        assert not answer_checks.failures(ctrl._tube_checks(sol, x, h, H))


def replace_theta(data, H):
    """``data`` with H_θ = H and no Θ0 (a program for this H_θ alone)."""
    import dataclasses

    return dataclasses.replace(data, H_theta=H, h_theta0=None)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_data_set_that_cuts_nothing_costs_one_support_lp_per_data_row(thin_step, backend):
    """After a step of (7) every row of Θ_(k−1) is irredundant; a row of Δ_k whose maximum over Θ_(k−1)
    is below its bound is implied by Θ_(k−1), so it is dropped after that one LP, and when no row cuts,
    Θ_k = Θ_(k−1) with no further LP (it used to cost one LP per row of Θ_(k−1) ∩ Δ_k: Example 1 with
    (7), 50 steps, 679 → 247 support LPs). With a row that cuts, the rows of Θ_(k−1) ∩ Δ_k are decided
    as before, and Θ_k ⊆ Θ_(k−1) ∩ Δ_k holds by rational arithmetic."""
    from amcp_drake.online.controller import AdaptiveMPC, StepRecord

    spec, offline, a = thin_step
    ctrl = AdaptiveMPC(spec.problem, offline, backend=backend, options=spec.online)
    s = ctrl.state.replace(k=9, H_theta=a["H_prev"], h_theta=a["h_prev"]).working()

    def record():
        return StepRecord(k=s.k, x=np.zeros(spec.problem.n), u=None, status=SolveStatus.NOT_RUN,
                          H_theta=s.H_theta, h_theta=s.h_theta, theta_hat=s.theta_hat)

    assert ctrl._update_exact(s, a["H_delta"], a["h_delta"], record())
    H9, h9 = s.H_theta.copy(), s.h_theta.copy()
    directions = []
    real_support = ctrl.backend.support

    def counting_support(H, h, d):
        directions.append(len(np.atleast_2d(d)))
        return real_support(H, h, d)

    ctrl.backend.support = counting_support
    loose = a["h_delta"] + 1e-3                      # every data row 1e-3 outside Θ_9: cuts nothing
    r = record()
    assert ctrl._update_exact(s, a["H_delta"], loose, r)
    assert sum(directions) == len(loose)
    assert np.array_equal(s.H_theta, H9) and np.array_equal(s.h_theta, h9)
    # one row cutting Θ_9 (data row 1 moved to 1e-6 inside Θ_9's extent along it): decided row by row
    from amcp_drake.model import polytope

    directions.clear()
    cut = loose.copy()
    cut[1] = polytope.support(H9, h9, a["H_delta"][1], certified=True).value - 1e-6
    assert ctrl._update_exact(s, a["H_delta"], cut, record())
    assert sum(directions) > len(loose)
    H_all, h_all = np.vstack([H9, a["H_delta"]]), np.concatenate([h9, cut])
    for row, bound in zip(H_all, h_all):
        assert exact_support_2d(s.H_theta, s.h_theta, row) - Fraction(float(bound)) <= Fraction(SET_TOL)
    assert any(np.array_equal(row, a["H_delta"][1]) for row in s.H_theta)
