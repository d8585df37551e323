"""The fast path of the vertex form (issue 16, amcp_drake/backends/daqp_fast.py): DAQP's answers are
the QP's (v within 1e-6 of Clarabel at tight tolerances on every step of a short Example 1 run),
and an answer that fails a check is never used (the step is solved by Clarabel and counted)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("daqp")

from amcp_drake.backends import daqp_fast
from amcp_drake.backends.drake_ import DrakeBackend
from amcp_drake.model.status import SolveStatus
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import disturbance_sequence

#: issue 16: the fast path gives the same v as Clarabel at tight tolerance to 1e-6
V_TOL = 1e-6
#: Clarabel at tight tolerances: the reference the fast path is compared with
TIGHT = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
STEPS = 25


@pytest.fixture(scope="module")
def fast_run(example_spec, example_design):
    """A closed loop with the fast path; per step, the same QP solved by Clarabel (tight)."""
    problem, sc = example_spec.problem, example_spec.scenario
    ctrl = AdaptiveMPC(problem, example_design, backend="drake", formulation="vertex", qp_solver="daqp")
    reference = DrakeBackend(formulation="vertex", solver_options=TIGHT).tube_mpc(ctrl.data)
    w = disturbance_sequence(problem, "uniform", STEPS, seed=0)
    x = np.asarray(sc.x0, float)
    pairs = []
    for k in range(STEPS):
        u, rec = ctrl.step(x)
        assert u is not None, rec.status
        ref = reference.solve(x, rec.h_theta, rec.theta_hat)
        assert ref.status is SolveStatus.OPTIMAL
        pairs.append((rec, ref))
        x = problem.step(x, u, sc.theta_star, w[k])
    return ctrl, pairs


def test_fast_path_gives_clarabels_v_on_every_step(fast_run):
    ctrl, pairs = fast_run
    for rec, ref in pairs:
        np.testing.assert_allclose(rec.v, ref.v, rtol=0, atol=V_TOL)
        assert rec.cost == pytest.approx(ref.cost, rel=1e-7, abs=1e-9)
    counts = ctrl.mpc.fast_path_counts
    assert counts["daqp"] + counts["fallback"] == STEPS
    assert counts["daqp"] >= STEPS - 2  # the path is really used (a fallback is allowed, not the rule)


def test_an_answer_that_fails_a_check_is_solved_by_clarabel(example_spec, example_design, monkeypatch):
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="vertex", qp_solver="daqp")
    monkeypatch.setattr(daqp_fast.DaqpVertexQP, "check", lambda self, w, lam: "stationarity residual 1e-3 (test)")
    x = np.asarray(example_spec.scenario.x0, float)
    sol = ctrl.mpc.solve(x, example_design.h_theta0, example_spec.problem.theta_hat0)
    plain = DrakeBackend(formulation="vertex").tube_mpc(ctrl.data).solve(x, example_design.h_theta0,
                                                                        example_spec.problem.theta_hat0)
    assert sol.status is SolveStatus.OPTIMAL
    assert "fell back to Clarabel: stationarity residual 1e-3 (test)" in sol.detail
    assert ctrl.mpc.fast_path_counts == {"daqp": 0, "fallback": 1}
    np.testing.assert_array_equal(sol.v, plain.v)  # Clarabel's answer, not DAQP's


def test_the_checks_reject_a_perturbed_answer(fast_run):
    """The last DAQP answer passes the checks; moved by 1e-5 in v, or pushed out of a row, it fails."""
    ctrl, _ = fast_run
    model = next(iter(ctrl.mpc._fast.models.values()))
    w, lam = model.last_w.copy(), model.last_lam.copy()
    assert model.check(w, lam) == ""
    moved = w.copy()
    moved[model.v[0]] += 1e-5
    assert model.check(moved, lam) != ""
    tightest = int(np.argmin(model.b - model.A @ w))
    outside = w + 1e-3 * model.A[tightest]  # across the tightest row
    assert model.check(outside, lam).startswith("primal infeasible")
    off = lam.copy()
    off[model.n_alpha + tightest] += 1e-6  # a multiplier of an active row: only stationarity breaks
    assert model.check(w, off).startswith("stationarity residual")


def test_fast_path_needs_the_vertex_form():
    with pytest.raises(ValueError, match="formulation='vertex'"):
        DrakeBackend(formulation="plain", qp_solver="daqp")
    with pytest.raises(ValueError, match="qp_solver 'osqp' unknown"):
        DrakeBackend(formulation="vertex", qp_solver="osqp")


def test_the_checks_reject_a_non_finite_answer(fast_run):
    """DAQP 0.11 reported "optimal" with NaN in w and its multipliers (Example 1, 4-facet X0, step 0, in
    the proximal step; session 8); NaN compares False everywhere, so the checks passed it."""
    ctrl, _ = fast_run
    model = next(iter(ctrl.mpc._fast.models.values()))
    w, lam = model.last_w.copy(), model.last_lam.copy()
    assert model.check(w, lam) == ""
    for bad in (np.nan, np.inf):
        for which in ("w", "lam"):
            w2, lam2 = w.copy(), lam.copy()
            (w2 if which == "w" else lam2)[0] = bad
            assert model.check(w2, lam2).startswith("non-finite"), (bad, which)


def test_a_nan_answer_of_daqp_is_solved_by_clarabel(example_spec):
    """The recorded case: on Example 1 with a 4-facet X0, the fast path's first step got NaN from DAQP;
    the step must be Clarabel's vertex-form answer (counted as a fallback), not the controller's
    fallback to the plain form after its own checks failed."""
    from dataclasses import replace

    from amcp_drake.offline.design import design

    d = design(example_spec.problem, replace(example_spec.design, x0_facets=4), backend="drake")
    ctrl = AdaptiveMPC(example_spec.problem, d, backend="drake", formulation="vertex", qp_solver="daqp")
    x = np.asarray(example_spec.scenario.x0, float)
    u, rec = ctrl.step(x)
    # the fallback is Clarabel on the vertex form with the backend's settings: compared with that program
    # solved apart (not with Clarabel at TIGHT: at the default tolerances this step's v is 1.05e-6 from the
    # tight answer on an AMD EPYC, session 10; that is Clarabel's accuracy, not the fast path's)
    ref = DrakeBackend(formulation="vertex").tube_mpc(ctrl.data).solve(x, rec.h_theta, rec.theta_hat)
    assert rec.status is SolveStatus.OPTIMAL, rec.detail
    assert u is not None and np.all(np.isfinite(rec.v))
    assert "fast path fell back to Clarabel: non-finite answer" in rec.qp_detail
    np.testing.assert_allclose(rec.v, ref.v, rtol=0, atol=1e-9)
    assert sum(ctrl.mpc.fast_path_counts.values()) == 1


def test_a_fast_path_answer_failing_the_controllers_checks_falls_back_to_the_plain_form(example_spec, example_design,
                                                                                        monkeypatch):
    """The controller's last resort, the other formulation, is the plain form, which has no fast path:
    it used to be built with qp_solver="daqp" and raised ValueError instead of solving the step."""
    import dataclasses

    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="vertex", qp_solver="daqp")
    solve = ctrl.mpc.solve

    def off_by_a_lot(*args, **kwargs):  # an "optimal" answer outside the tube rows
        sol = solve(*args, **kwargs)
        return dataclasses.replace(sol, v=sol.v + 10.0)

    monkeypatch.setattr(ctrl.mpc, "solve", off_by_a_lot)
    u, rec = ctrl.step(np.asarray(example_spec.scenario.x0, float))
    assert u is not None and rec.status is SolveStatus.INACCURATE
    assert "fallback: plain form of (20) (checked)" in rec.detail
