"""Certificate claim ``qp_optimality``: the recorded (z, α, v) of every solved
step is a minimiser of the QP (20) rebuilt from the record, shown by KKT residuals with numpy/scipy.

Honest runs pass (both backends, min–max cost, Example 2 with PE bounds and the predicted sets (26));
a design P edited within (16), a recorded decision replaced by another feasible one, and the same
with u and the cost made consistent all fail, the last two surgically (only this claim fails). The
feasible replacements are produced by the backend (a test may use one; the certificate never does).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.certificate.certify import certify
from amcp_drake.certificate.optimality import OPTIMALITY_TOL, ce_gradient, kkt_residuals
from amcp_drake.certificate.section4 import ENFORCED
from amcp_drake.model.options import OnlineOptions
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate

CLAIM = "qp_optimality"


def as_file(traj: Trajectory) -> dict:
    """The trajectory as the JSON dict of its file (what a user could edit)."""
    return json.loads(json.dumps(traj.to_dict()))


def load(data: dict) -> Trajectory:
    return Trajectory.from_dict(json.loads(json.dumps(data)))


def assert_fails_exactly(cert, expected: set[str]) -> None:
    assert set(cert.ids("fail")) == expected, f"failed {cert.ids('fail')}, expected {sorted(expected)}"
    assert cert.ids("not_run") == []


def run(spec, design, options, steps, backend="drake", theta_star=None) -> Trajectory:
    ctrl = AdaptiveMPC(spec.problem, design, backend=backend, options=options)
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star if theta_star is None else theta_star, steps, "uniform", seed=0,
                    mu_state_bound=spec.design.mu_state_bound)
    assert traj.stop_reason == "completed"
    return traj


@pytest.fixture(scope="module")
def drake_file(example_run) -> dict:
    return as_file(example_run)


@pytest.fixture(scope="module")
def minmax_run(example_spec, example_design) -> Trajectory:
    return run(example_spec, example_design, OnlineOptions(cost="minmax"), 10)


@pytest.fixture(scope="module")
def ex2_run(example_design) -> tuple:
    """Example 2 (d_θ = 0.01, PE window 3, level 0.8, drifting θ*_k), 15 steps, Drake."""
    from amcp_drake.model.examples import lorenzen2019_ex2_spec

    spec = lorenzen2019_ex2_spec()
    assert (spec.online.d_theta, spec.online.pe_window, spec.online.pe_level) == (0.01, 3, 0.8)
    traj = run(spec, example_design, spec.online, 15, theta_star=spec.scenario.theta_star_for(15))
    return spec, traj


# -- honest runs pass -----------------------------------------------------------------------------
@pytest.mark.parametrize("fixture", ["example_run", "example_run_cvxpy"])
def test_example_1_runs_of_both_backends_are_optimal(fixture, request, example_spec):
    traj = request.getfixturevalue(fixture)
    cert = certify(traj, example_spec)
    claim = cert.claim(CLAIM)
    assert claim.status == "pass" and claim.tolerance == OPTIMALITY_TOL
    assert claim.margin >= -OPTIMALITY_TOL / 10  # headroom, see docs/certificate.md (observed <= 1e-6)
    assert [k for k, _ in claim.data["per_step"]] == list(range(51))  # every solved step was checked
    assert cert.passed


def test_minmax_run_is_optimal(minmax_run, example_spec):
    claim = certify(minmax_run, example_spec).claim(CLAIM)
    assert claim.status == "pass" and claim.data["cost"] == "minmax"
    assert len(claim.data["per_step"]) == 11


def test_example_2_with_pe_bounds_and_predicted_sets_is_optimal(ex2_run):
    spec, traj = ex2_run
    assert any(r.pe_status in ENFORCED and r.pe_bounds is not None for r in traj.records)  # bound rows used
    assert all(r.h_theta_stages is not None for r in traj.records)                       # (26) per stage
    cert = certify(traj, spec)
    assert cert.claim(CLAIM).status == "pass"
    assert cert.ids("fail") == []


# -- tampering fails -------------------------------------------------------------------------------
def test_terminal_weight_raised_within_16_fails_only_optimality(drake_file, example_spec):
    """The issue's case: design P[0][0] raised by 0.1. P enters neither a constraint nor (16) in a way
    that breaks it (the design claim still passes), and the recorded cost moves by ~1e-7 relative
    (below cost_value's tolerance); only the recorded v is no longer the minimiser of (17)."""
    data = json.loads(json.dumps(drake_file))
    data["design"]["P"][0][0] += 0.1
    cert = certify(load(data), example_spec)
    assert_fails_exactly(cert, {CLAIM})
    assert cert.claim("design.terminal_cost_16").status == "pass"
    assert cert.claim(CLAIM).margin < -2 * OPTIMALITY_TOL  # measured −6.1e-5


def test_minmax_terminal_weight_raised_fails_optimality(minmax_run, example_spec):
    data = as_file(minmax_run)
    data["design"]["P"][0][0] += 0.1
    assert certify(load(data), example_spec).claim(CLAIM).status == "fail"


def _feasible_replacement(spec, design, record) -> dict:
    """Another feasible decision of step T's QP: the midpoint of the recorded one and the Drake solution of
    the same QP with θ̂ = [−1, −1, 1] (θ̂ enters only the cost (17), so that solution is feasible too, and
    (15) is convex, so the midpoint is feasible; by strict convexity in v it is not optimal)."""
    ctrl = AdaptiveMPC(spec.problem, design, backend="drake")
    other = ctrl.mpc.solve(record["x"], np.asarray(record["h_theta"]), np.array([-1.0, -1.0, 1.0]))
    assert other.status.value == "optimal"
    mid = {name: 0.5 * (np.asarray(record[name]) + getattr(other, name)) for name in ("v", "z", "alpha", "Lambda")}
    assert np.max(np.abs(mid["v"] - np.asarray(record["v"]))) > 1e-3
    return mid


def _ce_cost(problem, design, x, theta_hat, v) -> float:
    """(17)-(18) written out (independent of the certificate's own evaluation)."""
    A = problem.A0 + sum(t * Ai for t, Ai in zip(theta_hat, problem.A))
    B = problem.B0 + sum(t * Bi for t, Bi in zip(theta_hat, problem.B))
    K, P = np.asarray(design.K), np.asarray(design.P)
    xh, J = np.asarray(x, float), 0.0
    for vl in v:
        u = K @ xh + vl
        J += xh @ problem.Q @ xh + u @ problem.R @ u
        xh = A @ xh + B @ u
    return float(J + xh @ P @ xh)


def test_decision_replaced_by_another_feasible_one_fails(drake_file, example_spec, example_design):
    """The last record's (v, z, α, Λ) replaced by a feasible, non-optimal one, u and cost left as recorded:
    the tube and multiplier claims hold (it is feasible); (21) and the cost no longer match; and it is
    not optimal."""
    data = json.loads(json.dumps(drake_file))
    record = data["records"][-1]
    for name, value in _feasible_replacement(example_spec, example_design, record).items():
        record[name] = value.tolist()
    cert = certify(load(data), example_spec)
    assert_fails_exactly(cert, {CLAIM, "control_law", "cost_value"})
    assert cert.claim(CLAIM).data["worst_step"] == len(data["records"]) - 1


def test_cost_altered_consistently_with_a_tampered_decision_fails_only_optimality(drake_file, example_spec,
                                                                                   example_design):
    """As above, with u_T = K x_T + v_0 and the cost of the new v written in as well: every other claim
    is satisfied by the forgery; only optimality exposes it."""
    data = json.loads(json.dumps(drake_file))
    record = data["records"][-1]
    mid = _feasible_replacement(example_spec, example_design, record)
    for name, value in mid.items():
        record[name] = value.tolist()
    record["u"] = (np.asarray(data["design"]["K"]) @ np.asarray(record["x"]) + mid["v"][0]).tolist()
    record["cost"] = _ce_cost(example_spec.problem, example_design, record["x"], record["theta_hat"], mid["v"])
    assert record["cost"] > drake_file["records"][-1]["cost"]  # a worse decision, passed off as the optimum
    cert = certify(load(data), example_spec)
    assert_fails_exactly(cert, {CLAIM})


def test_cli_exits_1_naming_the_claim(drake_file, tmp_path):
    from amcp_drake.cli import main

    data = json.loads(json.dumps(drake_file))
    data["design"]["P"][0][0] += 0.1
    path = load(data).save(tmp_path / "tampered.json.gz")
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(path), "--out", str(tmp_path / "out")],
                                catch_exceptions=False)
    assert result.exit_code == 1, result.output
    assert "NOT CERTIFIED: 1 claim(s) failed: qp_optimality" in result.output
    row = next(line for line in result.output.splitlines() if line.startswith(CLAIM))
    assert " fail " in row
    saved = json.loads((tmp_path / "out" / "certificate.json").read_text())
    assert [c["id"] for c in saved["claims"] if c["status"] == "fail"] == [CLAIM]


