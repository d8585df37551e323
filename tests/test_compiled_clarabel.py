"""The cvxpy backend's compiled route (``amcp_reference.compiled_clarabel``): Clarabel's
data evaluated from cvxpy's compiled program, a kept solver updated by the entries that changed.

Every expected value comes from cvxpy's own route: ``Problem.get_problem_data`` (cvxpy's parameter
application and solver interface) for the data, ``Problem.solve`` for the answers; and every way
the route can be wrong has a run in which it is caught (a misread program, a step it does not
answer, an exception inside it).
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np
import pytest
import scipy.sparse as sp

from amcp_drake.model.status import SolveStatus
from amcp_reference import CvxpyBackend
from amcp_reference import compiled_clarabel as cc_module
from amcp_reference.compiled_clarabel import CompiledClarabel
from amcp_reference.solver_call import clarabel_defaults


def _random_qp(rng, n: int = 4, m: int = 6):
    """A DPP QP with matrix, vector and scalar parameters in the cost and the constraints:
    min ‖F x − g‖² + c·x  s.t.  G x <= h, x_0 + t x_1 == e, x >= −10 (all parameters)."""
    F = cp.Parameter((n + 1, n), name="F")
    g = cp.Parameter(n + 1, name="g")
    c = cp.Parameter(n, name="c")
    G = cp.Parameter((m, n), name="G")
    h = cp.Parameter(m, name="h")
    t = cp.Parameter(name="t")
    e = cp.Parameter(name="e")
    x = cp.Variable(n, name="x")
    y = cp.Variable((2, 2), name="y")
    problem = cp.Problem(cp.Minimize(cp.sum_squares(F @ x - g) + c @ x + cp.sum_squares(y - 1)),
                         [G @ x <= h, x[0] + t * x[1] == e, x >= -10, y[0, :] <= x[:2]])
    params = {"F": F, "g": g, "c": c, "G": G, "h": h, "t": t, "e": e}

    def draw() -> None:
        F.value = rng.normal(size=(n + 1, n)) + 2 * np.eye(n + 1, n)
        g.value = rng.normal(size=n + 1)
        c.value = rng.normal(size=n)
        G.value = rng.normal(size=(m, n))
        h.value = rng.uniform(1, 2, size=m)     # x = 0 strictly feasible for G x <= h
        t.value = rng.normal()
        e.value = rng.normal()

    draw()
    return problem, params, draw, x, y


def _dense_data(compiled: CompiledClarabel):
    P, q, A, b = compiled._data()
    return (cc_module._csc(compiled._P_pattern, P).toarray(), q,
            cc_module._csc(compiled._A_pattern, A).toarray(), b)


def _cvxpy_data(problem):
    data, _, _ = problem.get_problem_data("CLARABEL")
    return sp.triu(data["P"]).toarray(), np.asarray(data["c"]), data["A"].toarray(), np.asarray(data["b"])


def test_the_data_equals_cvxpys_get_problem_data_on_random_parameter_values():
    rng = np.random.default_rng(3)
    problem, _, draw, _, _ = _random_qp(rng)
    compiled = CompiledClarabel(problem, clarabel_defaults())
    assert compiled.reason is None
    for _ in range(20):
        draw()
        for ours, theirs, name in zip(_dense_data(compiled), _cvxpy_data(problem), "PqAb"):
            assert ours.shape == theirs.shape, name
            assert np.max(np.abs(ours - theirs)) <= 1e-13 * max(1.0, np.max(np.abs(theirs))), name


def test_solves_with_partial_updates_agree_with_problem_solve():
    """The kept solver is updated by the changed entries of A and P (positions, values); 15 solves in
    a row, each against ``Problem.solve`` with the same parameter values."""
    rng = np.random.default_rng(4)
    problem, params, draw, x, y = _random_qp(rng)
    compiled = CompiledClarabel(problem, clarabel_defaults())
    previous = None
    for k in range(15):
        draw()
        if previous is not None and k % 3 == 0:  # only the right-hand sides and q change: no update of A, P
            for name, value in previous.items():
                params[name].value = value
        previous = {name: np.copy(params[name].value) for name in ("F", "G", "t")}
        sol = compiled.solve()
        assert str(sol.status) == "Solved"
        problem.solve(solver="CLARABEL")
        assert problem.status == "optimal"
        assert np.max(np.abs(compiled.value(x, sol.x) - x.value)) <= 1e-7
        assert np.max(np.abs(compiled.value(y, sol.x) - y.value)) <= 1e-7
        assert compiled.value(y, sol.x).shape == (2, 2)


@pytest.fixture(scope="module")
def vertex_controllers(example_spec, example_design):
    from amcp_drake.online.controller import AdaptiveMPC

    return {route: AdaptiveMPC(example_spec.problem, example_design, backend="cvxpy", formulation="vertex",
                               compiled_qp=(route == "compiled"))
            for route in ("compiled", "problem")}


def _route_tries(monkeypatch) -> list:
    """Every solve of a compiled route, counted (a spy around CompiledClarabel.solve): which route a
    step's answer finally came from is this machine's solver's business, whether the route was tried is not."""
    tries: list = []
    real = CompiledClarabel.solve

    def solve(self):
        tries.append(self)
        return real(self)

    monkeypatch.setattr(CompiledClarabel, "solve", solve)
    return tries


