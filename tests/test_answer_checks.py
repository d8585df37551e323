"""Solver answers are verified before use: each check of amcp_drake.online.answer_checks
fires on a backend stub that returns a wrong "optimal", the step records status "inaccurate" with the
failed check in its detail, and the fallback is taken and recorded. Plus the campaign 0-19 replay.

Expected values never come from the code under test: the stubs' wrong answers are built by hand,
the right answers come from a fresh solve by the real backend (another object and code path than
the controller's fallback) or from the brute-force projection of test_projection_degenerate.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from amcp_drake.backends import get_backend
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answer_checks, answers

DATA = Path(__file__).parent / "data"
BACKENDS = ("drake", "cvxpy")


class WrongBackend:
    """Delegates to a real backend; ``project`` / ``set_update`` answers are replaced by ``wrong_*``
    (a function of the real answer and the arguments) while the status stays "optimal"."""

    def __init__(self, real, wrong_project=None, wrong_set_update=None):
        self._real = real
        self.name = real.name
        self.formulation = getattr(real, "formulation", "plain")
        self.wrong_project = wrong_project
        self.wrong_set_update = wrong_set_update
        self.calls = {"project": 0, "set_update": 0}

    def __getattr__(self, item):
        return getattr(self._real, item)

    def project(self, point, H, h):
        real = self._real.project(point, H, h)
        if self.wrong_project is None:
            return real
        self.calls["project"] += 1
        return dataclasses.replace(real, status=SolveStatus.OPTIMAL, theta=self.wrong_project(real, point, H, h))

    def set_update(self, H_theta, h_prev, H_data, h_data):
        real = self._real.set_update(H_theta, h_prev, H_data, h_data)
        if self.wrong_set_update is None:
            return real
        self.calls["set_update"] += 1
        return dataclasses.replace(real, status=SolveStatus.OPTIMAL, h=self.wrong_set_update(real, h_prev))


class WrongTube:
    """A tube QP whose "optimal" answers are changed by ``wrong(sol)``; without ``refine=True``."""

    REFINES = False

    def __init__(self, real, wrong):
        self._real, self.wrong, self.calls = real, wrong, 0
        self.formulation = real.formulation

    def solve(self, *args, **kwargs):
        sol = self._real.solve(*args, **kwargs)
        if sol.status is not SolveStatus.OPTIMAL:
            return sol
        self.calls += 1
        return self.wrong(sol)


class UnrefinedTube:
    """A plain-form tube QP whose first try (``refine=False``) is changed by ``wrong(sol)``; with
    ``refine=True`` it answers as the real solver (``wrong_refined`` changes that answer too)."""

    REFINES = True

    def __init__(self, real, wrong, wrong_refined=None):
        self._real, self.wrong, self.wrong_refined, self.refined = real, wrong, wrong_refined, 0

    def solve(self, *args, refine=False, **kwargs):
        sol = self._real.solve(*args, refine=refine, **kwargs)
        if sol.status is not SolveStatus.OPTIMAL:
            return sol
        if refine:
            self.refined += 1
            return self.wrong_refined(sol) if self.wrong_refined else sol
        return self.wrong(sol)


# -- fixtures: Example 1 (every step updates Θ_k) and campaign problem 0-19 (θ̃_1 outside Θ_1) ---------------
@pytest.fixture(scope="module")
def case_0_19():
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.offline.design import design

    spec = load_spec(DATA / "campaign-0-19-problem.json")
    w = np.array(json.loads((DATA / "campaign-0-19-disturbances.json").read_text())["w"])
    return spec, design(spec.problem, spec.design, backend="drake"), w


def _controller(spec, design, backend, options=None, **backend_options):
    from amcp_drake.online.controller import AdaptiveMPC

    return AdaptiveMPC(spec.problem, design, backend=backend, options=options or spec.online, **backend_options)


def _run(ctrl, spec, steps, w="uniform"):
    from amcp_drake.online.simulate import simulate

    sc = spec.scenario
    return simulate(ctrl, sc.x0, sc.theta_star, steps, w if isinstance(w, str) else w[:steps], seed=0,
                    mu_state_bound=spec.design.mu_state_bound)


# -- (a) projection (12) --------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_projection_outside_the_set_is_caught_and_replaced(case_0_19, backend):
    """The 0-19 failure mode: an "optimal" projection outside Θ_1 (θ̃ itself, 0.55 away)."""
    from tests.test_projection_degenerate import exact_projection

    spec, design, w = case_0_19
    ctrl = _controller(spec, design, backend)
    ctrl.backend = WrongBackend(ctrl.backend, wrong_project=lambda real, point, H, h: point.copy())
    traj = _run(ctrl, spec, 3, w)
    assert ctrl.backend.calls["project"] >= 1
    r = traj.records[1]
    assert r.projection_status is SolveStatus.INACCURATE
    assert answers.of(r, "projection") == answers.entry("projection", "fallback", "least_distance", "projection in set")
    expected = exact_projection(r.theta_tilde, r.H_theta, r.h_theta)
    assert np.linalg.norm(r.theta_hat - expected) <= 1e-8
    assert traj.stop_reason == "completed"


@pytest.mark.parametrize("backend", BACKENDS)
def test_feasible_but_not_optimal_projection_is_caught(case_0_19, backend):
    """A point of Θ_1 that is not the projection (the real one moved 1e-6 along a facet of the thin set
    is still inside it): membership passes, KKT does not."""
    from amcp_drake.model import polytope

    spec, design, w = case_0_19

    def off_centre(real, point, H, h):
        centre, _ = polytope.chebyshev_center(H, h)
        return centre  # inside Θ_1, but ~1e-6 from the projection: not optimal

    ctrl = _controller(spec, design, backend)
    ctrl.backend = WrongBackend(ctrl.backend, wrong_project=off_centre)
    traj = _run(ctrl, spec, 2, w)
    r = traj.records[1]
    assert r.projection_status is SolveStatus.INACCURATE
    e = answers.of(r, "projection")
    assert e["outcome"] == "fallback" and e["check"] == "projection KKT residual", e   # membership passed


def test_projection_fallbacks_in_order(case_0_19, monkeypatch):
    """When the second solver fails too: θ̂_(k−1) if it is in S, else the Chebyshev centre of S."""
    from amcp_drake.model import polytope
    from amcp_drake.online import controller as controller_module

    spec, design, w = case_0_19
    monkeypatch.setattr(controller_module.polytope, "least_distance_point", lambda *a: None)
    ctrl = _controller(spec, design, "drake")
    ctrl.backend = WrongBackend(ctrl.backend, wrong_project=lambda real, point, H, h: point.copy())
    traj = _run(ctrl, spec, 2, w)
    r = traj.records[1]
    assert r.projection_status is SolveStatus.INACCURATE
    # θ̂_0 is not in the collapsed Θ_1, so the Chebyshev centre of Θ_1 is used
    assert np.max(r.H_theta @ traj.records[0].theta_hat - r.h_theta) > 1e-3
    assert answers.of(r, "projection")["kind"] == "chebyshev_centre"
    centre, _ = polytope.chebyshev_center(r.H_theta, r.h_theta)
    assert np.allclose(r.theta_hat, centre, atol=1e-12)
    assert np.max(r.H_theta @ r.theta_hat - r.h_theta) <= answer_checks.PROJECTION_MEMBERSHIP_TOL


# -- (b) set update (9) ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("kind", ["grown", "cut"])
def test_wrong_set_update_is_caught_and_recomputed(example_spec, example_design, backend, kind):
    """An "optimal" h of (9) that grows (breaks (10)) or cuts 0.05 off every row (not an outer bound of
    Θ_(k−1) ∩ Δ_k): status inaccurate, then HiGHS's supports, which agree with a fresh real solve."""
    shift = {"grown": 0.05, "cut": -0.05}[kind]
    ctrl = _controller(example_spec, example_design, backend, options=None)
    ctrl.backend = WrongBackend(ctrl.backend, wrong_set_update=lambda real, h_prev: np.asarray(real.h) + shift)
    seen = []
    original = ctrl._update_set

    def spy(s, H_delta, h_delta, record):
        seen.append((np.array(s.h_theta), H_delta, h_delta))
        return original(s, H_delta, h_delta, record)

    ctrl._update_set = spy
    traj = _run(ctrl, example_spec, 3)
    r = traj.records[1]
    assert r.set_status is SolveStatus.INACCURATE
    check = "set update nested" if kind == "grown" else "set update outer bound"
    e = answers.of(r, "set_update")
    assert (e["outcome"], e["kind"]) == ("fallback", "highs_support_lps") and e["check"].startswith(check), e
    h_prev, H_delta, h_delta = seen[0]
    fresh = get_backend(backend).set_update(example_design.H_theta, h_prev, H_delta, h_delta)
    assert np.max(np.abs(r.h_theta - fresh.h)) <= 1e-7
    assert traj.stop_reason == "completed"


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_set_update_above_the_previous_offsets_by_round_off_is_clipped_to_them(example_spec, example_design,
                                                                                  backend):
    """An answer of (9) 5e-9 above h_(k−1) in the rows the data do not cut passes its checks (nested to
    1e-8); the controller keeps min(h, h_(k−1)), so Θ_k ⊆ Θ_(k−1) holds exactly (campaign seed 4 #37:
    a window update drifted 4e-9 above h_θ0 and the Drake plain form left its reduced program)."""
    seen = []

    def bumped(real, h_prev):
        untouched = np.asarray(real.h) >= h_prev - 1e-12
        seen.append((np.array(real.h), np.array(h_prev), untouched))
        return np.asarray(real.h) + 5e-9 * untouched

    ctrl = _controller(example_spec, example_design, backend, options=None)
    ctrl.backend = WrongBackend(ctrl.backend, wrong_set_update=bumped)
    traj = _run(ctrl, example_spec, 2)
    r = traj.records[1]
    real_h, h_prev, untouched = seen[0]
    assert untouched.any() and not untouched.all()   # some rows kept, some cut by the data
    assert r.set_status is SolveStatus.OPTIMAL and answers.of(r, "set_update") == answers.entry("set_update", "first")
    np.testing.assert_array_equal(r.h_theta, np.where(untouched, h_prev, real_h))
    assert np.all(r.h_theta <= h_prev)