def test_unenumerable_theta_k_is_not_run_never_pass(drake_file, example_spec):
    """Θ_3 made empty (θ1 <= −2 against θ1 >= −1): its vertices do not exist, so the QP cannot be rebuilt
    at step 3; the claim is not_run (not pass), whatever the other claims say."""
    data = json.loads(json.dumps(drake_file))
    assert data["records"][3]["H_theta"][0] == [1.0, 0.0, 0.0]
    data["records"][3]["h_theta"][0] = -2.0
    claim = certify(load(data), example_spec).claim(CLAIM)
    assert claim.status == "not_run" and claim.margin is None
    assert "3" in claim.detail


# -- building blocks against known answers ---------------------------------------------------------
def test_ce_gradient_matches_finite_differences_of_17(example_spec, example_design, rng):
    """(17) is quadratic in v, so central differences are exact up to rounding."""
    pr = example_spec.problem
    x, theta_hat = np.array([1.5, -0.2]), np.array([0.3, -0.7, 0.4])
    v = rng.normal(size=(pr.N, pr.m))
    grad = ce_gradient(pr, example_design, x, theta_hat, v)
    h = 1e-5
    for l in range(pr.N):
        up, down = v.copy(), v.copy()
        up[l, 0] += h
        down[l, 0] -= h
        fd = (_ce_cost(pr, example_design, x, theta_hat, up) - _ce_cost(pr, example_design, x, theta_hat, down)) / (2 * h)
        assert grad[l, 0] == pytest.approx(fd, rel=1e-7, abs=1e-8)


