"""The Clarabel retry ladder of the tube QP (amcp_drake/backends/clarabel_retry.py): an
"inaccurate" first solve (made without iterative refinement) is solved again with the
backend's own settings, then with the ladder's settings in order; only a clean "optimal" is
accepted, the rung is named in the detail, and when every rung fails the status stays "inaccurate"
(never promoted to "optimal"). The failures are made by fakes (the first k solves report "inaccurate");
after them this machine's Clarabel may need further rungs, so the tests assert the order of the tries, the
answer (equal to an unforced solve) and that the detail names the rung that was actually the last try,
never which rung a real solve needs."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.backends.clarabel_retry import CLARABEL_RETRY_LADDER, MINMAX_TIGHT, NO_REFINEMENT
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.status import SolveStatus
from amcp_drake.online.controller import AdaptiveMPC

X = np.array([2.0, 3.0])


@pytest.fixture(scope="module")
def drake_mpc(example_spec, example_design):
    return AdaptiveMPC(example_spec.problem, example_design, backend="drake").mpc


@pytest.fixture(scope="module")
def cvxpy_mpc(example_spec, example_design):
    return AdaptiveMPC(example_spec.problem, example_design, backend="cvxpy").mpc


def _args(mpc):
    """x_k = [2, 3], Θ_k = Θ (its offsets), θ̂ = 0."""
    H = np.asarray(mpc.data.H_theta, float)
    return X, np.ones(H.shape[0]), np.zeros(H.shape[1])


def _drake_with_failures(monkeypatch, mpc, failures: int) -> list:
    """The first ``failures`` solves report INACCURATE; records the extra options of every solve."""
    solver = mpc._solver
    calls: list = []
    real_solve, real_status = solver.solve, solver.status

    def solve(prog, extra_options=None):
        calls.append(extra_options)
        return real_solve(prog, extra_options)

    def status(result):
        return SolveStatus.INACCURATE if len(calls) <= failures else real_status(result)

    monkeypatch.setattr(solver, "solve", solve)
    monkeypatch.setattr(solver, "status", status)
    return calls


def _rung(calls: list) -> int:
    """The ladder rung of the last try (calls: the first try, the backend's own options, then the ladder)."""
    return len(calls) - 2


def test_drake_retries_in_order_and_names_the_rung(monkeypatch, drake_mpc):
    reference = drake_mpc.solve(*_args(drake_mpc))
    assert reference.status is SolveStatus.OPTIMAL
    calls = _drake_with_failures(monkeypatch, drake_mpc, failures=3)
    sol = drake_mpc.solve(*_args(drake_mpc))
    assert calls == [NO_REFINEMENT, None, *CLARABEL_RETRY_LADDER][:len(calls)] and len(calls) >= 4
    assert sol.status is SolveStatus.OPTIMAL and f"retry {_rung(calls)}" in sol.detail
    assert "re-solved with iterative refinement" in sol.detail
    np.testing.assert_allclose(sol.v, reference.v, atol=1e-6)


def test_minmax_tries_tight_tolerances_first_then_the_defaults_then_the_ladder(monkeypatch, example_spec, example_design):
    """Min–max cost (19): the first try is at MINMAX_TIGHT (1e-10), a failed one is solved again with
    the backend's own options (named in the detail), then the ladder; never without refinement."""
    mpc = AdaptiveMPC(example_spec.problem, example_design, backend="drake", options=OnlineOptions(cost="minmax")).mpc
    reference = mpc.solve(*_args(mpc))
    assert reference.status is SolveStatus.OPTIMAL
    calls = _drake_with_failures(monkeypatch, mpc, failures=2)
    sol = mpc.solve(*_args(mpc))
    assert calls == [MINMAX_TIGHT, None, *CLARABEL_RETRY_LADDER][:len(calls)] and len(calls) >= 3
    assert sol.status is SolveStatus.OPTIMAL and "re-solved at the default tolerances" in sol.detail
    assert f"retry {_rung(calls)}" in sol.detail and "iterative refinement" not in sol.detail
    np.testing.assert_allclose(sol.v, reference.v, atol=1e-5)


def test_drake_never_promotes_an_inaccurate_answer(monkeypatch, drake_mpc):
    calls = _drake_with_failures(monkeypatch, drake_mpc, failures=100)
    sol = drake_mpc.solve(*_args(drake_mpc))
    assert calls == [NO_REFINEMENT, None, *CLARABEL_RETRY_LADDER]
    assert sol.status is SolveStatus.INACCURATE and sol.v is None
    assert f"after {len(CLARABEL_RETRY_LADDER)} Clarabel retries" in sol.detail


def test_cvxpy_retries_in_order_and_never_promotes(monkeypatch, cvxpy_mpc):
    from amcp_reference import backend as ref_backend

    real = ref_backend.SolverCall.solve
    calls: list = []
    failures = {"n": 2}

    def solve(self, problem, extra_options=None):
        calls.append({**self.options, **(extra_options or {})})
        status, t, detail = real(self, problem, extra_options)
        if len(calls) <= failures["n"]:
            return SolveStatus.INACCURATE, t, "optimal_inaccurate"
        return status, t, detail

    monkeypatch.setattr(ref_backend.SolverCall, "solve", solve)
    sol = cvxpy_mpc.solve(*_args(cvxpy_mpc))
    base = dict(cvxpy_mpc._call.options)
    ladder = [{**base, **NO_REFINEMENT}, base] + [{**base, **rung} for rung in CLARABEL_RETRY_LADDER]
    assert calls == ladder[:len(calls)] and len(calls) >= 3
    assert sol.status is SolveStatus.OPTIMAL and f"retry {_rung(calls)}" in sol.detail
    assert "re-solved with iterative refinement" in sol.detail
    calls.clear()
    failures["n"] = 100
    sol = cvxpy_mpc.solve(*_args(cvxpy_mpc))
    # every rung once, in order, never a promoted rung; at most one more try after the ladder (the plain
    # form's tie-broken solve, verified before use) and nothing accepted from a failing solver
    assert calls[:len(ladder)] == ladder and len(calls) <= len(ladder) + 1
    assert sol.status is SolveStatus.INACCURATE and sol.v is None and "Clarabel retries" in sol.detail


def test_a_minmax_step_that_stalled_under_every_earlier_rung_is_solved():
    """A generated case (min-max cost (19), n = 3, N = 3, x_0 on the boundary): step 1
    ended AlmostSolved in Drake after the five earlier rungs on the machine where it was recorded; whichever
    try answers it here, the step is answered and checked like any answer, and the run completes."""
    from pathlib import Path

    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.replay import run_scenario

    spec = load_spec(Path(__file__).parent / "data" / "minmax-stall-problem.json")
    assert spec.online.cost == "minmax"
    from amcp_drake.online import answers

    traj = run_scenario(spec, "drake", steps=2)
    assert all(answers.qp_applied(r) for r in traj.records)   # answered and checked (min-max has no fallback)
    assert traj.stop_reason == "completed"


def test_a_drake_vertex_step_that_stalled_at_1e_10_is_answered_by_the_retry_ladder():
    """A recorded hard step (tests/data/lockstep-vertex-ladder: n = 2, p = 2, θ* at a vertex, Θ_k
    pinned to a point, window update): at step 4 the Drake vertex form at 1e-10 can end AlmostSolved
    with and without iterative refinement. The vertex form must answer the step itself (optimal,
    checked) with the v of the plain form and of cvxpy's vertex form. Which rung of the retry ladder
    answers depends on the processor's round-off and is deliberately not asserted."""
    from pathlib import Path

    from amcp_drake.comparison.compare import ACCURATE_CLARABEL
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import Trajectory

    folder = Path(__file__).parent / "data" / "lockstep-vertex-ladder"
    spec, traj = load_spec(folder / "problem.json"), Trajectory.load(folder / "trajectory.json.gz")
    step = traj.records[4]
    assert step.status is SolveStatus.INACCURATE and "fallback: plain form" in step.detail  # as recorded
    x = np.asarray(traj.x[4], float)
    answers = {}
    for backend, formulation in (("drake", "vertex"), ("drake", "plain"), ("cvxpy", "vertex")):
        ctrl = AdaptiveMPC(spec.problem, traj.design, backend=backend, formulation=formulation, options=traj.options,
                           solver_options=ACCURATE_CLARABEL)
        answers[backend, formulation] = ctrl.mpc.solve(x, step.h_theta, step.theta_hat, step.H_theta)
    drake_vertex = answers["drake", "vertex"]
    assert drake_vertex.status is SolveStatus.OPTIMAL, drake_vertex.detail   # the vertex form's own answer
    for other in (answers["drake", "plain"], answers["cvxpy", "vertex"]):
        assert other.status is SolveStatus.OPTIMAL
        np.testing.assert_allclose(drake_vertex.v, other.v, rtol=0, atol=1e-8)