def test_set_update_keeps_previous_set_when_every_solver_fails(example_spec, example_design, monkeypatch):
    from amcp_drake.online import controller as controller_module

    monkeypatch.setattr(controller_module.polytope, "support_certified", lambda *a: None)
    ctrl = _controller(example_spec, example_design, "drake", options=None)
    ctrl.backend = WrongBackend(ctrl.backend, wrong_set_update=lambda real, h_prev: np.asarray(real.h) - 0.05)
    traj = _run(ctrl, example_spec, 2)
    assert traj.records[1].set_status is SolveStatus.INACCURATE
    assert answers.of(traj.records[1], "set_update")["kind"] == "kept_previous_set"
    assert np.array_equal(traj.records[1].h_theta, traj.records[0].h_theta)


def test_exact_update_with_every_row_wrongly_removed_keeps_the_set(example_spec, example_design):
    """(7): a support LP that calls every row redundant would make Θ_k ⊄ Θ_(k−1); HiGHS re-checks the
    removed rows, puts back those not implied, and the step keeps the set Θ_0 ∩ Δ_1."""
    from amcp_drake.model.options import OnlineOptions

    ctrl = _controller(example_spec, example_design, "drake", options=OnlineOptions(update="exact"))
    real = ctrl.backend

    class Lying(WrongBackend):
        def support(self, H, h, directions):
            return np.full(len(np.atleast_2d(directions)), -1e3)  # "every row is implied"

    ctrl.backend = Lying(real)
    traj = _run(ctrl, example_spec, 2)
    r = traj.records[1]
    assert r.set_status is SolveStatus.INACCURATE
    assert answers.of(r, "exact_update")["kind"] == "removed_rows_kept"
    # rows of (7) only, and every row of Θ_0 ∩ Δ_1 implied by them (scipy): the same set as (7)
    from scipy.optimize import linprog

    H_d, h_d = ctrl._delta(ctrl.state.working(), traj.x[0], traj.u[0], traj.x[1])
    H_all = np.vstack([np.asarray(example_design.H_theta), H_d])
    h_all = np.concatenate([np.asarray(example_design.h_theta0), h_d])
    assert all(any(np.array_equal(row, a) for a in H_all) for row in r.H_theta)
    for row, bound in zip(H_all, h_all):
        res = linprog(-row, A_ub=r.H_theta, b_ub=r.h_theta, bounds=[(None, None)] * 3, method="highs")
        assert res.status == 0 and -res.fun <= bound + 1e-8