def test_kkt_residuals_of_a_one_dimensional_qp():
    """min (v − 2)² s.t. v <= 1. At v = 1: ∇f = −2, the row is active with ω = 2, residual 0. At v = 1.5
    (infeasible by 0.5): ω = 1, residual 0, infeasibility 0.5. At v = 0.5: ∇f = −3 and the row at slack 0.5;
    the worst of stationarity |ω − 3|/3 and complementarity 0.5 ω/3 is least at ω = 2: 1/3 (by hand; the LP
    certificate brackets it from above to within its bisection's resolution, 0.4 %)."""
    A, b = np.array([[1.0]]), np.array([1.0])
    at_bound = kkt_residuals(A, b, np.array([1.0]), [np.array([-2.0])])
    assert at_bound["stationarity"] == pytest.approx(0.0, abs=1e-15) and at_bound["active"] == 1
    assert at_bound["infeasibility"] == 0.0
    inside = kkt_residuals(A, b, np.array([0.5]), [np.array([-3.0])])
    assert 1.0 / 3.0 * (1 - 1e-12) <= _worst(inside) <= 1.0 / 3.0 * 1.005
    outside = kkt_residuals(A, b, np.array([1.5]), [np.array([-1.0])])
    assert outside["stationarity"] == pytest.approx(0.0, abs=1e-15) and outside["infeasibility"] == pytest.approx(0.5)


