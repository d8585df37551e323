"""Steps that needed more than the first solve (amcp_drake.studies.resolves): the controller records
the typed attempts of the step, and the bench and the campaign count the kinds in them."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from amcp_drake.backends.base import Attempt
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answers
from amcp_drake.online.controller import AdaptiveMPC, StepRecord
from amcp_drake.studies.resolves import count_resolves, step_kinds


def _outside_theta0_step(example_spec, example_design, backend):
    """One step of the plain form with Θ_k = 1.2·Θ0 (not inside Θ0: the Drake backend's reduced
    program does not apply and it solves the program with every row)."""
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend=backend, formulation="plain",
                       options=OnlineOptions(update="none"))
    ctrl.state = ctrl.state.replace(h_theta=1.2 * np.asarray(example_design.h_theta0, float))
    u, record = ctrl.step(np.array([1.0, 0.5]))
    assert u is not None, record.status
    return record


def test_the_step_records_its_qp_answers_detail_and_the_every_row_program_is_counted(example_spec, example_design):
    record = _outside_theta0_step(example_spec, example_design, "drake")
    assert count_resolves([step_kinds(record)])["every_row"] == 1   # Θ_k ⊄ Θ0: the reduced program cannot apply


def test_a_step_inside_theta0_counts_nowhere(example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="plain")
    u, record = ctrl.step(np.asarray(example_spec.scenario.x0, float))
    assert u is not None, record.status
    assert set(count_resolves([step_kinds(record)]).values()) == {0}


def test_the_campaign_counts_extra_solves_only_where_they_can_occur():
    from amcp_drake.studies.campaign import _resolve_counts

    def step(k, inner=(), fallback=False):
        first = Attempt("tube_qp", "first", SolveStatus.OPTIMAL, accepted=not fallback,
                        inner=tuple(Attempt("tube_qp", r, SolveStatus.OPTIMAL) for r in inner))
        attempts = [first] + ([Attempt("tube_qp", "other_formulation", SolveStatus.OPTIMAL, accepted=True)]
                              if fallback else [])
        entry = answers.entry("tube_qp", "fallback", "vertex_form", "tube (15c)") if fallback else \
            answers.entry("tube_qp", "first")
        return StepRecord(k=k, x=np.zeros(1), u=None, status=SolveStatus.OPTIMAL, H_theta=np.eye(1),
                          h_theta=np.ones(1), theta_hat=np.zeros(1), answers=[entry], attempts=attempts)

    run = SimpleNamespace(records=[step(0, ["every_row"]), step(1), step(2, fallback=True), step(3, ["every_row"])])
    drake = _resolve_counts(run, "drake")
    assert drake == {"resolve_clarabel_retry": 0.0, "resolve_refined_resolve": 0.0, "resolve_every_row": 2.0,
                     "resolve_answer_check_fallback": 1.0}
    # the cvxpy plain form always has every row: the key is not reported rather than reported as 0; its
    # optimality re-solve is reported for it alone
    assert _resolve_counts(run, "cvxpy") == {**{k: v for k, v in drake.items() if k != "resolve_every_row"},
                                             "resolve_optimality_resolve": 0.0}