def test_exact_update_keeps_only_the_removed_rows_that_are_not_implied(example_spec, example_design):
    """(7): a support LP that calls every data row of Δ_k redundant (and answers the others truly):
    HiGHS finds the data rows that cut Θ_(k−1); exactly those are put back, the truly redundant ones
    stay removed, and the kept rows describe Θ_(k−1) ∩ Δ_k (every row of the intersection is implied
    by them, scipy LPs here). Were every row kept whenever one such row is found, a backend LP 4e-8
    off would grow Θ_k by ~7 rows a step (campaign seed 13 #6, generator 2)."""
    from scipy.optimize import linprog

    from amcp_drake.model.options import OnlineOptions

    ctrl = _controller(example_spec, example_design, "drake", options=OnlineOptions(update="exact"))
    real = ctrl.backend
    q = len(example_design.h_theta0)

    class LyingOnData(WrongBackend):
        def support(self, H, h, directions):
            d = np.atleast_2d(directions)
            is_data = [not any(np.allclose(row, t) for t in np.asarray(example_design.H_theta)) for row in d]
            return np.where(is_data, -1e3, real.support(H, h, d))  # "every data row is implied"

    def implied_by(H, h, row, bound):
        res = linprog(-row, A_ub=H, b_ub=h, bounds=[(None, None)] * H.shape[1], method="highs")
        return res.status == 0 and -res.fun <= bound + 1e-9 * max(1.0, abs(bound))

    x0 = np.asarray(example_spec.scenario.x0, float)
    u0, _ = ctrl.step(x0)
    H0, h0 = np.array(ctrl.H_theta), np.array(ctrl.h_theta)
    # a disturbance whose Δ_1 has data rows of both kinds: some cut Θ_0, some do not (scipy decides)
    for w0 in np.vstack([example_spec.problem.w_vertices(), np.zeros((1, 2))]):
        x1 = example_spec.problem.step(x0, u0, example_spec.scenario.theta_star, w0)
        H_d, h_d = ctrl._delta(ctrl.state.working(), x0, u0, x1)
        # the specification, written out here with scipy: in order, a data row is put back when the rows
        # kept so far (Θ_0's, then the data rows put back before it) do not imply it
        cuts = []
        for j, (row, bound) in enumerate(zip(H_d, h_d)):
            if not implied_by(np.vstack([H0, H_d[cuts]]), np.concatenate([h0, h_d[cuts]]), row, bound):
                cuts.append(j)
        if 0 < len(cuts) < len(h_d):
            break
    else:
        pytest.fail("no vertex of W gives a Δ_1 with rows of both kinds")
    ctrl.backend = LyingOnData(real)
    _, r = ctrl.step(x1)
    assert r.set_status is SolveStatus.INACCURATE and answers.of(r, "exact_update")["kind"] == "removed_rows_kept"
    kept = np.asarray(r.H_theta)
    assert np.array_equal(kept[:q], H0) and np.array_equal(r.h_theta[:q], h0)     # Θ_0 (a box) keeps its rows
    assert np.array_equal(kept[q:], H_d[cuts]) and np.array_equal(r.h_theta[q:], h_d[cuts])  # and the cuts only
    H_all, h_all = np.vstack([H0, H_d]), np.concatenate([h0, h_d])
    for row, bound in zip(H_all, h_all):                                          # the same set as (7)
        assert implied_by(kept, r.h_theta, row, bound + 1e-8)