def test_example_1_tries_the_compiled_route_at_every_step_with_problem_solves_plan(example_spec, example_design,
                                                                                    monkeypatch):
    """40 closed-loop steps of Example 1 with each route from the same states: the compiled route is on with
    the installed cvxpy (a cvxpy whose compiled program is read differently fails here instead of silently
    going slower), it is tried at every step of the controller that has it and never by the other, and every
    step's plan is Problem.solve's."""
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence

    ctrls = {route: AdaptiveMPC(example_spec.problem, example_design, backend="cvxpy", formulation="vertex",
                                compiled_qp=(route == "compiled")) for route in ("compiled", "problem")}
    form = ctrls["compiled"].mpc._forms[ctrls["compiled"].mpc.capacity]
    assert form.compiled is not None and form.compiled.reason is None
    assert ctrls["problem"].mpc._forms[ctrls["problem"].mpc.capacity].compiled is None
    problem, sc = example_spec.problem, example_spec.scenario
    w = disturbance_sequence(problem, "uniform", 40, seed=1)
    x = np.asarray(sc.x0, float)
    tries = _route_tries(monkeypatch)
    for k in range(40):
        before = len(tries)
        u, rec = ctrls["compiled"].step(x)
        assert len(tries) > before, k
        before = len(tries)
        u_ref, rec_ref = ctrls["problem"].step(x)
        assert len(tries) == before, k
        assert rec.status is SolveStatus.OPTIMAL and rec_ref.status is SolveStatus.OPTIMAL
        assert np.max(np.abs(rec.v - rec_ref.v)) <= 1e-7, k
        assert abs(rec.cost - rec_ref.cost) <= 1e-7 * max(1.0, abs(rec_ref.cost)), k
        x = problem.step(x, u, sc.theta_star, w[k])


def test_the_kept_solver_answers_as_a_fresh_one(example_spec, example_design, monkeypatch):
    """The route keeps one Clarabel solver and updates it by the entries that changed; over 12
    closed-loop steps v equals that of a controller whose route builds a new solver at every step
    to 1e-9, and the kept controller's solver is one object throughout."""
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence

    pr, sc = example_spec.problem, example_spec.scenario
    kept, fresh = (AdaptiveMPC(pr, example_design, backend="cvxpy", formulation="vertex") for _ in range(2))
    w = disturbance_sequence(pr, "uniform", 12, seed=3)
    x = np.asarray(sc.x0, float)
    solvers = []
    tries = _route_tries(monkeypatch)
    for k in range(12):
        fresh.mpc._forms[fresh.mpc.capacity].compiled.forget_solver()
        before = len(tries)
        u, r = kept.step(x)
        assert len(tries) > before, k                # the kept controller tried its route
        before = len(tries)
        _, r_fresh = fresh.step(x)
        assert len(tries) > before, k                # and the fresh one
        assert r.status is SolveStatus.OPTIMAL and r_fresh.status is SolveStatus.OPTIMAL
        assert np.max(np.abs(r.v - r_fresh.v)) <= 1e-9, k
        solvers.append(kept.mpc._forms[kept.mpc.capacity].compiled._solver)
        x = pr.step(x, u, sc.theta_star, w[k])
    assert solvers[0] is not None and all(s is solvers[0] for s in solvers)


