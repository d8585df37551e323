"""The fast path of the vertex form (amcp_drake/backends/daqp_fast.py): DAQP's answers are
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

#: the fast path gives the same v as Clarabel at tight tolerance to 1e-6
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
    assert counts["daqp"] >= 1  # the comparison is not empty: at least one step is DAQP's own answer


def test_an_answer_that_fails_a_check_is_solved_by_clarabel(example_spec, example_design, monkeypatch):
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="vertex", qp_solver="daqp")
    monkeypatch.setattr(daqp_fast.DaqpVertexQP, "check", lambda self, w, lam: "stationarity residual 1e-3 (test)")
    x = np.asarray(example_spec.scenario.x0, float)
    sol = ctrl.mpc.solve(x, example_design.h_theta0, example_spec.problem.theta_hat0)
    plain = DrakeBackend(formulation="vertex").tube_mpc(ctrl.data).solve(x, example_design.h_theta0,
                                                                        example_spec.problem.theta_hat0)
    assert sol.status is SolveStatus.OPTIMAL
    assert ctrl.mpc.fast_path_counts == {"daqp": 0, "fallback": 1}
    assert ctrl.mpc._fast.last_fallback == "stationarity residual 1e-3 (test)"   # the failed check, kept
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
    the proximal step); NaN compares False everywhere, so without a finiteness test the checks would pass it."""
    ctrl, _ = fast_run
    model = next(iter(ctrl.mpc._fast.models.values()))
    w, lam = model.last_w.copy(), model.last_lam.copy()
    assert model.check(w, lam) == ""
    for bad in (np.nan, np.inf):
        for which in ("w", "lam"):
            w2, lam2 = w.copy(), lam.copy()
            (w2 if which == "w" else lam2)[0] = bad
            assert model.check(w2, lam2).startswith("non-finite"), (bad, which)


def test_a_nan_answer_of_daqp_is_solved_by_clarabel(example_spec, monkeypatch):
    """DAQP reporting "optimal" with NaN in its proximal step (measured once on Example 1 with a 4-facet X0,
    step 0; made here by a fake DAQP model whose second solve of a step returns NaN, so that it happens on
    every machine): the step must be Clarabel's vertex-form answer, counted as a fallback of the fast path,
    not the controller's fallback to the plain form after its own checks failed."""
    from dataclasses import replace

    import daqp

    from amcp_drake.offline.design import design

    class NanInTheProximalStep(daqp.Model):
        solves = 0

        def solve(self):
            w, fval, exitflag, info = super().solve()
            NanInTheProximalStep.solves += 1
            if NanInTheProximalStep.solves % 2 == 0:
                w = np.full_like(np.asarray(w, float), np.nan)
            return w, fval, exitflag, info

    monkeypatch.setattr(daqp, "Model", NanInTheProximalStep)
    d = design(example_spec.problem, replace(example_spec.design, x0_facets=4), backend="drake")
    ctrl = AdaptiveMPC(example_spec.problem, d, backend="drake", formulation="vertex", qp_solver="daqp")
    x = np.asarray(example_spec.scenario.x0, float)
    u, rec = ctrl.step(x)
    assert NanInTheProximalStep.solves >= 2                 # the fake answered the fast path's solves
    # the fallback is Clarabel on the vertex form with the backend's settings: compared with that program
    # solved apart (not with Clarabel at TIGHT: at the default tolerances this step's v is 1.05e-6 from the
    # tight answer on an AMD EPYC; that is Clarabel's accuracy, not the fast path's)
    ref = DrakeBackend(formulation="vertex").tube_mpc(ctrl.data).solve(x, rec.h_theta, rec.theta_hat)
    assert rec.status is SolveStatus.OPTIMAL, rec.detail
    assert u is not None and np.all(np.isfinite(rec.v))
    np.testing.assert_allclose(rec.v, ref.v, rtol=0, atol=1e-9)
    assert ctrl.mpc.fast_path_counts == {"daqp": 0, "fallback": 1}


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
    from amcp_drake.online import answers

    assert u is not None and rec.status is SolveStatus.INACCURATE
    e = answers.of(rec, "tube_qp")
    assert (e["outcome"], e["kind"]) == ("fallback", "plain_form"), e


# -- each acceptance check of the fast path at its tolerance edge: 2x outside rejected, 0.5x inside accepted --
# The documented tolerances (amcp_drake/backends/daqp_fast.py), written here rather than read from the module,
# so that a loosened constant is caught instead of followed.
STATIONARITY_TOL = 1e-9
PRIMAL_TOL = 1e-8
DUAL_TOL = 1e-8
def _edge_model(fast_run):
    ctrl, _ = fast_run
    model = next(iter(ctrl.mpc._fast.models.values()))
    w, lam = model.last_w.copy(), model.last_lam.copy()
    assert model.check(w, lam) == ""
    return model, w, lam