# -- (c) tube QP (20) ------------------------------------------------------------------------------------------
def _shift_z0(sol):
    z = np.array(sol.z)
    z[0] += 1.0
    return dataclasses.replace(sol, z=z)


def _negate_lambda(sol):
    return dataclasses.replace(sol, Lambda=None if sol.Lambda is None else -np.asarray(sol.Lambda) - 1.0)


def _push_v(sol):
    v = np.array(sol.v)
    v[1:] += 50.0
    return dataclasses.replace(sol, v=v)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("formulation, wrong, check", [
    ("plain", _shift_z0, "tube x_k in X_0|k (15b)"),
    ("plain", _negate_lambda, "tube Lambda >= 0"),
    ("vertex", _push_v, "tube constraints (15a)"),        # v pushed by 50: (15a) is the first row it breaks
])
def test_wrong_tube_answer_is_replaced_by_the_other_formulation(example_spec, example_design, backend, formulation,
                                                                 wrong, check):
    """An "optimal" (v, z, α, Λ) that breaks a row of (15)/(5b): status inaccurate, the other formulation's
    answer (checked) is applied; it equals a fresh solve of that formulation."""
    ctrl = _controller(example_spec, example_design, backend, options=None, formulation=formulation)
    ctrl.mpc = WrongTube(ctrl.mpc, wrong)
    traj = _run(ctrl, example_spec, 2)
    assert ctrl.mpc.calls >= 2
    r = traj.records[0]
    assert r.status is SolveStatus.INACCURATE
    other = "vertex" if formulation == "plain" else "plain"
    assert answers.of(r, "tube_qp") == answers.entry("tube_qp", "fallback", f"{other}_form", check)
    fresh = get_backend(backend, formulation=other).tube_mpc(ctrl.data).solve(r.x, r.h_theta, r.theta_hat)
    assert np.max(np.abs(r.v - fresh.v)) <= 1e-6
    assert np.allclose(r.u, example_design.K @ r.x + fresh.v[0], atol=1e-6)
    assert traj.stop_reason == "completed"


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_a_first_try_that_fails_the_checks_is_solved_again_with_iterative_refinement(example_spec, example_design,
                                                                                     backend):
    """The plain form's first try runs without iterative refinement (speed); an answer of it that
    fails a check is solved again with refinement and, when that answer passes, applied as the
    step's optimal answer with both noted (a generated case: a first try 1.3e-6 outside (15c))."""
    ctrl = _controller(example_spec, example_design, backend, options=None, formulation="plain")
    ctrl.mpc = UnrefinedTube(ctrl.mpc, _negate_lambda)
    traj = _run(ctrl, example_spec, 2)
    assert ctrl.mpc.refined >= 2
    r = traj.records[0]
    assert r.status is SolveStatus.OPTIMAL
    e = answers.of(r, "tube_qp")
    assert (e["outcome"], e["kind"]) == ("resolved", "iterative_refinement") and e["check"], e
    fresh = get_backend(backend, formulation="plain").tube_mpc(ctrl.data).solve(r.x, r.h_theta, r.theta_hat)
    assert np.max(np.abs(r.v - fresh.v)) <= 1e-6
    assert traj.stop_reason == "completed"


def test_a_refined_answer_that_fails_too_falls_back_to_the_other_formulation(example_spec, example_design):
    ctrl = _controller(example_spec, example_design, "drake", options=None, formulation="plain")
    ctrl.mpc = UnrefinedTube(ctrl.mpc, _negate_lambda, wrong_refined=_negate_lambda)
    traj = _run(ctrl, example_spec, 2)
    r = traj.records[0]
    assert r.status is SolveStatus.INACCURATE
    e = answers.of(r, "tube_qp")      # the refined answer failed too: the other formulation's, not a re-solve
    assert (e["outcome"], e["kind"]) == ("fallback", "vertex_form"), e


def test_wrong_tube_answer_without_another_formulation_is_not_solved(example_spec, example_design):
    """The min-max cost (19) exists in the plain form only: the step is reported as not solved."""
    from amcp_drake.model.options import OnlineOptions

    ctrl = _controller(example_spec, example_design, "drake", options=OnlineOptions(cost="minmax"))
    ctrl.mpc = WrongTube(ctrl.mpc, _shift_z0)
    traj = _run(ctrl, example_spec, 3)
    assert len(traj.records) == 1 and traj.records[0].u is None
    assert traj.records[0].status is SolveStatus.INACCURATE
    assert answers.of(traj.records[0], "tube_qp") == answers.entry("tube_qp", "not_solved", "", "tube x_k in X_0|k (15b)")
    assert traj.stop_reason == "step 0: status optimal_inaccurate"