def _solve_once(ctrl, example_spec):
    mpc = ctrl.mpc
    p = np.shape(ctrl.data.A)[0]
    return mpc.solve(np.asarray(example_spec.scenario.x0, float), ctrl.data.h_theta0, np.zeros(p))


def _problem_solves(monkeypatch) -> list:
    """Every cvxpy ``Problem.solve`` (the route-free solve), counted by a spy."""
    calls: list = []
    real = cp.Problem.solve

    def solve(self, *args, **kwargs):
        calls.append(self)
        return real(self, *args, **kwargs)

    monkeypatch.setattr(cp.Problem, "solve", solve)
    return calls


def test_a_step_the_compiled_route_does_not_answer_is_solved_through_problem_solve(vertex_controllers, example_spec,
                                                                                   monkeypatch):
    """Tampered: the compiled route's Clarabel limited to one iteration ends "MaxIterations"; the step is then
    solved through Problem.solve (a spy counts it) and has the plan of the route-free controller."""
    ctrl = vertex_controllers["compiled"]
    reference = _solve_once(vertex_controllers["problem"], example_spec)
    form = ctrl.mpc._forms[ctrl.mpc.capacity]
    form.compiled.settings["max_iter"] = 1
    form.compiled.forget_solver()
    tries, solves = _route_tries(monkeypatch), _problem_solves(monkeypatch)
    try:
        sol = _solve_once(ctrl, example_spec)
    finally:
        form.compiled.settings["max_iter"] = clarabel_defaults()["max_iter"]
        form.compiled.forget_solver()
    assert tries and solves          # the route was tried, and Problem.solve answered
    assert sol.status is SolveStatus.OPTIMAL
    assert np.max(np.abs(sol.v - reference.v)) <= 1e-7
    again = _solve_once(ctrl, example_spec)  # the route is back once its settings are: the same plan
    assert again.status is SolveStatus.OPTIMAL and np.max(np.abs(again.v - reference.v)) <= 1e-7


def test_an_exception_inside_the_compiled_route_becomes_a_problem_solve(vertex_controllers, example_spec, monkeypatch):
    ctrl = vertex_controllers["compiled"]
    form = ctrl.mpc._forms[ctrl.mpc.capacity]

    def broken():
        raise RuntimeError("update refused")

    monkeypatch.setattr(form.compiled, "solve", broken)
    solves = _problem_solves(monkeypatch)
    sol = _solve_once(ctrl, example_spec)
    assert sol.status is SolveStatus.OPTIMAL and solves    # answered, through Problem.solve
    reference = _solve_once(vertex_controllers["problem"], example_spec)
    assert np.max(np.abs(sol.v - reference.v)) <= 1e-7


def test_a_misread_compiled_program_turns_the_route_off(example_spec, example_design, monkeypatch):
    """Tampered: the map from cvxpy's tensor product to A's entries reversed. The construction check
    against get_problem_data catches it, the route is off with the reason, and the controller is
    answered through Problem.solve."""
    from amcp_drake.online.controller import AdaptiveMPC

    real = cc_module._split_offset

    def misread(index):
        A_map, pattern, b_rows, b_map = real(index)
        return A_map[::-1].copy(), pattern, b_rows, b_map

    monkeypatch.setattr(cc_module, "_split_offset", misread)
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="cvxpy", formulation="vertex")
    form = ctrl.mpc._forms[ctrl.mpc.capacity]
    assert form.compiled.reason is not None and "A differs from cvxpy's get_problem_data" in form.compiled.reason
    tries, solves = _route_tries(monkeypatch), _problem_solves(monkeypatch)
    sol = _solve_once(ctrl, example_spec)
    assert sol.status is SolveStatus.OPTIMAL and not tries and solves   # the route never used, Problem.solve answered