def _worst(res):
    return max(res["stationarity"], res["complementarity"], res["infeasibility"])


@pytest.mark.parametrize("factor, passes", [(0.5, True), (2.0, False)])
def test_kkt_residual_of_a_point_short_of_its_active_row_at_the_tolerance_edge(factor, passes):
    """Complementarity at its edge: min (y − 1)² s.t. y <= 0, judged at y = −δ (the row's slack δ,
    ∇f = −2(1 + δ) = −G, s = G). With ω on the row, stationarity |G − ω|/G and complementarity δ ω/G; the worst
    is least at ω = G/(1 + δ): δ/(1 + δ) (by hand). At δ = 0.5·OPTIMALITY_TOL the point passes, at
    2·OPTIMALITY_TOL it fails; the value reported lies between that minimum and δ (the certificate ω = G)."""
    delta = factor * OPTIMALITY_TOL
    res = kkt_residuals(np.array([[1.0]]), np.array([0.0]), np.array([-delta]), [np.array([-2.0 * (1.0 + delta)])])
    assert delta / (1.0 + delta) * (1 - 1e-12) <= _worst(res) <= delta * (1 + 1e-12)
    assert (_worst(res) <= OPTIMALITY_TOL) is passes


@pytest.mark.parametrize("factor, passes", [(0.5, True), (2.0, False)])
def test_kkt_stationarity_of_a_point_whose_cost_decreases_into_the_interior_at_the_tolerance_edge(factor, passes):
    """Stationarity at its edge: f(y) = (y1 + 1)² − (2 − e) y1 + y2², rows y1 <= 0 and y2 <= 0, judged at y = 0
    where both rows are active. ∇f = (e, 0) from the parts (2, 0) and (−(2 − e), 0) (s = 2): f decreases as y1
    moves into the interior, and no ω >= 0 helps (ω on y1 <= 0 adds +ω to the first component, ω on y2 <= 0
    only a residual in the second), so the residual is e/2 (by hand) and complementarity 0 (both rows at
    slack 0). With e/2 = factor·OPTIMALITY_TOL the point passes at 0.5, fails at 2."""
    e = 2.0 * factor * OPTIMALITY_TOL
    res = kkt_residuals(np.eye(2), np.zeros(2), np.zeros(2), [np.array([2.0, 0.0]), np.array([-(2.0 - e), 0.0])])
    assert res["stationarity"] == pytest.approx(e / 2.0, rel=1e-9)
    assert res["complementarity"] == 0.0 and res["infeasibility"] == 0.0
    assert (_worst(res) <= OPTIMALITY_TOL) is passes


@pytest.mark.parametrize("factor, passes", [(0.5, True), (2.0, False)])
def test_kkt_many_slightly_slack_rows_do_not_certify_together(factor, passes):
    """Complementarity is a sum over rows (the duality gap), not a per-row allowance: f(y) = (y + 1)², judged at
    y = 0 (∇f = 2, s = 2), with 100 copies of the row −y <= σ (each at slack σ). Any ω on them gives
    stationarity |2 − W|/2 and complementarity σ W/2 with W = Σ ω_i, whatever the split; the worst is least
    at W = 2/(1 + σ): σ/(1 + σ) (by hand), the value of a single such row. (A per-row maximum would allow W = 2
    at σ·2/100/2 = σ/100, certifying a point 100x further from its rows.) σ = factor·OPTIMALITY_TOL."""
    sigma = factor * OPTIMALITY_TOL
    res = kkt_residuals(-np.ones((100, 1)), np.full(100, sigma), np.zeros(1), [np.array([2.0])])
    assert sigma / (1 + sigma) * (1 - 1e-9) <= _worst(res) <= sigma * 1.005
    assert (_worst(res) <= OPTIMALITY_TOL) is passes