class GivesUpTube:
    """A tube QP that answers ``status`` with no solution (a solver's numerical failure after its retries)."""

    REFINES = True

    def __init__(self, real, status):
        self._real, self.status, self.calls = real, status, 0

    def solve(self, *args, **kwargs):
        from amcp_drake.backends.base import MPCSolution

        self.calls += 1
        return MPCSolution(self.status, None, None, None, None, None, detail=f"stub: {self.status.value}")


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("formulation", ["plain", "vertex"])
@pytest.mark.parametrize("status", [SolveStatus.INACCURATE, SolveStatus.ERROR])
def test_a_tube_qp_without_an_answer_falls_back_to_the_other_formulation(example_spec, example_design, backend,
                                                                          formulation, status):
    """A QP (20) that ends "inaccurate" or with a solver error (no answer, after the retry ladder) is
    solved in the other formulation, whose answer is checked and applied; the step's status stays
    "inaccurate" (the first backend answer failed). Found on massera2017 (cvxpy, plain form, θ* = −1):
    the run used to stop there although the vertex form solved the step."""
    ctrl = _controller(example_spec, example_design, backend, options=None, formulation=formulation)
    ctrl.mpc = GivesUpTube(ctrl.mpc, status)
    traj = _run(ctrl, example_spec, 2)
    assert ctrl.mpc.calls >= 2 and traj.stop_reason == "completed"
    r = traj.records[0]
    assert r.status is SolveStatus.INACCURATE and r.u is not None
    other = "vertex" if formulation == "plain" else "plain"
    assert answers.of(r, "tube_qp") == answers.entry("tube_qp", "fallback", f"{other}_form", f"status {status.value}")
    fresh = get_backend(backend, formulation=other).tube_mpc(ctrl.data).solve(r.x, r.h_theta, r.theta_hat)
    assert np.max(np.abs(r.v - fresh.v)) <= 1e-6
    assert np.allclose(r.u, example_design.K @ r.x + fresh.v[0], atol=1e-6)


def test_an_infeasible_tube_qp_has_no_fallback(example_spec, example_design):
    """"Infeasible" is an answer (the certificate's recursive feasibility fails there), not a numerical
    failure: the other formulation is not asked and the step is not solved."""
    ctrl = _controller(example_spec, example_design, "drake", options=None, formulation="plain")
    ctrl.mpc = GivesUpTube(ctrl.mpc, SolveStatus.INFEASIBLE)
    traj = _run(ctrl, example_spec, 2)
    assert len(traj.records) == 1 and traj.records[0].u is None
    assert traj.records[0].status is SolveStatus.INFEASIBLE
    assert answers.of(traj.records[0], "tube_qp") == answers.entry("tube_qp", "not_solved", "infeasible")


def test_massera2017_step_that_cvxpy_plain_form_could_not_solve_is_solved():
    """Regression (massera2017, θ* = −1, uniform disturbances, seed 3, cvxpy): at step 14, with
    Θ_14 = [−1, −0.98725], Clarabel ended the plain form "AlmostSolved" under every rung of the retry
    ladder (relative gap stalled at 1.15e-7), and the run stopped. Drake's plain form and both
    vertex forms solve this QP (cost 0.25129). Now the step is solved, by the plain form if a future
    Clarabel manages, else by the checked vertex-form fallback."""
    from amcp_drake.model.examples import get_example
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC

    spec = get_example("massera2017")
    offline = design(spec.problem, spec.design, backend="cvxpy")
    ctrl = AdaptiveMPC(spec.problem, offline, backend="cvxpy", formulation="plain")
    ctrl.state = ctrl.state.replace(h_theta=np.array([-0.9872451948108746, 0.9999999999411466]),
                                    theta_hat=np.array([-0.131851241551105]))
    u, r = ctrl.step(np.array([0.0513887048026173, 0.2228770115475585, -0.1979463514878846]))
    assert u is not None
    assert answers.qp_applied(r)         # by the plain form itself or by the checked vertex-form fallback
    fresh = get_backend("drake", formulation="vertex").tube_mpc(ctrl.data).solve(r.x, r.h_theta, r.theta_hat)
    assert abs(r.cost - fresh.cost) <= 1e-6 and np.max(np.abs(r.v - fresh.v)) <= 1e-5


# -- the checks themselves, on hand-made answers ---------------------------------------------------------------
def test_check_projection_accepts_the_exact_projection_and_rejects_others():
    from tests.test_projection_degenerate import exact_projection

    case = json.loads((DATA / "campaign-0-19-projection.json").read_text())
    point, H, h = (np.asarray(case[k], float) for k in ("point", "H", "h"))
    exact = exact_projection(point, H, h)
    assert not answer_checks.failures(answer_checks.check_projection(exact, point, H, h, (exact,)))
    for wrong, name in [(point, "projection in set"), (exact + np.array([0.0, 0.0, 1e-3]), "projection in set"),
                        (np.array([np.nan, 0.0, 0.0]), "projection finite")]:
        failed = answer_checks.failures(answer_checks.check_projection(wrong, point, H, h))
        assert any(c.name.startswith(name) for c in failed), (wrong, failed)


