"""``amcp coverage`` (amcp_drake.studies.coverage) on a problem whose feasible region is known by hand.

The system (decoupled, two states, two inputs, one parameter per axis):

    x1⁺ = a θ1 x1 + u1 + w1,   x2⁺ = a θ2 x2 + u2 + w2,   θ ∈ [−1, 1]², |w_i| <= w,
    |x1| <= 2, |x2| <= 1, |u_i| <= 5,  K = 0 (given), X0 a box (4 facets), N = 2, a = 0.5, w = 0.1.

By hand: the tube is z + α X0 with X0 = [−r, r]² (r from the template iteration; it cancels).
(15a)-(15b) at l = 0 force |x0_i| <= xmax_i (x0 ∈ z0 + α0 X0 and the state rows). The successor
set of x0 is the box centred at v0 (A0 = 0, B = I) with half-widths a|x0_i| + w, so the next tube
needs α1 r >= max_i (a|x0_i| + w) whatever z1 is; the rows of X_f^0 = {(F + GK) z + f̄ α <= 1} give
α r <= 1 − |z2| <= 1, and with z1 = 0 the terminal recursion (A_z = A_cl(θ̂0) = 0) only adds
a α r + w <= 1, which α r <= 1 implies. Hence 𝔻(x0, Θ) ≠ ∅ iff

    |x2| <= 1  and  a|x1| + w <= 1, i.e. |x1| <= (1 − w)/a = 1.8   (and |x1| <= 2, implied).

So the robust region is the rectangle [−1.8, 1.8] × [−1, 1], strictly inside the state box.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import amcp_drake.studies.coverage as coverage_region
from amcp_drake.cli import main
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec, Scenario
from amcp_drake.model.problem_io import save_spec
from amcp_drake.offline.design import design
from amcp_drake.studies.coverage import TubeLP, grid_points, run_coverage

A_GAIN, W_MAX = 0.5, 0.1
X1_EDGE = (1.0 - W_MAX) / A_GAIN  # 1.8, the hand-computed boundary in x1
X2_EDGE = 1.0
BOX = np.array([[-2.5, 2.5], [-1.5, 1.5]])
GRID = 11  # x1 ∈ {−2.5, −2, …, 2.5}, x2 ∈ {−1.5, −1.2, …, 1.5}: no grid point on the boundary


def decoupled_spec() -> ProblemSpec:
    a = A_GAIN
    problem = Problem(
        A0=np.zeros((2, 2)), B0=np.eye(2), A=[[[a, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, a]]],
        B=np.zeros((2, 2, 2)), H_w=np.vstack([np.eye(2), -np.eye(2)]) / W_MAX,
        H_theta=np.vstack([np.eye(2), -np.eye(2)]), h_theta=np.ones(4),
        F=np.vstack([np.diag([0.5, 1.0]), -np.diag([0.5, 1.0]), np.zeros((4, 2))]),
        G=np.vstack([np.zeros((4, 2)), np.eye(2) / 5.0, -np.eye(2) / 5.0]),
        Q=np.eye(2), R=np.eye(2), N=2, theta_hat0=np.zeros(2), name="decoupled")
    # K = 0 and P = 2 I satisfy (16): a² P + Q − P = −0.5 I
    options = DesignOptions(x0_facets=4, K=np.zeros((2, 2)), P=2.0 * np.eye(2))
    scenario = Scenario(x0=np.array([0.5, 0.5]), theta_star=np.array([0.6, -0.4]), steps=10)
    return ProblemSpec(problem=problem, design=options, scenario=scenario)


def hand_region(points: np.ndarray) -> np.ndarray:
    return (np.abs(points[:, 0]) <= X1_EDGE) & (np.abs(points[:, 1]) <= X2_EDGE)


@pytest.fixture(scope="module")
def spec():
    return decoupled_spec()


@pytest.fixture(scope="module")
def offline(spec):
    return design(spec.problem, spec.design, backend="drake")


@pytest.mark.parametrize("backend, formulation", [("drake", "vertex"), ("drake", "plain"), ("cvxpy", "vertex")])
def test_robust_region_is_the_hand_computed_rectangle(spec, offline, backend, formulation):
    points, axes = grid_points(BOX, GRID)
    res = run_coverage(spec, offline, points, axes=axes, backend=backend, formulation=formulation)
    expected = hand_region(points)
    assert 0 < expected.sum() < len(points)  # the box cuts the region on both sides
    np.testing.assert_array_equal([v.feasible for v in res.robust], expected)
    np.testing.assert_array_equal([v.lp_feasible for v in res.robust], expected)  # the LP alone, too
    assert res.summary()["robust_fraction"] == pytest.approx(expected.mean())
    assert res.passed and res.summary()["disagree_count"] == 0


@pytest.mark.parametrize("x0, feasible", [((X1_EDGE - 0.01, 0.0), True), ((X1_EDGE + 0.01, 0.0), False),
                                          ((0.0, X2_EDGE - 0.01), True), ((0.0, X2_EDGE + 0.01), False),
                                          ((X1_EDGE - 0.01, X2_EDGE - 0.01), True)])
def test_lp_slack_changes_sign_at_the_hand_computed_boundary(spec, offline, x0, feasible):
    lp = TubeLP.build(spec.problem, offline, offline.H_theta, offline.h_theta0)
    t = lp.margin(np.array(x0))
    assert (t > coverage_region.AGREEMENT_TOL) if feasible else (t < -coverage_region.AGREEMENT_TOL)


def test_adapted_region_contains_the_robust_one(spec, offline):
    points, axes = grid_points(BOX, GRID)
    res = run_coverage(spec, offline, points, axes=axes, adapt_steps=8)
    robust = np.array([v.feasible for v in res.robust])
    adaptive = np.array([v.feasible for v in res.adaptive])
    assert np.all(adaptive[robust]) and res.issues()["monotonicity"] == []
    # Θ_T is narrower in θ1, so x1 beyond 1.8 becomes feasible (|x1| <= 2 remains a hard bound)
    assert adaptive.sum() > robust.sum()
    assert not np.any(adaptive[np.abs(points[:, 0]) > 2.0]) and not np.any(adaptive[np.abs(points[:, 1]) > 1.0])
    assert res.adapt_info["steps_run"] == 8 and res.passed


def test_a_lying_qp_is_reported_as_disagreement(spec, offline, monkeypatch):
    """A stubbed QP that calls every point feasible: the LP exposes every point outside the region."""
    monkeypatch.setattr(coverage_region, "qp_status", lambda *args, **kwargs: "optimal")
    points, axes = grid_points(BOX, GRID)
    res = run_coverage(spec, offline, points, axes=axes)
    outside = np.flatnonzero(~hand_region(points))
    listed = [row["index"] for row in res.issues()["disagree"]]
    assert listed == outside.tolist()
    assert all(row["lp_margin"] < 0 and row["qp_status"] == "optimal" for row in res.issues()["disagree"])
    assert not res.passed and res.summary()["disagree_count"] == len(outside)


def test_undecided_qp_is_reported(spec, offline, monkeypatch):
    monkeypatch.setattr(coverage_region, "qp_status", lambda *args, **kwargs: "solver_error")
    res = run_coverage(spec, offline, np.array([[0.0, 0.0], [2.2, 0.0]]))
    assert [row["index"] for row in res.issues()["qp_undecided"]] == [0, 1]
    assert [v.feasible for v in res.robust] == [True, False]  # the LP's verdict, flagged
    assert not res.passed


@pytest.fixture(scope="module")
def problem_file(spec, tmp_path_factory):
    return str(save_spec(spec, tmp_path_factory.mktemp("cov") / "decoupled.json"))


def test_cli_writes_json_and_png(problem_file, tmp_path):
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["coverage", problem_file, "--grid", str(GRID), "--box", "-2.5:2.5,-1.5:1.5",
                                  "--adapt", "4", "--out", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    data = json.loads((out / "coverage.json").read_text())
    points = np.array(data["points"])
    assert data["summary"]["robust_fraction"] == pytest.approx(hand_region(points).mean())
    assert data["summary"]["disagree_count"] == 0 and data["adapt"]["steps_run"] == 4
    assert (out / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "robust Θ: feasible fraction" in r.output


def test_cli_exit_1_and_listing_on_disagreement(problem_file, tmp_path, monkeypatch):
    monkeypatch.setattr(coverage_region, "qp_status", lambda *args, **kwargs: "infeasible")
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["coverage", problem_file, "--points", _points_file(tmp_path, [[0.0, 0.0], [3.0, 0.0]]),
                                  "--out", str(out), "--no-progress"])
    assert r.exit_code == 1, r.output
    assert "1 disagreements" in r.output and "disagree: x0 = [0., 0.]" in r.output
    data = json.loads((out / "coverage.json").read_text())
    assert data["issues"]["disagree"][0]["x0"] == [0.0, 0.0]


def _points_file(tmp_path, points) -> str:
    path = tmp_path / "points.json"
    path.write_text(json.dumps({"points": points}))
    return str(path)


@pytest.mark.parametrize("args, field", [
    (["--box", "-1:1"], "--box"),                      # one interval for two states
    (["--box", "1:-1,0:1"], "--box"),                  # LO > HI
    (["--box", "a:b,0:1"], "--box"),
    (["--points", "{bad}"], "--points"),               # replaced by a file below
    (["--grid", "0"], "--grid"),
    (["--example", "no_such_example"], "--example"),
])
def test_cli_bad_input_exits_2_without_output(problem_file, tmp_path, args, field):
    if args[0] == "--points":
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps({"points": [[1.0, 2.0, 3.0]]}))
        args = ["--points", str(bad)]
    out = tmp_path / "out"
    base = [] if args[0] == "--example" else [problem_file]
    r = CliRunner().invoke(main, ["coverage", *base, *args, "--out", str(out), "--no-progress"])
    assert r.exit_code == 2, r.output
    assert field in r.output and "Traceback" not in r.output
    assert not (out / "coverage.json").exists()


def test_polytope_points_file_keeps_grid_points_inside(tmp_path):
    path = tmp_path / "poly.json"
    path.write_text(json.dumps({"polytope": {"H": [[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1]], "h": [1, 1, 1, 1, 0]}}))
    pts, _ = coverage_region.load_points(path, 2, 5)
    assert np.all(pts[:, 0] + pts[:, 1] <= 1e-12) and np.all(np.abs(pts) <= 1.0)
    assert len(pts) == 15  # 5×5 grid on [−1, 1]²: the 15 points with x1 + x2 <= 0


@pytest.mark.parametrize("n, drawn", [(1, True), (2, True), (3, False)])
def test_png_for_n_up_to_2_only(tmp_path, n, drawn):
    from amcp_drake.studies.coverage import CoverageResult, PointVerdict, write_coverage

    points = np.zeros((2, n))
    points[1, 0] = 1.0
    res = CoverageResult(problem="p", n=n, points=points, source="s", axes=None, backend="drake",
                         formulation="vertex", robust=[PointVerdict("optimal", 0.5), PointVerdict("infeasible", -0.5)])
    js, png = write_coverage(res, tmp_path)
    assert json.loads(js.read_text())["classes"] == ["robust", "infeasible"]
    assert (png is not None) == drawn and (tmp_path / "coverage.png").exists() == drawn


def test_cli_adapt_x0_and_warning_when_the_run_stops(problem_file, tmp_path):
    """--adapt-x0 outside the region: the run stops at step 0, which is said (exit 0: no disagreement)."""
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["coverage", problem_file, "--grid", "3", "--adapt", "5", "--adapt-x0", "1.9,0",
                                  "--out", str(out), "--no-progress"])
    assert r.exit_code == 0, r.output
    assert "WARNING: the adaptive run from x0 = [1.9, 0.0] stopped after 0 of 5 steps" in r.output
    data = json.loads((out / "coverage.json").read_text())
    assert data["adapt"]["steps_run"] == 0 and data["adapt"]["x0"] == [1.9, 0.0]
    r = CliRunner().invoke(main, ["coverage", problem_file, "--adapt", "5", "--adapt-x0", "1,2,3", "--out", str(out)])
    assert r.exit_code == 2 and "--adapt-x0" in r.output
