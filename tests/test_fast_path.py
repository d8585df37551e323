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