def test_projection_candidate_check_is_absolute_for_short_distances():
    """θ̃ inside S = [−1, 1]² and a known point of S 1e-14 from it (the LMS step at the origin): an
    answer 1e-10 from θ̃ (solver round-off) passes; before, the relative test gave 1e4 > 1e-8 (campaign
    seed 0 #131: up to 1.25e8). An answer 1e-6 off still fails, and so does 1e-6 relative at distance 10."""
    H = np.vstack([np.eye(2), -np.eye(2)])
    h = np.ones(4)
    name = "projection no farther than a known point of the set"
    point = np.array([0.15, 0.2])

    def failed(theta, candidate, pt=point):
        return [c.name for c in answer_checks.failures(answer_checks.check_projection(theta, pt, H, h, (candidate,)))]

    assert name not in failed(point + [1e-10, 0.0], point + [1e-14, 0.0])
    assert name in failed(point + [1e-6, 0.0], point)
    far = np.array([11.0, 0.0])              # Π(far) = (1, 0), at distance 10
    assert name not in failed(np.array([1.0, 0.0]), np.array([1.0, 0.0]), far)
    assert name in failed(np.array([1.0, 1e-2]), np.array([1.0, 0.0]), far)  # 5e-7 relative


def test_check_set_update_uses_the_dual_certificate():
    """Θ_(k−1) = [−1, 1]², one datum θ_1 <= 0.5: the offsets [0.5, 1, 1, 1] with Λ = rows picking the datum
    for row 1 pass; claiming 0.4 for row 1 fails the outer bound (θ = (0.5, 0) is in the intersection)."""
    H = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    h_prev = np.ones(4)
    H_data, h_data = np.array([[1.0, 0.0]]), np.array([0.5])
    Lam = np.hstack([np.eye(4), np.zeros((4, 1))])
    Lam[0] = [0, 0, 0, 0, 1.0]
    box = np.array([1.0, 1.0])
    good = np.array([0.5, 1.0, 1.0, 1.0])
    points = np.array([[0.5, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    assert not answer_checks.failures(answer_checks.check_set_update(good, Lam, points, H, h_prev, H_data, h_data, box))
    cut = good - np.array([0.1, 0, 0, 0])
    names = [c.name for c in answer_checks.failures(
        answer_checks.check_set_update(cut, Lam, None, H, h_prev, H_data, h_data, box))]
    assert names == ["set update outer bound (dual certificate)"]
    bad_points = points + np.array([[0.2, 0.0], [0, 0], [0, 0], [0, 0]])
    names = [c.name for c in answer_checks.failures(
        answer_checks.check_set_update(good, Lam, bad_points, H, h_prev, H_data, h_data, box))]
    assert names == ["set update maximisers feasible and tight"]


def test_set_update_check_reuses_only_what_is_unchanged():
    """SetUpdateCheck (the parts of check_set_update that depend only on the answer and Θ_(k−1)
    reused while those are unchanged to the bit) gives the rows of check_set_update, names, verdicts and
    values to the bit, on a sequence that repeats one answer while Δ_k, h_(k−1), H_θ, h, the number of
    data rows and the finiteness of Λ and of the maximisers change one at a time (a part reused for a
    changed input shows a stale value here)."""
    H = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    H_tilted = np.array([[1.0, 0.0], [0.6, 0.8], [-1.0, 0.0], [0.0, -1.0]])
    h_prev = np.ones(4)
    box = np.array([1.0, 1.0])
    one_datum = (np.array([[1.0, 0.0]]), np.array([0.5]))
    other_datum = (np.array([[0.8, 0.6]]), np.array([0.7]))
    two_data = (np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([0.5, 0.9]))
    Lam = np.hstack([np.eye(4), np.zeros((4, 1))])
    Lam[0] = [0, 0, 0, 0, 1.0]
    Lam2 = np.hstack([Lam, np.zeros((4, 1))])
    good = np.array([0.5, 1.0, 1.0, 1.0])
    points = np.array([[0.5, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    nan_points = points.copy()
    nan_points[1, 0] = np.nan
    nan_Lam = Lam.copy()
    nan_Lam[2, 1] = np.nan
    # each case differs from the one before it in one input (a part reused for it would be stale)
    cases = [
        (good, Lam, points, H, h_prev, *one_datum),
        (good, Lam, points, H, h_prev, *other_datum),              # Δ_k: dual bound, feasibility
        (good, Lam, points, H, h_prev - [0.0, 0.1, 0.0, 0.0], *other_datum),  # h_(k−1): nesting (10)
        (good, Lam, points, H, h_prev, *other_datum),
        (good, Lam, points, H_tilted, h_prev, *other_datum),       # H_θ: residual and miss
        (good, Lam, points, H, h_prev, *other_datum),
        (good - [0.1, 0, 0, 0], Lam, points, H, h_prev, *other_datum),  # h: miss
        (good, Lam, points, H, h_prev, *other_datum),
        (good, 2.0 * Lam, points, H, h_prev, *other_datum),        # Λ: dual bound
        (good, Lam, points, H, h_prev, *other_datum),
        (good, Lam2, points, H, h_prev, *two_data),                # two data rows
        (good, Lam2, points, H, h_prev, *one_datum),               # Λ of the wrong width: not run
        (good, Lam2, points, H, h_prev, *two_data),
        (good, Lam, points, H, h_prev, *one_datum),
        (good, Lam, nan_points, H, h_prev, *one_datum),            # non-finite maximisers
        (good, Lam, nan_points, H, h_prev, *other_datum),
        (good, Lam, points, H, h_prev, *other_datum),
        (good, Lam, None, H, h_prev, *other_datum),                # no maximisers
        (good, Lam, points, H, h_prev, *other_datum),
        (good, nan_Lam, points, H, h_prev, *other_datum),          # non-finite Λ
        (good, nan_Lam, points, H, h_prev, *one_datum),
        (good, Lam, points, H, h_prev, *one_datum),
        (good + [np.nan, 0, 0, 0], Lam, points, H, h_prev, *one_datum),  # non-finite h: one row
        (good, Lam, points, H, h_prev, *one_datum),
    ]
    checker = answer_checks.SetUpdateCheck()

    def rows(checks):
        return [(c.name, np.float64(c.value).tobytes(), c.tolerance, c.ran) for c in checks]

    for i, args in enumerate(cases):
        got = checker.check(*args, box)
        assert rows(got) == rows(answer_checks.check_set_update(*args, box)), i
    # the answer repeated with new data is checked against the new data: a cut datum fails it
    cut = (np.array([[1.0, 0.0]]), np.array([0.3]))
    failed = answer_checks.failures(checker.check(good, Lam, points, H, h_prev, *cut, box))
    assert [c.name for c in failed] == ["set update maximisers feasible and tight"]


@pytest.mark.parametrize("formulation", ["vertex", "plain"])
def test_preassembled_tube_check_equals_check_tube(example_spec, example_design, formulation):
    """TubeCheck (the rows of check_tube preassembled, one product per block) gives the names,
    verdicts and values of check_tube on real and perturbed answers: vertex form for several Θ_k (random
    sub-boxes of Θ0: its (5b) rows are rebuilt, and reused for the next answer) and without Θ_k's vertices
    ("not run"); plain form with Λ perturbed too and per-stage offsets (26); and for non-finite answers."""
    from amcp_drake.model import polytope

    ctrl = _controller(example_spec, example_design, "drake", formulation=formulation)
    data, fast = ctrl.data, answer_checks.TubeCheck(ctrl.data)
    H, h0 = np.asarray(example_design.H_theta, float), np.asarray(example_design.h_theta0, float)
    x0 = np.asarray(example_spec.scenario.x0, float)
    N = int(data.N)
    rng = np.random.default_rng(16)
    verdicts = set()
    for trial in range(6):
        lo, hi = np.sort(rng.uniform(-1.0, 1.0, (2, 3)), axis=0)
        corners = np.array(np.meshgrid(*zip(lo, hi))).reshape(3, -1).T      # the box's 8 corners
        h = np.minimum(np.max(corners @ H.T, axis=0), h0)                    # its offsets on Θ0's rows
        if formulation == "plain" and trial % 2:                              # per-stage offsets (26)
            h = np.minimum(h[None, :] + 0.01 * np.arange(N)[:, None], h0)
        theta = 0.5 * (lo + hi)
        vertices = polytope.theta_vertices(H, h if h.ndim == 1 else h[0])
        sol = ctrl.mpc.solve(x0, h, theta)
        assert sol.status is SolveStatus.OPTIMAL
        for scale in (0.0, 1e-7, 1e-4, 1e-1):
            wrong = dataclasses.replace(sol, v=sol.v + scale * rng.standard_normal(sol.v.shape),
                                        z=sol.z + scale * rng.standard_normal(sol.z.shape),
                                        alpha=sol.alpha + scale * rng.standard_normal(sol.alpha.shape))
            if sol.Lambda is not None:
                wrong = dataclasses.replace(wrong, Lambda=sol.Lambda + scale * rng.standard_normal(sol.Lambda.shape))
            x = x0 + scale * rng.standard_normal(2)
            # the plain form is checked at Θ_k's vertices too when Θ_k is one set for every stage
            for verts in ((vertices, None) if sol.Lambda is None or np.ndim(h) == 1 else (None,)):
                ref = answer_checks.check_tube(wrong, data, x, h, None, verts)
                got = fast.check(wrong, x, verts, h)
                assert [(c.name, c.ran, c.passed) for c in got] == [(c.name, c.ran, c.passed) for c in ref]
                np.testing.assert_allclose([c.value for c in got], [c.value for c in ref], rtol=1e-9, atol=1e-12)
                verdicts.add(bool(answer_checks.failures(got)))
    assert verdicts == {True, False}  # both passing and failing answers were compared
    bad = [dataclasses.replace(sol, v=np.full_like(sol.v, np.nan))]
    if sol.Lambda is not None:
        bad += [dataclasses.replace(sol, Lambda=sol.Lambda[..., :-1]), dataclasses.replace(sol, Lambda=sol.Lambda * np.nan)]
    for b in bad:
        ref, got = answer_checks.check_tube(b, data, x0, h, None, vertices), fast.check(b, x0, vertices, h)
        assert [(c.name, c.ran, c.passed) for c in got] == [(c.name, c.ran, c.passed) for c in ref]
        np.testing.assert_allclose([c.value for c in got], [c.value for c in ref], rtol=1e-9, atol=1e-12)


def test_a_plain_answer_outside_5b_at_the_vertices_is_solved_again_with_refinement():
    """A generated case (Proposition 9, x_0 on the boundary of the feasible set): a plain-form
    first try can meet (15c) and (15d) to 1e-6 each, yet its tube leave (5b) at a vertex of Θ_k
    (here by 1.25e-6); so the plain answer is checked at Θ_k's vertices too (and one that fails is
    solved again with iterative refinement: test_a_first_try_that_fails_the_checks_...). With (15d)
    eliminated (backends/multiplier_basis.py) the first try on this data passes; the recorded tube
    must satisfy Proposition 9 either way."""
    pytest.importorskip("amcp_properties")
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.replay import run_scenario
    from amcp_properties import claims

    spec = load_spec(DATA / "plain-5b-first-try-problem.json")
    traj = run_scenario(spec, "drake", steps=3)
    assert all(answers.qp_applied(r) for r in traj.records)   # a checked answer applied at every step
    assert claims.prediction_tube(traj).passed


def test_tube_check_at_negative_alpha_equals_check_tube(example_spec, example_design):
    """The (5b) rows of TubeCheck take the largest over the vertices x^j of X0 through the α_l term
    alone: its coefficient's maximum for α_l >= 0 and its minimum for α_l < 0. Answers with α_l of
    both signs (and all negative) give the values of check_tube, which forms every row (l, j, s)."""
    from amcp_drake.model import polytope

    ctrl = _controller(example_spec, example_design, "drake", formulation="vertex")
    data, fast = ctrl.data, answer_checks.TubeCheck(ctrl.data)
    H, h0 = np.asarray(example_design.H_theta, float), np.asarray(example_design.h_theta0, float)
    x0 = np.asarray(example_spec.scenario.x0, float)
    vertices = polytope.theta_vertices(H, h0)
    sol = ctrl.mpc.solve(x0, h0, np.zeros(len(example_spec.problem.A)))
    assert sol.status is SolveStatus.OPTIMAL
    signs = np.where(np.arange(len(sol.alpha)) % 2 == 0, -1.0, 1.0)
    for alpha in (-sol.alpha, signs * sol.alpha, -sol.alpha - 0.5):
        wrong = dataclasses.replace(sol, alpha=alpha)
        ref, got = answer_checks.check_tube(wrong, data, x0, h0, None, vertices), fast.check(wrong, x0, vertices, h0)
        assert [(c.name, c.ran, c.passed) for c in got] == [(c.name, c.ran, c.passed) for c in ref]
        np.testing.assert_allclose([c.value for c in got], [c.value for c in ref], rtol=1e-9, atol=1e-12)


#: Vertices of the X0 polygon of the memory test of TubeCheck, and the most bytes its (5b) rows may
#: allocate (measured: 33 MiB, about two blocks of the check's 16 MiB chunks; the rows formed for every
#: vertex of X0 at once needed about 1 GiB).
TUBE_POLYGON_VERTICES = 1000
TUBE_CHECK_BYTES = 64 * 2**20


def test_tube_check_memory_does_not_multiply_x0_and_theta_vertices(example_spec, example_design):
    import tracemalloc

    from amcp_drake.model import polytope

    ctrl = _controller(example_spec, example_design, "drake", formulation="vertex")
    H, h0 = np.asarray(example_design.H_theta, float), np.asarray(example_design.h_theta0, float)
    x0 = np.asarray(example_spec.scenario.x0, float)
    vertices = polytope.theta_vertices(H, h0)
    sol = ctrl.mpc.solve(x0, h0, np.zeros(len(example_spec.problem.A)))
    angles = 2 * np.pi * np.arange(TUBE_POLYGON_VERTICES) / TUBE_POLYGON_VERTICES
    H_x = np.column_stack([np.cos(angles), np.sin(angles)]) / 0.5
    data = dataclasses.replace(ctrl.data, H_x=H_x, X0_vertices=polytope.vertices(H_x, np.ones(len(H_x))),
                               w_bar=np.zeros(len(H_x)))
    fast = answer_checks.TubeCheck(data)
    tracemalloc.start()
    try:
        got = fast.check(sol, x0, vertices, h0)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    ref = answer_checks.check_tube(sol, data, x0, h0, None, vertices)
    assert [(c.name, c.passed) for c in got] == [(c.name, c.passed) for c in ref]
    np.testing.assert_allclose([c.value for c in got], [c.value for c in ref], rtol=1e-9, atol=1e-12)
    assert peak < TUBE_CHECK_BYTES, f"the (5b) rows of TubeCheck allocated {peak / 2**20:.0f} MiB"
