"""The answer policy as data (amcp_drake.online.policy): the rungs of a problem run in order until an
answer passes its checks, every solve is a typed Attempt, and the step's provenance entry is rendered
from the attempts."""

from __future__ import annotations

from amcp_drake.backends.base import Attempt
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answers, policy
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate
from tests import tampered_backends as tb

OPT, INF, INACC, NOT_RUN = SolveStatus.OPTIMAL, SolveStatus.INFEASIBLE, SolveStatus.INACCURATE, SolveStatus.NOT_RUN


def _scripted(problem, outcomes):
    """An ``attempt`` function for policy.run answering rung -> (status, failed check or "") from
    ``outcomes``; a rung missing from it does not apply. Returns (function, rungs called)."""
    called = []

    def attempt(rung):
        if rung.name not in outcomes:
            return None
        called.append(rung.name)
        status, check = outcomes[rung.name]
        opts = (("formulation", "vertex"),) if rung.name == "other_formulation" else ()
        return rung.name, Attempt(problem, rung.name, status, check=check, options=opts,
                                  accepted=status is OPT and not check)
    return attempt, called


def test_the_first_answer_that_passes_is_used_and_nothing_after_it_runs():
    fn, called = _scripted("tube_qp", {"first": (OPT, ""), "refine": (OPT, ""), "other_formulation": (OPT, "")})
    answer, attempts = policy.run(policy.TUBE_QP, fn)
    assert (answer, called) == ("first", ["first"])
    assert policy.answer_entry(policy.TUBE_QP, attempts) == answers.entry("tube_qp", "first")


def test_a_failed_check_is_re_solved_then_falls_back_to_the_other_formulation():
    fn, called = _scripted("tube_qp", {"first": (OPT, "tube (15c)"), "refine": (OPT, "tube (15c)"),
                                       "other_formulation": (OPT, "")})
    answer, attempts = policy.run(policy.TUBE_QP, fn)
    assert (answer, called) == ("other_formulation", ["first", "refine", "other_formulation"])
    assert [a.accepted for a in attempts] == [False, False, True]
    assert policy.answer_entry(policy.TUBE_QP, attempts) == answers.entry("tube_qp", "fallback", "vertex_form",
                                                                          "tube (15c)")


def test_a_re_solve_that_passes_is_the_backends_own_answer():
    fn, _ = _scripted("tube_qp", {"first": (OPT, "tube (15c)"), "refine": (OPT, ""), "other_formulation": (OPT, "")})
    answer, attempts = policy.run(policy.TUBE_QP, fn)
    assert answer == "refine"
    assert policy.answer_entry(policy.TUBE_QP, attempts) == answers.entry("tube_qp", "resolved",
                                                                          "iterative_refinement", "tube (15c)")


def test_no_answer_skips_the_re_solve_and_infeasible_is_an_answer_without_fallback():
    fn, called = _scripted("tube_qp", {"first": (INACC, ""), "refine": (OPT, ""), "other_formulation": (OPT, "")})
    answer, attempts = policy.run(policy.TUBE_QP, fn)
    assert called == ["first", "other_formulation"]
    assert policy.answer_entry(policy.TUBE_QP, attempts)["check"] == f"status {INACC.value}"
    fn, called = _scripted("tube_qp", {"first": (INF, ""), "refine": (OPT, ""), "other_formulation": (OPT, "")})
    answer, attempts = policy.run(policy.TUBE_QP, fn)
    assert (answer, called) == (None, ["first"])
    assert policy.answer_entry(policy.TUBE_QP, attempts) == answers.entry("tube_qp", "not_solved", "infeasible")


def test_an_other_formulation_that_cannot_run_leaves_the_step_unsolved_without_a_kind():
    fn, _ = _scripted("tube_qp", {"first": (OPT, "tube (15c)"), "refine": (OPT, "tube (15c)"),
                                  "other_formulation": (NOT_RUN, "no other formulation")})
    answer, attempts = policy.run(policy.TUBE_QP, fn)
    assert answer is None
    assert policy.answer_entry(policy.TUBE_QP, attempts) == answers.entry("tube_qp", "not_solved", "", "tube (15c)")
    assert policy.notes(policy.TUBE_QP, attempts).endswith("no other formulation: step not solved")


def test_the_set_update_keeps_the_previous_set_when_both_solvers_fail():
    fn, called = _scripted("set_update", {"first": (INACC, ""), "highs_support_lps": (OPT, "nested"),
                                          "kept_previous_set": (OPT, "")})
    answer, attempts = policy.run(policy.SET_UPDATE, fn)
    assert called == ["first", "highs_support_lps", "kept_previous_set"]
    assert policy.answer_entry(policy.SET_UPDATE, attempts) == answers.entry("set_update", "fallback",
                                                                             "kept_previous_set", f"status {INACC.value}")


def test_the_step_records_its_attempts_and_renders_its_provenance_from_them(example_spec, example_design,
                                                                           monkeypatch):
    tb.use_as_drake(monkeypatch, tb.WrongTubeDrake)
    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake")
    traj = simulate(ctrl, sc.x0, sc.theta_star, 2, "uniform", seed=0, mu_state_bound=example_spec.design.mu_state_bound)
    for record in traj.records:
        assert record.u is not None
        tube = [a for a in record.attempts if a.problem == "tube_qp"]
        # the shifted plain answer fails a check of (15) on every plain rung; the vertex form answers
        assert tube[0].rung == "first" and not tube[0].accepted and tube[0].check.startswith("tube ")
        assert tube[-1].rung == "other_formulation" and tube[-1].accepted
        assert tube[-1].option("formulation") == "vertex"
        assert answers.of(record, "tube_qp") == policy.answer_entry(policy.TUBE_QP, tube)
    sets = [a for a in traj.records[1].attempts if a.problem == "set_update"]
    assert [a.rung for a in sets] == ["first"] and sets[0].accepted
    assert answers.of(traj.records[1], "set_update") == answers.entry("set_update", "first")


def test_a_projection_without_a_certified_point_is_not_solved_without_a_kind():
    fn, called = _scripted("projection", {"first": (OPT, "projection in S"), "least_distance": (OPT, "projection in S"),
                                          "kept_previous_estimate": (NOT_RUN, ""), "chebyshev_centre": (INF, "")})
    answer, attempts = policy.run(policy.PROJECTION, fn)
    assert answer is None and called == ["first", "least_distance", "kept_previous_estimate", "chebyshev_centre"]
    assert policy.answer_entry(policy.PROJECTION, attempts) == answers.entry("projection", "not_solved", "",
                                                                             "projection in S")
    assert policy.notes(policy.PROJECTION, attempts, target="Θ_k").endswith("no certified point of Θ_k: step not solved")