def test_a_variable_replaced_in_the_compiled_program_is_named():
    """cvxpy replaces a variable with attributes (nonneg=True) by a new one in its compiled program:
    reading it is an error that says so, never a slice of another variable."""
    a = cp.Variable(2, nonneg=True, name="a")
    problem = cp.Problem(cp.Minimize(cp.sum_squares(a - cp.Parameter(2, value=np.ones(2)))))
    compiled = CompiledClarabel(problem, clarabel_defaults())
    sol = compiled.solve()
    with pytest.raises(KeyError, match="'a' is not in cvxpy's compiled program"):
        compiled.value(a, sol.x)
    asked = CompiledClarabel(problem, clarabel_defaults(), read=(a,))  # asked for at construction: the route is off
    assert asked.reason is not None and "['a'] are not in cvxpy's compiled program" in asked.reason


def test_the_route_is_on_by_default_off_on_request_and_off_for_other_solvers(example_spec, example_design):
    from amcp_drake.online.controller import AdaptiveMPC

    assert CvxpyBackend(formulation="vertex").compiled_qp is True
    assert CvxpyBackend(formulation="vertex", compiled_qp=False).compiled_qp is False
    other = AdaptiveMPC(example_spec.problem, example_design, backend="cvxpy", formulation="vertex", solver="SCS")
    assert other.mpc.compiled is False
    assert all(form.compiled is None for form in other.mpc._forms.values())


@pytest.mark.parametrize("seed", range(6))
def test_random_problems_get_problem_solves_answers_by_the_compiled_route(seed, monkeypatch):
    """Generated problems (the campaign's generator: n <= 3, p <= 3, θ* on a facet or vertex, pinned
    Θ_k): 8 closed-loop steps of the cvxpy vertex form with each route from the same states. Statuses
    are equal, v agrees to 1e-6 (the brief's cross-backend tolerance), and the compiled route was tried
    at every step of the controller that has it."""
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.studies.random_problems import random_case

    case = random_case(np.random.default_rng(900 + seed), steps=8)
    problem = case.spec.problem
    options = OnlineOptions(update=case.options.update, projection=case.options.projection)
    ctrls = {route: AdaptiveMPC(problem, case.design, backend="cvxpy", formulation="vertex", options=options,
                                compiled_qp=(route == "compiled")) for route in ("compiled", "problem")}
    x = np.asarray(case.x0, float)
    tries = _route_tries(monkeypatch)
    for k in range(8):
        before = len(tries)
        u, rec = ctrls["compiled"].step(x)
        assert len(tries) > before, (k, case.labels)
        before = len(tries)
        _, rec_ref = ctrls["problem"].step(x)
        assert len(tries) == before, k
        assert rec.status is rec_ref.status, (k, rec.qp_detail, rec_ref.qp_detail)
        if u is None:
            break
        assert np.max(np.abs(rec.v - rec_ref.v)) <= 1e-6, k
        x = problem.step(x, u, case.theta_star, case.w[k])


def test_a_misread_map_hidden_by_zero_parameter_values_is_caught_at_random_values(monkeypatch):
    """Tampered: b's map reversed on a problem whose b is the parameter p, set to 0 when the route is
    built; at p = 0 both readings agree, the check at random parameter values does not. The values
    set by the caller are restored afterwards."""
    real = cc_module._split_offset

    def misread(index):
        A_map, pattern, b_rows, b_map = real(index)
        return A_map, pattern, b_rows, b_map[::-1].copy()

    monkeypatch.setattr(cc_module, "_split_offset", misread)
    x = cp.Variable(3, name="x")
    p = cp.Parameter(3, name="p", value=np.zeros(3))
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x) - 10 * cp.sum(x)), [x <= p])  # b = p, nothing else
    compiled = CompiledClarabel(problem, clarabel_defaults())
    assert compiled.reason is not None and "b differs from cvxpy's get_problem_data" in compiled.reason
    np.testing.assert_array_equal(p.value, np.zeros(3))
    monkeypatch.setattr(cc_module, "_split_offset", real)
    assert CompiledClarabel(problem, clarabel_defaults()).reason is None  # the same problem read right
