"""The default formulation rule (amcp_drake/online/formulation_choice.py) and the measured switch of
the DAQP fast path (amcp_drake/backends/daqp_fast.py): sizes counted by hand, the rule's boundary,
the options that need the plain form, and the switch turning the fast path off with every step
still answered (by Clarabel, the same v as the vertex form)."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.backends import daqp_fast
from amcp_drake.model.options import OnlineOptions
from amcp_drake.online import formulation_choice
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.formulation_choice import choose_formulation, formulation_sizes, resolve_formulation
from amcp_drake.online.simulate import disturbance_sequence


def test_example_1_sizes_counted_by_hand(example_spec, example_design):
    # 8 facets, Θ a box in p = 3 (8 vertices, 6 rows): vertex 8·8 = 64; the plain form keeps one vertex of
    # X0 per facet (dominated_rows' docstring: 8 of 64 rows per stage) with 6 − 3 + 1 = 4 → 32
    assert formulation_sizes(example_spec.problem, example_design) == (64, 32)
    choice = choose_formulation(example_spec.problem, example_design)
    assert choice.formulation == "vertex"
    assert "64 <= 2.5 x plain size 32" in choice.reason


def test_the_rule_at_its_boundary(example_spec, example_design, monkeypatch):
    # 64 = 2.0 x 32: vertex at ratio 2.0 (inside), plain just below it (outside)
    monkeypatch.setattr(formulation_choice, "VERTEX_SIZE_RATIO", 2.0)
    assert choose_formulation(example_spec.problem, example_design).formulation == "vertex"
    monkeypatch.setattr(formulation_choice, "VERTEX_SIZE_RATIO", 1.99)
    assert choose_formulation(example_spec.problem, example_design).formulation == "plain"


def test_many_theta_vertices_choose_plain(example_spec):
    from amcp_drake.offline.design import design

    base = example_spec.problem
    rng = np.random.default_rng(0)
    A = np.concatenate([base.A, 0.02 * rng.standard_normal((3, 2, 2))])
    B = np.concatenate([base.B, 0.02 * rng.standard_normal((3, 2, 1))])
    p6 = base.with_changes(A=A, B=B, H_theta=np.vstack([np.eye(6), -np.eye(6)]), h_theta=np.ones(12),
                           theta_hat0=np.zeros(6))
    d = design(p6, example_spec.design)
    vertex_size, plain_size = formulation_sizes(p6, d)
    assert vertex_size == len(d.H_x) * 64           # a box in 6 dimensions has 64 vertices
    assert vertex_size > 2.5 * plain_size
    assert choose_formulation(p6, d).formulation == "plain"


@pytest.mark.parametrize("options, words", [
    (OnlineOptions(cost="minmax"), "min-max cost"),
    (OnlineOptions(d_theta=0.01), "time-varying"),
    (OnlineOptions(pe_window=3), "PE constraint"),
])
def test_options_of_the_plain_form_only_choose_it(example_spec, example_design, options, words):
    choice = choose_formulation(example_spec.problem, example_design, options)
    assert choice.formulation == "plain" and words in choice.reason


def test_auto_resolves_in_the_controller(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design, formulation="auto")
    assert ctrl.backend.formulation == "vertex"
    assert ctrl.formulation_choice.formulation == "vertex"
    explicit = AdaptiveMPC(example_spec.problem, example_design, formulation="plain")
    assert explicit.backend.formulation == "plain" and explicit.formulation_choice is None
    # the fast path is dropped when the rule picks the plain form
    options, choice = resolve_formulation({"formulation": "auto", "qp_solver": "daqp"}, example_spec.problem,
                                          example_design, OnlineOptions(cost="minmax"))
    assert options == {"formulation": "plain"} and choice.formulation == "plain"


# -- the measured switch of the fast path ---------------------------------------------------------

def _path():
    A15b = np.zeros((2, 3))
    return daqp_fast.DaqpFastPath(np.arange(3), 1, slice(2, 3), np.zeros((1, 3)), np.zeros(1), A15b, 4)


def test_switch_stays_on_when_daqp_is_not_slower():
    path = _path()
    for _ in range(daqp_fast.CALIBRATION_STEPS):
        assert path.calibrating
        path.calibrate(1e-3, 1e-3)          # equal: not slower
    assert path.active and not path.calibrating and path.off_reason == ""


def test_switch_goes_off_when_daqp_is_slower():
    path = _path()
    for fast, slow in [(2e-3, 1e-3), (2e-3, 1e-3), (0.5e-3, 1e-3)]:   # median 2 ms against 1 ms
        path.calibrate(fast, slow)
    assert not path.active
    assert "DAQP 2.00 ms > Clarabel 1.00 ms" in path.off_reason


def test_size_limit_counts_dense_entries(monkeypatch):
    path = _path()
    # (2 rows of (15b) + 1 fixed row + S·4 tube rows) x 3 variables
    assert path.dense_entries(2) == (3 + 8) * 3
    monkeypatch.setattr(daqp_fast, "MAX_DENSE_ENTRIES", (3 + 8) * 3)
    assert path.model(2) is not None and path.active        # at the limit: built
    monkeypatch.setattr(daqp_fast, "MAX_DENSE_ENTRIES", (3 + 12) * 3 - 1)
    assert path.model(3) is None and not path.active        # one entry over: off, with the reason
    assert "45 entries" in path.off_reason


def test_fast_path_off_answers_every_step_by_clarabel(example_spec, example_design, monkeypatch):
    monkeypatch.setattr(daqp_fast, "MAX_DENSE_ENTRIES", 1)
    problem, sc = example_spec.problem, example_spec.scenario
    fast = AdaptiveMPC(problem, example_design, formulation="vertex", qp_solver="daqp")
    vertex = AdaptiveMPC(problem, example_design, formulation="vertex")
    w = disturbance_sequence(problem, "uniform", 5, seed=0)
    x = np.asarray(sc.x0, float)
    for k in range(5):
        u, rec = fast.step(x)
        u_ref, rec_ref = vertex.step(x)
        assert u is not None and "fast path off" in rec.qp_detail
        assert np.array_equal(u, u_ref)     # the same Clarabel program and settings
        x = problem.step(x, u, sc.theta_star, w[k])
    assert fast.mpc.fast_path_counts == {"daqp": 0, "fallback": 0}


def test_fast_path_off_names_why_and_is_empty_while_on(example_spec, example_design, monkeypatch):
    problem, sc = example_spec.problem, example_spec.scenario
    on = AdaptiveMPC(problem, example_design, formulation="vertex", qp_solver="daqp")
    on.step(np.asarray(sc.x0, float))
    assert on.mpc.fast_path_off == "" and on.mpc.fast_path_counts["daqp"] == 1
    assert AdaptiveMPC(problem, example_design, formulation="vertex").mpc.fast_path_off == ""  # no fast path
    monkeypatch.setattr(daqp_fast, "MAX_DENSE_ENTRIES", 1)
    off = AdaptiveMPC(problem, example_design, formulation="vertex", qp_solver="daqp")
    off.step(np.asarray(sc.x0, float))
    assert off.mpc.fast_path_off.startswith("dense QP of ") and "> 1 (S = 8 vertices)" in off.mpc.fast_path_off


# -- the CLI's --formulation auto ------------------------------------------------------------------------
def test_run_with_formulation_auto_prints_the_form_chosen_and_why():
    from click.testing import CliRunner

    from amcp_drake.cli import main

    result = CliRunner().invoke(main, ["run", "--formulation", "auto", "--steps", "2"], catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert "formulation auto: vertex (vertex form size 64 <= 2.5 x plain size 32 per stage)" in result.output
    pe = CliRunner().invoke(main, ["run", "--formulation", "auto", "--steps", "2", "--pe", "3"], catch_exceptions=False)
    assert pe.exit_code == 0, pe.output
    assert "formulation auto: plain (the PE constraint needs the plain form)" in pe.output


def test_certify_with_formulation_auto_records_and_certifies_the_form_it_ran(tmp_path):
    from click.testing import CliRunner

    from amcp_drake.cli import main
    from amcp_drake.online.simulate import Trajectory

    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["certify", "--formulation", "auto", "--steps", "4", "--out", str(out)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    assert "formulation auto: vertex" in result.output
    assert Trajectory.load(out / "trajectory.json.gz").meta["formulation"] == "vertex"