def _stationarity_scale(model, w) -> float:
    """max(1, ‖q‖∞, ‖P₀ w‖∞) with P₀ the cost Hessian without the regularisation of (z, α)."""
    P0 = np.array(model.P)
    zalpha = np.arange(len(w) - len(model.v))
    P0[zalpha, zalpha] = 0.0
    return max(1.0, float(np.max(np.abs(model.q))), float(np.max(np.abs(P0 @ w))))


@pytest.mark.parametrize("factor, rejected", [(2.0, True), (0.5, False)])
def test_the_stationarity_check_at_its_tolerance_edge(fast_run, factor, rejected):
    """A multiplier of an active row moved so that the stationarity residual is factor × STATIONARITY_TOL·scale.
    With the tolerance loosened from 1e-9 to 1e-6 the 2× answer (a residual of 2e-9·scale) was accepted."""
    model, w, lam = _edge_model(fast_run)
    slack = model.b - model.A @ w
    row = int(np.argmin(slack))                                 # an active row: its slack is ~0
    size = factor * STATIONARITY_TOL * _stationarity_scale(model, w) / float(np.max(np.abs(model.A[row])))
    off = lam.copy()
    off[model.n_alpha + row] += size
    reason = model.check(w, off)
    if rejected:
        assert reason.startswith("stationarity residual"), reason
    else:
        assert reason == "", reason


@pytest.mark.parametrize("factor, rejected", [(2.0, True), (0.5, False)])
def test_the_primal_feasibility_check_at_its_tolerance_edge(fast_run, factor, rejected):
    """w moved in (z, α) only (no cost there, so stationarity is unchanged) across the active rows, the worst
    one by factor × PRIMAL_TOL·max(1, |b|)."""
    model, w, lam = _edge_model(fast_run)
    slack = model.b - model.A @ w
    row = int(np.argmin(slack))
    direction = np.zeros_like(w)
    zalpha = slice(model.n_alpha, len(w) - len(model.v))       # z only: α keeps its bound α >= 0 untouched
    direction[zalpha] = model.A[row, zalpha]
    assert np.linalg.norm(direction) > 0
    rates = (model.A @ direction) / np.maximum(1.0, np.abs(model.b))   # relative violation per unit step
    active = slack <= 1e-12 * np.maximum(1.0, np.abs(model.b))
    t = factor * PRIMAL_TOL / float(np.max(rates[active]))
    moved = w + t * direction
    worst = float(np.max((model.A @ moved - model.b) / np.maximum(1.0, np.abs(model.b))))
    assert worst == pytest.approx(factor * PRIMAL_TOL, rel=1e-3)  # the edge the test means
    reason = model.check(moved, lam)
    if rejected:
        assert reason.startswith("primal infeasible"), reason
    else:
        assert not reason.startswith("primal infeasible"), reason


@pytest.mark.parametrize("factor, rejected", [(2.0, True), (0.5, False)])
def test_the_multiplier_sign_check_at_its_tolerance_edge(fast_run, factor, rejected):
    """An inactive row's multiplier set to −factor × DUAL_TOL: 2× is "of the wrong sign"; 0.5× is round-off
    for that check (the stationarity check, which runs after it, may still reject the answer)."""
    model, w, lam = _edge_model(fast_run)
    rows = lam[model.n_alpha:]
    row = int(np.flatnonzero(rows == 0.0)[0])
    off = lam.copy()
    off[model.n_alpha + row] = -factor * DUAL_TOL
    reason = model.check(w, off)
    assert reason.startswith("multiplier of the wrong sign") == rejected, reason


COMPLEMENTARITY_TOL = 1e-7


@pytest.mark.parametrize("factor, rejected", [(2.0, True), (0.5, False)])
def test_the_complementarity_check_at_its_tolerance_edge(fast_run, factor, rejected):
    """The same answer judged against the QP with one active row (its multiplier λ > 0) loosened by s, so that
    λ·s = factor × COMPLEMENTARITY_TOL·scale: feasibility and stationarity are unchanged (neither reads the
    offsets b), only complementarity moves."""
    import copy

    model, w, lam = _edge_model(fast_run)
    rows = lam[model.n_alpha:]
    row = int(np.argmax(rows))
    assert rows[row] > 0
    s = factor * COMPLEMENTARITY_TOL * _stationarity_scale(model, w) / float(rows[row])
    loose = copy.copy(model)
    loose.b = np.array(model.b, float)
    loose.b[row] += s
    slack = loose.b - loose.A @ w
    gap = float(np.max(np.abs(rows * slack)))
    assert gap == pytest.approx(factor * COMPLEMENTARITY_TOL * _stationarity_scale(model, w), rel=1e-3)
    reason = loose.check(w, lam)
    if rejected:
        assert reason.startswith("complementarity"), reason
    else:
        assert reason == "", reason