def test_kkt_multipliers_prefer_active_rows_when_the_dual_is_not_unique():
    """min (y1 − 1)² + (y2 − 1)² s.t. y1 + y2 <= √2·1e-4 (listed first; unit row (1, 1)/√2 at slack 1e-4),
    y1 <= 0, y2 <= 0, at its optimum y = 0 (∇f = (−2, −2)). Stationarity alone is met either by ω = 2√2 on
    the first row, which is not active (complementarity 2√2·1e-4/2 ≈ 1.4e-4, 14x the tolerance, charged to an
    exact optimum), or by ω = (2, 2) on the active rows (complementarity 0). The certificate takes the second:
    the worst residual is (near) 0. (The degenerate case of nearly parallel vertex rows on a thin Θ_k.)"""
    A, b = np.array([[1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]), np.array([np.sqrt(2.0) * 1e-4, 0.0, 0.0])
    res = kkt_residuals(A, b, np.zeros(2), [np.array([-2.0, -2.0])])
    assert _worst(res) <= 1e-8


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_a_generated_minmax_run_certifies_optimal(backend):
    """A generated min–max run (tests/data/minmax-kkt-problem.json: random_case numpy seed 5018, N <= 6,
    12 steps, cost "minmax"): at Clarabel's default 1e-8 the plans were optimal only to about √tol and
    ``qp_optimality`` failed an honest run on both backends (stationarity 2.2e-5 > 1e-5, the only failing
    claim); the min–max QP is now tried at MINMAX_TIGHT first (clarabel_retry): 1.4e-6 / 1.7e-6."""
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.replay import run_scenario

    spec = load_spec("tests/data/minmax-kkt-problem.json")
    traj = run_scenario(spec, backend, design_backend="drake")
    assert traj.stop_reason == "completed"
    cert = certify(traj, spec)
    assert cert.claim(CLAIM).status == "pass" and cert.claim(CLAIM).data["cost"] == "minmax"
    assert cert.claim(CLAIM).margin > -OPTIMALITY_TOL / 2
    assert cert.verdict == "pass", cert.ids("fail")


def _recorded_step(name: str, vertex_count: int):
    """A recorded step of tests/data (only the fields the claim reads) as a one-step view, with its record."""
    from pathlib import Path
    from types import SimpleNamespace

    from amcp_drake.certificate.claims import theta_vertices

    raw = json.loads((Path(__file__).parent / "data" / name).read_text())
    arrays = {k: (v if k == "N" else np.asarray(v, float)) for k, v in raw["problem"].items()}
    problem = SimpleNamespace(**arrays, n=arrays["A0"].shape[0], m=arrays["B0"].shape[1])
    design = SimpleNamespace(**{k: np.asarray(v, float) for k, v in raw["design"].items()})
    record = SimpleNamespace(**{k: np.asarray(v, float) for k, v in raw["record"].items()}, h_theta_stages=None,
                             pe_bounds=None)
    vertices = theta_vertices(record.H_theta, record.h_theta)
    assert vertices is not None and len(vertices) == vertex_count
    return SimpleNamespace(problem=problem, design=design, records=[record], theta_k_vertices=[vertices]), record


def test_an_answer_within_the_solvers_tolerance_on_a_degenerate_8_state_step_is_certified_optimal():
    """mass_chain4 (n = 8, 256 vertices of X0, Θ_k with 8 vertices), step 2 of a Drake run
    (tests/data/mass-chain4-kkt-step.json): 628 vertex rows within 1e-2 of active, many nearly parallel. The
    recorded plan is 1.6e-7 from the optimum (Clarabel's default 1e-8; the Drake and cvxpy vertex forms at
    1e-12 agree on the optimum to 1e-14). Fitting ω to stationarity alone loads rows at slack ~1e-4 and
    charges this answer 1.87e-5 (over OPTIMALITY_TOL); the multipliers minimising the worst residual over
    every row certify it (measured 1.7e-6)."""
    from amcp_drake.certificate.optimality import step_residuals

    view, _ = _recorded_step("mass-chain4-kkt-step.json", 8)
    assert _worst(step_residuals(view, 0, "certainty_equivalence")) <= OPTIMALITY_TOL / 5


def test_an_optimal_quadrotor_plan_whose_gradient_is_below_the_scale_floor_is_certified_optimal():
    """ji2022_quadrotor (n = 4, 102-facet X0, N = 15), step 6 of a cvxpy plain-form run
    (tests/data/ji2022-quadrotor-kkt-step.json). The plan equals the Drake and cvxpy vertex-form solutions of
    the same QP to 8e-10 in v (their costs agree to 2e-14); 2632 rows are within 1e-2 of active. The gradient of
    (17) is ~1e-5, a difference of parts ~5e-3 along (18) and of curvature and state parts H v and q ~5.9
    (|B(θ̂)| ≈ 86); judged against the parts along (18) alone (s = SCALE_FLOOR) with a per-row
    complementarity and NNLS multipliers, this answer was charged 1.24e-5 (over OPTIMALITY_TOL). Measured
    now: 9.1e-8."""
    from amcp_drake.certificate.optimality import step_residuals

    view, _ = _recorded_step("ji2022-quadrotor-kkt-step.json", 2)
    res = step_residuals(view, 0, "certainty_equivalence")
    assert _worst(res) <= OPTIMALITY_TOL / 5


def test_a_feasible_quadrotor_plan_a_few_millionths_dearer_than_the_recorded_optimum_fails():
    """The recorded quadrotor step's plan y* moved towards another feasible point y' of the same QP (the vertex
    of the rebuilt feasible set maximising v_0, by HiGHS: setup only) until (17), evaluated here independently,
    rises by 3e-6 of its value: the plan stays feasible (convex set) and is not optimal, and the claim fails
    it by more than twice the tolerance (measured 1.9e-3)."""
    from scipy.optimize import linprog

    from amcp_drake.certificate.optimality import _Layout, constraint_rows, step_residuals

    view, record = _recorded_step("ji2022-quadrotor-kkt-step.json", 2)
    pr, d = view.problem, view.design
    lay = _Layout(pr.n, pr.m, pr.N)
    A, b = constraint_rows(pr, d, lay, record.x, [view.theta_k_vertices[0]] * pr.N, None)
    y_star = lay.pack(record.z, record.alpha, record.v)
    c = np.zeros(lay.size)
    c[lay.v0] = -1.0
    other = linprog(c, A_ub=A, b_ub=b, bounds=(None, None), method="highs")
    assert other.status == 0

    def cost(t: float) -> float:
        y = y_star + t * (other.x - y_star)
        return _ce_cost(pr, d, record.x, record.theta_hat, y[lay.v0:].reshape(pr.N, pr.m))

    J0 = cost(0.0)
    assert cost(1.0) > J0 * (1 + 3e-6)
    lo, hi = 0.0, 1.0
    for _ in range(60):  # J is convex along the segment and least at t = 0: increasing in t
        lo, hi = ((lo + hi) / 2, hi) if cost((lo + hi) / 2) < J0 * (1 + 3e-6) else (lo, (lo + hi) / 2)
    y = y_star + hi * (other.x - y_star)
    assert cost(hi) / J0 - 1 == pytest.approx(3e-6, rel=1e-3)
    record.z = y[:lay.a0].reshape(pr.N + 1, pr.n)
    record.alpha = y[lay.a0:lay.v0]
    record.v = y[lay.v0:].reshape(pr.N, pr.m)
    res = step_residuals(view, 0, "certainty_equivalence")
    assert res["infeasibility"] <= 1e-9
    assert _worst(res) > 2 * OPTIMALITY_TOL
