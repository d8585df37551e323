"""Campaign summaries and ``amcp verify`` report, per backend and per kind, the share of solver answers that
were not the backend's own (re-solved, fallback, not solved).

The counts come from real runs of Example 1: one with the honest Drake backend, one with a Drake backend whose
every plain-form answer of (20) is wrong (tests/tampered_backends.py), each stored as one campaign problem. The
expected rates are counted here by hand from the run lengths (9 tube QPs per 8-step run), not by the code.
"""

from __future__ import annotations

import pytest

from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate
from tests import tampered_backends as tb

STEPS = 8
QPS = STEPS + 1  # one tube QP per record


def _counts(spec, design):
    from amcp_drake.studies.campaign import _answer_counts

    sc = spec.scenario
    ctrl = AdaptiveMPC(spec.problem, design, backend="drake")
    traj = simulate(ctrl, sc.x0, sc.theta_star, STEPS, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)
    return _answer_counts(traj)


@pytest.fixture(scope="module")
def honest(example_spec, example_design):
    return _counts(example_spec, example_design)


def test_campaign_summary_reports_fallback_rates_per_backend_and_kind(example_spec, example_design, honest,
                                                                      monkeypatch):
    from amcp_drake.cli.campaign import answer_lines, summary_text
    from amcp_drake.studies.campaign_store import CampaignStore

    tb.use_as_drake(monkeypatch, tb.WrongTubeDrake)
    tampered = _counts(example_spec, example_design)
    store = CampaignStore.in_memory()
    for idx, cov in enumerate([honest, tampered, honest, honest]):
        store.add({"campaign_seed": 0, "idx": idx, "status": "pass", "seconds": 1.0, "claims": {},
                   "coverage": {"drake": cov}})
    lines = answer_lines(store.answer_table())
    row = next(line for line in lines if line.startswith("tube_qp fallback vertex_form"))
    # 9 of the 36 tube QPs of 4 problems were answered by the vertex form, in 1 of the 4 problems
    assert row.split()[-4:] == ["drake", str(QPS), f"{QPS / (4 * QPS):.2%}", "1/4"], row
    total = next(line for line in lines if line.startswith("tube_qp fallback "))
    assert total.split()[-4:] == ["drake", str(QPS), f"{QPS / (4 * QPS):.2%}", "1/4"], total
    assert not any(line.startswith("set_update fallback") and line.split()[-3] != "0" for line in lines), lines
    assert row in summary_text(store)


def test_amcp_verify_prints_fallback_rates_per_backend_and_kind(capsys):
    from amcp_drake.cli.verify import _print_answers

    _print_answers({"drake": {"tube_qp": {"answers": 40, "first": 30, "resolved": 2, "fallback": 8, "not_solved": 0,
                                          "resolved clarabel_refinement": 2, "fallback vertex_form": 8}},
                    "cvxpy": {"tube_qp": {"answers": 40, "first": 40, "resolved": 0, "fallback": 0, "not_solved": 0}}})
    out = capsys.readouterr().out
    assert "drake  tube_qp            40 answers: resolved 2, fallback 8 (20.00%), not solved 0" in out
    assert "fallback vertex_form 8 (20.00%)" in out and "resolved clarabel_refinement 2 (5.00%)" in out
    assert "cvxpy  tube_qp            40 answers: resolved 0, fallback 0 (0.00%), not solved 0" in out
