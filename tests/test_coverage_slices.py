"""``amcp coverage`` at n = 3: slices (``--plane``, ``--fix``), the cost printed before a grid runs, and the
refusal of a grid above the limit.

The system is tests/test_coverage.py's decoupled one with a third state (one parameter per state):

    x_i⁺ = a θ_i x_i + u_i + w_i,  θ ∈ [−1, 1]³, |w_i| <= w,  |x1| <= 2, |x2| <= 1, |x3| <= 1, |u_i| <= 5,
    K = 0 (given), X0 a box, N = 2, a = 0.5, w = 0.1.

By the argument of tests/test_coverage.py (the tube's cross-section is α X0 with X0 a box; the tightest
state row bounds α r by 1, the next tube needs α_1 r >= max_i (a|x0_i| + w)), 𝔻(x0, Θ) ≠ ∅ iff

    |x1| <= (1 − w)/a = 1.8,  |x2| <= 1,  |x3| <= 1.

So the slice x3 = c of the region is the rectangle [−1.8, 1.8] × [−1, 1] for |c| <= 1 and empty for |c| > 1.
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

A_GAIN, W_MAX = 0.5, 0.1
X1_EDGE = (1.0 - W_MAX) / A_GAIN  # 1.8
GRID = 11  # on [−2.5, 2.5] × [−1.5, 1.5]: no grid point on the boundary
BOX = "-2.5:2.5,-1.5:1.5"
LABELS = ("p [m]", "v [m/s]", "phi [rad]")


def three_state_spec() -> ProblemSpec:
    a = A_GAIN
    problem = Problem.from_matrices(
        np.zeros((3, 3)), np.eye(3), A=[np.diag(row) for row in a * np.eye(3)], B=np.zeros((3, 3, 3)),
        states=[("p", "m"), ("v", "m/s"), ("phi", "rad")], inputs=["F1", "F2", "F3"], W_box=[W_MAX] * 3,
        Theta_box=[(-1, 1)] * 3, x_bounds={"p": (-2, 2), "v": (-1, 1), "phi": (-1, 1)},
        u_bounds={f"F{i}": (-5, 5) for i in (1, 2, 3)}, Q=np.eye(3), R=np.eye(3), N=2, name="decoupled3")
    # K = 0 and P = 2 I satisfy (16): a² P + Q − P = −0.75 I
    return ProblemSpec(problem=problem, design=DesignOptions(x0_facets=6, K=np.zeros((3, 3)), P=2.0 * np.eye(3)),
                       scenario=Scenario(x0=np.array([0.5, 0.5, 0.2]), theta_star=np.array([0.6, -0.4, 0.2]), steps=10))


@pytest.fixture(scope="module")
def problem_file(tmp_path_factory):
    return str(save_spec(three_state_spec(), tmp_path_factory.mktemp("cov3") / "decoupled3.json"))


def _run(problem_file, out, *args):
    return CliRunner().invoke(main, ["coverage", problem_file, *args, "--out", str(out), "--no-progress"])


@pytest.mark.parametrize("fixed, inside", [(0.95, True), (1.05, False), (-0.95, True), (-1.05, False)])
def test_a_slice_is_the_hand_computed_cross_section(problem_file, tmp_path, fixed, inside):
    """The slice phi = c in the plane (p, v): the rectangle |p| <= 1.8, |v| <= 1 for |c| <= 1 (just inside),
    nothing for |c| > 1 (just outside)."""
    out = tmp_path / "out"
    r = _run(problem_file, out, "--plane", "p,v", "--fix", f"phi={fixed}", "--grid", str(GRID), "--box", BOX)
    assert r.exit_code == 0, r.output
    data = json.loads((out / "coverage.json").read_text())
    points = np.array(data["points"])
    assert points.shape == (GRID * GRID, 3) and np.all(points[:, 2] == fixed)
    expected = (np.abs(points[:, 0]) <= X1_EDGE) & (np.abs(points[:, 1]) <= 1.0) & inside
    assert [c == "robust" for c in data["classes"]] == expected.tolist()
    assert data["summary"]["disagree_count"] == 0
    assert data["slice"] == {"plane": ["p [m]", "v [m/s]"], "plane_index": [1, 2], "fixed": {"phi [rad]": fixed}}
    assert (out / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_other_states_are_zero_unless_fixed_and_the_plane_may_be_given_by_index(problem_file, tmp_path):
    out = tmp_path / "out"
    r = _run(problem_file, out, "--plane", "3,1", "--grid", "3")
    assert r.exit_code == 0, r.output
    points = np.array(json.loads((out / "coverage.json").read_text())["points"])
    # the default box of a slice: Z's bounds of phi (horizontal axis) and p
    assert np.all(points[:, 1] == 0.0)
    assert sorted(set(points[:, 2])) == [-1.0, 0.0, 1.0] and sorted(set(points[:, 0])) == [-2.0, 0.0, 2.0]


def test_the_slice_plot_names_the_plane_states(problem_file, tmp_path, monkeypatch):
    figures = []
    original = coverage_region.draw_region
    monkeypatch.setattr(coverage_region, "draw_region", lambda res: figures.append(original(res)) or figures[-1])
    r = _run(problem_file, tmp_path / "out", "--plane", "phi,v", "--grid", "3")
    assert r.exit_code == 0, r.output
    (ax,) = figures[0].axes
    assert (ax.get_xlabel(), ax.get_ylabel()) == (LABELS[2], LABELS[1])
    # without a slice, n = 3 draws nothing
    r = _run(problem_file, tmp_path / "out2", "--grid", "2")
    assert r.exit_code == 0 and figures[1] is None and not (tmp_path / "out2" / "coverage.png").exists()


@pytest.mark.parametrize("adapt", [False, True])
def test_the_cost_is_counted_and_estimated_before_the_grid_runs(tmp_path, adapt, monkeypatch):
    """on_estimate is called when only the probe's QPs have been solved; the counts are one QP and one LP per
    point and parameter set."""
    from amcp_drake.offline.design import design

    spec = three_state_spec()
    d = design(spec.problem, spec.design, backend="drake")
    points, _ = coverage_region.slice_points(np.array([[-2.5, 2.5], [-1.5, 1.5]]), 5, (0, 1), np.zeros(3))
    calls = []
    original = coverage_region.qp_status
    monkeypatch.setattr(coverage_region, "qp_status", lambda *a, **k: calls.append(1) or original(*a, **k))
    seen = []
    res = coverage_region.run_coverage(spec, d, points, adapt_steps=3 if adapt else None,
                                       on_estimate=lambda e: seen.append((len(calls), e)))
    (solved_then, estimate), = seen
    assert solved_then == estimate["probe_points"] == coverage_region.PROBE_POINTS
    sets = 2 if adapt else 1
    assert (estimate["points"], estimate["qps"], estimate["lps"]) == (25, 25 * sets, 25 * sets)
    assert len(calls) == estimate["qps"] + estimate["probe_points"]  # every QP the estimate counted, plus the probe
    assert 0 < estimate["estimate_s"] < float("inf")
    assert res.to_dict()["estimate"] == estimate


@pytest.mark.parametrize("limit_args, exit_code", [
    (["--max-points", "26"], 2),      # 27 points: just above
    (["--max-points", "27"], 0),      # just at the limit
    (["--max-points", "13", "--yes"], 0),
])
def test_a_grid_above_the_limit_is_refused_before_anything_is_solved(problem_file, tmp_path, monkeypatch, limit_args,
                                                                     exit_code):
    import amcp_drake.offline.design as offline_design

    designed = []
    original = offline_design.design
    monkeypatch.setattr(offline_design, "design", lambda *a, **k: designed.append(1) or original(*a, **k))
    out = tmp_path / "out"
    r = _run(problem_file, out, "--grid", "3", *limit_args)  # 3³ = 27 points
    assert r.exit_code == exit_code, r.output
    if exit_code == 2:
        assert "--grid" in r.output and "27 points" in r.output and "27 QPs" in r.output and "Traceback" not in r.output
        assert designed == [] and not out.exists()
    else:
        assert designed == [1] and len(json.loads((out / "coverage.json").read_text())["points"]) == 27


def test_the_default_limit_refuses_a_21_point_grid_in_four_dimensions(tmp_path):
    """The cart-pole of the own-system guide: 21⁴ = 194 481 points are refused with the counts."""
    from pathlib import Path

    cartpole = Path(__file__).resolve().parents[1] / "examples" / "own-system" / "cartpole.json"
    out = tmp_path / "out"
    r = CliRunner().invoke(main, ["coverage", str(cartpole), "--grid", "21", "--out", str(out)])
    assert r.exit_code == 2, r.output
    assert "194481 points" in r.output and f"at most {coverage_region.DEFAULT_MAX_POINTS}" in r.output
    assert not out.exists()


@pytest.mark.parametrize("args, field", [
    (["--fix", "phi=0.5"], "--fix"),                                 # --fix without --plane
    (["--plane", "p,v", "--fix", "p=0.5"], "--fix"),                 # a state of the plane
    (["--plane", "p,v", "--fix", "phi=abc"], "--fix"),
    (["--plane", "p,v", "--fix", "phi=inf"], "--fix"),
    (["--plane", "p,v", "--fix", "phi"], "--fix"),
    (["--plane", "p,v", "--fix", "phi=1,phi=2"], "--fix"),
    (["--plane", "p,p"], "--plane"),
    (["--plane", "p,q"], "--plane"),
    (["--plane", "1,2,3"], "--plane"),
    (["--plane", "p,v", "--box", "-1:1"], "--box"),                 # one interval for a plane
    (["--max-points", "250001"], "--max-points"),
    (["--points", "points.json", "--plane", "p,v"], "--plane, --points"),
])
def test_bad_slice_options_exit_2_without_output(problem_file, tmp_path, args, field):
    args = [str(tmp_path / "points.json") if a == "points.json" else a for a in args]
    (tmp_path / "points.json").write_text(json.dumps({"points": [[0, 0, 0]]}))
    out = tmp_path / "out"
    r = _run(problem_file, out, "--grid", "3", *args)
    assert r.exit_code == 2, r.output
    assert field in r.output and "Traceback" not in r.output
    assert not out.exists()


def test_the_region_draws_into_a_given_axes():
    from matplotlib.figure import Figure

    from amcp_drake.studies.coverage import CoverageResult, PointVerdict, draw_region

    points = np.array([[0.0, 0.0, 0.5], [1.0, -1.0, 0.5]])
    res = CoverageResult(problem="p", n=3, points=points, source="s", axes=None, backend="drake", formulation="vertex",
                         robust=[PointVerdict("optimal", 0.5), PointVerdict("infeasible", -0.5)], labels=list(LABELS),
                         plane=(0, 1), fixed=np.array([0.0, 0.0, 0.5]))
    fig = Figure()
    left, right = fig.subplots(1, 2)
    assert draw_region(res, ax=right) is fig and not left.collections
    offsets = np.vstack([c.get_offsets() for c in right.collections])
    assert sorted(map(tuple, offsets.tolist())) == [(0.0, 0.0), (1.0, -1.0)]
    assert (right.get_xlabel(), right.get_ylabel()) == LABELS[:2]
