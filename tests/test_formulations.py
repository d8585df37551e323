"""The vertex form of the tube MPC QP (20) against the plain form (15) with Λ.

Both describe the same feasible set in (z, α, v) (proof of Proposition 9; argument in
``amcp_drake.backends.vertex_form``), so v* (unique: the cost is strictly convex in v) and the
optimal cost must agree. Every comparison solves both forms at identical data (x_k, Θ_k, θ̂_k),
on random problems: Example 1 with random θ*, x0, seeds and Θ_k shrunk by the data of a run,
random sub-boxes and random extra cuts of Θ (general polytopes, shape change), flat Θ_k, and
random small systems built with ``Problem`` + ``design``; both backends.

Clarabel runs at tolerances 1e-10 here: at its defaults (1e-8 on the gap) v itself is only
determined to ~1e-4 on flat optima (measured at x0 = [2, 3] of Example 1 for the plain form of
either backend), which is the solver's accuracy, not the formulation's.
"""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.backends import TubeMPCData, get_backend
from amcp_drake.backends.vertex_form import VertexEnumerationError, theta_vertices
from amcp_drake.model import polytope
from amcp_drake.model.problem import DesignOptions, Problem
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate

from .conftest import scalar_problem

#: Agreement required by the issue (v and cost).
AGREE_TOL = 1e-6
#: Clarabel options for the comparisons (both forms, both backends).
TIGHT = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
BACKENDS = ["drake", "cvxpy"]


def tube_data(problem: Problem, d) -> TubeMPCData:
    return TubeMPCData(A0=problem.A0, B0=problem.B0, A=problem.A, B=problem.B, F=problem.F, G=problem.G, Q=problem.Q,
                       R=problem.R, N=problem.N, K=d.K, P=d.P, H_x=d.H_x, X0_vertices=d.X0_vertices, w_bar=d.w_bar,
                       f_bar=d.f_bar, H_T=d.H_T, h_T=d.h_T, H_theta=d.H_theta, h_theta0=d.h_theta0)


def solvers(data: TubeMPCData, backend: str):
    plain = get_backend(backend, solver_options=TIGHT).tube_mpc(data)
    vertex = get_backend(backend, solver_options=TIGHT, formulation="vertex").tube_mpc(data)
    return plain, vertex


def assert_same_optimum(plain_sol, vertex_sol, where: str) -> bool:
    """Same status; when optimal, same v and cost within AGREE_TOL. Returns True if optimal."""
    assert vertex_sol.status is plain_sol.status, f"{where}: status {vertex_sol.status} vs plain {plain_sol.status}"
    if plain_sol.status is not SolveStatus.OPTIMAL:
        return False
    dv = float(np.max(np.abs(vertex_sol.v - plain_sol.v)))
    dc = abs(vertex_sol.cost - plain_sol.cost)
    assert dv <= AGREE_TOL, f"{where}: max |v_vertex - v_plain| = {dv:.2e}"
    assert dc <= AGREE_TOL * max(1.0, abs(plain_sol.cost)), f"{where}: |cost difference| = {dc:.2e}"
    assert vertex_sol.Lambda is None and plain_sol.Lambda is not None
    return True


def random_sub_box(rng, H: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Offsets h for rows H of a random box inside [lo, hi] (its support in the directions H)."""
    centre = rng.uniform(lo, hi)
    radius = rng.uniform(0.02, 1.0, size=len(lo)) * (hi - lo) / 2
    a, b = np.maximum(lo, centre - radius), np.minimum(hi, centre + radius)
    corners = np.array(np.meshgrid(*zip(a, b), indexing="ij")).reshape(len(lo), -1).T
    return np.max(corners @ H.T, axis=0)


def boundary_state(solver, h, theta_hat, direction, H=None, fraction=0.97, steps=18, limit=8.0,
                   with_flag: bool = False):
    """fraction·s·direction with s the largest feasible scaling along ``direction`` up to ``limit``
    (bisection on ``solver``): near the boundary of the feasible set the robust tube rows are
    active, so the comparison sees them (well inside, v* is often set by the input bounds and the
    cost alone). The limit keeps x in the region the examples live in: at |x| ~ 100 (Example 1's
    Z is unbounded in x1) v* is of order 10 and Clarabel's 1e-10 tolerances give ~1e-5 in v.
    ``with_flag``: also return whether a boundary was found below the limit."""
    if solver.solve(limit * direction, h, theta_hat, H).status is SolveStatus.OPTIMAL:
        x = fraction * limit * direction
        return (x, False) if with_flag else x
    lo, hi = 0.0, limit
    for _ in range(steps):
        mid = 0.5 * (lo + hi)
        if solver.solve(mid * direction, h, theta_hat, H).status is SolveStatus.OPTIMAL:
            lo = mid
        else:
            hi = mid
    x = fraction * lo * direction
    return (x, True) if with_flag else x


def robustness_matters(solver, x, h, theta_hat, reference, H=None) -> bool:
    """True when shrinking Θ_k to the point θ̂ changes v* by more than 1e-4: the case exercises the
    tube rows (5b)/(15c)-(15d). Keeps the comparisons honest (a test whose cases never touch the
    tube constraints would pass for any formulation of them)."""
    if reference.status is not SolveStatus.OPTIMAL:
        return False
    H = solver.data.H_theta if H is None else H
    point = solver.solve(x, H @ theta_hat, theta_hat, H)
    return point.status is SolveStatus.OPTIMAL and float(np.max(np.abs(point.v - reference.v))) > 1e-4


# -- vertex enumeration -------------------------------------------------------------------------

@pytest.mark.parametrize("seed", range(6))
def test_basis_enumeration_finds_the_same_vertices_as_qhull(seed):
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 5))
    directions = rng.normal(size=(int(rng.integers(p + 3, 14)), p))
    H = np.vstack([np.eye(p), -np.eye(p), directions / np.linalg.norm(directions, axis=1, keepdims=True)])
    h = np.concatenate([np.ones(2 * p), rng.uniform(0.3, 1.5, len(directions))])
    mine = theta_vertices(H, h)
    qhull = polytope.vertices(H, h)
    dist = np.linalg.norm(mine[:, None, :] - qhull[None, :, :], axis=2)
    assert len(mine) == len(qhull)
    assert max(dist.min(axis=0).max(), dist.min(axis=1).max()) < 1e-9


def test_basis_enumeration_handles_flat_boxes_and_points():
    H = np.vstack([np.eye(3), -np.eye(3)])
    flat = theta_vertices(H, np.array([0.5, 0.2, 1.0, -0.5, 0.2, 1.0]))       # θ1 = 0.5 exactly
    assert len(flat) == 4 and np.allclose(flat[:, 0], 0.5)
    point = theta_vertices(H, np.array([0.5, 0.2, -0.1, -0.5, -0.2, 0.1]))
    np.testing.assert_allclose(point, [[0.5, 0.2, -0.1]], atol=1e-12)


def test_basis_enumeration_reports_an_empty_set():
    with pytest.raises(VertexEnumerationError, match="empty"):
        theta_vertices(np.array([[1.0], [-1.0]]), np.array([-1.0, 0.0]))   # θ <= -1 and θ >= 0


# -- construction ------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
def test_unknown_formulation_is_rejected(backend):
    with pytest.raises(ValueError, match="formulation"):
        get_backend(backend, formulation="dual")


@pytest.mark.parametrize("backend", BACKENDS)
def test_adaptive_mpc_passes_the_formulation_to_the_backend(backend, example_spec, example_design):
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend=backend, formulation="vertex")
    assert ctrl.backend.formulation == "vertex"
    _, rec = ctrl.step(np.asarray(example_spec.scenario.x0, float))
    assert rec.status is SolveStatus.OPTIMAL and rec.Lambda is None and rec.v is not None


# -- Example 1: Θ_k shrunk by the data of random runs ---------------------------------------------

@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed", [1, 2])
def test_same_optimum_along_random_runs_of_example_1(backend, seed, example_spec, example_design):
    rng = np.random.default_rng(100 + seed)
    pr = example_spec.problem
    theta_star = rng.uniform(-0.9, 0.9, pr.p)
    x0 = np.array([rng.uniform(-2.5, 2.5), rng.uniform(0.0, 3.0)])
    ctrl = AdaptiveMPC(pr, example_design, backend="drake", solver_options=TIGHT)
    traj = simulate(ctrl, x0, theta_star, 12, "vertices" if seed % 2 else "uniform", seed=seed)
    plain, vertex = solvers(tube_data(pr, example_design), backend)
    solved = 0
    for r in traj.records:
        solved += assert_same_optimum(plain.solve(r.x, r.h_theta, r.theta_hat),
                                      vertex.solve(r.x, r.h_theta, r.theta_hat), f"k={r.k}")
    assert solved >= 10


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_optimum_on_random_sub_boxes_states_and_estimates(backend, example_spec, example_design):
    rng = np.random.default_rng(7)
    pr, d = example_spec.problem, example_design
    plain, vertex = solvers(tube_data(pr, d), backend)
    lo, hi = -np.ones(pr.p), np.ones(pr.p)
    solved = robust = 0
    for i in range(8):
        h = random_sub_box(rng, d.H_theta, lo, hi)
        theta_hat = rng.uniform(-1, 1, pr.p)
        if i % 2:
            x = np.array([rng.uniform(-3, 3), rng.uniform(-0.25, 3)])
        else:
            angle = rng.uniform(-0.4, 0.6) + (0 if i % 4 else np.pi)
            x = boundary_state(vertex, h, theta_hat, np.array([np.cos(angle), np.sin(angle)]))
        reference = plain.solve(x, h, theta_hat)
        solved += assert_same_optimum(reference, vertex.solve(x, h, theta_hat), f"case {i}")
        robust += robustness_matters(vertex, x, h, theta_hat, reference)
    assert solved >= 6 and robust >= 2


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_optimum_on_general_polytopes_of_changing_shape(backend, example_spec, example_design):
    """Θ_k = sub-box cut by random half-spaces through it (as the exact update (7) produces):
    the plain form rebuilds for the new row count, the vertex form only enumerates vertices."""
    rng = np.random.default_rng(11)
    pr, d = example_spec.problem, example_design
    plain, vertex = solvers(tube_data(pr, d), backend)
    for i in range(4):
        h_box = random_sub_box(rng, d.H_theta, -np.ones(pr.p), np.ones(pr.p))
        centre = theta_vertices(d.H_theta, h_box).mean(axis=0)
        cuts = rng.normal(size=(int(rng.integers(1, 4)), pr.p))
        cuts /= np.linalg.norm(cuts, axis=1, keepdims=True)
        H = np.vstack([d.H_theta, cuts])
        h = np.concatenate([h_box, cuts @ centre + rng.uniform(0.01, 0.3, len(cuts))])
        theta_hat = centre
        angle = rng.uniform(-0.4, 0.6) + (np.pi if i % 2 else 0.0)
        x = boundary_state(vertex, h, theta_hat, np.array([np.cos(angle), np.sin(angle)]), H=H)
        assert assert_same_optimum(plain.solve(x, h, theta_hat, H), vertex.solve(x, h, theta_hat, H), f"case {i}")


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_optimum_on_a_flat_parameter_set(backend, example_spec, example_design):
    """θ3 pinned (Θ_k with empty interior): Qhull could not enumerate it, bases can."""
    pr, d = example_spec.problem, example_design
    plain, vertex = solvers(tube_data(pr, d), backend)
    centre = np.array([0.6, 0.1, -0.5])
    corners = np.array(np.meshgrid([0.5, 0.7], [0.0, 0.3], [-0.5, -0.5], indexing="ij")).reshape(3, -1).T
    h = np.max(corners @ d.H_theta.T, axis=0)
    sol = vertex.solve(np.array([1.0, 1.0]), h, centre)
    assert "4 vertices" in sol.detail
    assert assert_same_optimum(plain.solve(np.array([1.0, 1.0]), h, centre), sol, "flat")


@pytest.mark.parametrize("backend", BACKENDS)
def test_both_forms_report_an_infeasible_state(backend, example_spec, example_design):
    pr, d = example_spec.problem, example_design
    plain, vertex = solvers(tube_data(pr, d), backend)
    h = np.max(d.theta_vertices @ d.H_theta.T, axis=0)
    x = np.array([0.0, -5.0])                      # far below x2 >= -0.3
    p_sol, v_sol = plain.solve(x, h, np.zeros(pr.p)), vertex.solve(x, h, np.zeros(pr.p))
    assert p_sol.status is SolveStatus.INFEASIBLE and v_sol.status is SolveStatus.INFEASIBLE
    assert v_sol.v is None and v_sol.Lambda is None
    assert v_sol.infeasible_constraints  # named, as in the plain form
    if backend == "cvxpy":  # the elastic diagnosis blames the same group in both forms
        assert v_sol.infeasible_constraints == p_sol.infeasible_constraints


# -- random small systems built with Problem + design ---------------------------------------------

def random_system(seed: int, n: int, p: int, N: int) -> tuple[Problem, object]:
    """A random stable-ish n-state, 1-input system with p parameters whose design succeeds
    (the first of a deterministic sequence of draws)."""
    rng = np.random.default_rng(seed)
    for _ in range(30):
        A0 = rng.uniform(-0.6, 0.6, (n, n))
        A0 *= 0.8 / max(0.8, float(np.max(np.abs(np.linalg.eigvals(A0)))))
        B0 = rng.uniform(-1, 1, (n, 1)) + np.eye(n, 1)
        A = 0.04 * rng.normal(size=(p, n, n))
        B = 0.03 * rng.normal(size=(p, n, 1))
        problem = Problem(A0=A0, B0=B0, A=A, B=B, H_w=np.vstack([np.eye(n), -np.eye(n)]) / 0.05,
                          H_theta=np.vstack([np.eye(p), -np.eye(p)]), h_theta=np.ones(2 * p),
                          F=np.vstack([np.eye(n) / 4, -np.eye(n) / 4, np.zeros((2, n))]),
                          G=np.vstack([np.zeros((2 * n, 1)), [[0.5], [-0.5]]]), Q=np.eye(n), R=np.eye(1), N=N,
                          theta_hat0=np.zeros(p), name=f"random{seed}")
        try:
            return problem, design(problem, DesignOptions(x0_facets=2 * n + 2 if n == 2 else 2 * n), backend="drake")
        except Exception:  # noqa: BLE001 - an infeasible draw; try the next one
            continue
    pytest.fail(f"no random system with a successful design for seed {seed}")


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("seed, n, p, N", [(1, 2, 1, 4), (2, 2, 2, 6), (3, 3, 2, 3)])
def test_same_optimum_on_random_small_systems(backend, seed, n, p, N):
    problem, d = random_system(seed, n, p, N)
    rng = np.random.default_rng(seed)
    plain, vertex = solvers(tube_data(problem, d), backend)
    solved = 0
    for i in range(6):
        h = random_sub_box(rng, d.H_theta, -np.ones(p), np.ones(p))
        theta_hat = rng.uniform(-1, 1, p)
        direction = rng.normal(size=n)
        x = boundary_state(vertex, h, theta_hat, direction / np.linalg.norm(direction), fraction=[0.5, 0.99][i % 2])
        solved += assert_same_optimum(plain.solve(x, h, theta_hat), vertex.solve(x, h, theta_hat),
                                      f"{problem.name} case {i}")
    assert solved >= 5


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_feasible_region_across_its_boundary(backend, example_spec, example_design):
    """The set of states x_k for which (20) is feasible is the same for both forms: along random
    directions, 1% inside the vertex form's boundary both are feasible (and agree), 1% outside both
    are infeasible. A vertex form that drops or loosens rows fails the outer check, one that
    tightens them fails the inner one."""
    rng = np.random.default_rng(5)
    pr, d = example_spec.problem, example_design
    plain, vertex = solvers(tube_data(pr, d), backend)
    crossed = 0
    for i in range(6):
        h = random_sub_box(rng, d.H_theta, -np.ones(pr.p), np.ones(pr.p))
        theta_hat = rng.uniform(-1, 1, pr.p)
        angle = rng.uniform(0, 2 * np.pi)
        direction = np.array([np.cos(angle), np.sin(angle)])
        inner, found = boundary_state(vertex, h, theta_hat, direction, fraction=0.99, steps=24, with_flag=True)
        assert assert_same_optimum(plain.solve(inner, h, theta_hat), vertex.solve(inner, h, theta_hat), f"inner {i}")
        outer = inner * (1.01 / 0.99)
        if found:
            crossed += 1
            assert plain.solve(outer, h, theta_hat).status is SolveStatus.INFEASIBLE, f"outer {i}"
            assert vertex.solve(outer, h, theta_hat).status is SolveStatus.INFEASIBLE, f"outer {i}"
    assert crossed >= 3


@pytest.mark.parametrize("backend", BACKENDS)
def test_same_closed_loop_on_the_scalar_system(backend):
    problem = scalar_problem()
    d = design(problem, DesignOptions(x0_facets=2), backend="drake")
    runs = {}
    for form in ("plain", "vertex"):
        ctrl = AdaptiveMPC(problem, d, backend=backend, formulation=form, solver_options=TIGHT)
        runs[form] = simulate(ctrl, np.array([3.0]), np.array([0.7]), 15, "uniform", seed=4)
    assert runs["plain"].all_solved and runs["vertex"].all_solved
    np.testing.assert_allclose(runs["vertex"].u, runs["plain"].u, atol=AGREE_TOL)
    np.testing.assert_allclose(runs["vertex"].x, runs["plain"].x, atol=AGREE_TOL)


@pytest.mark.parametrize("backend", BACKENDS)
def test_an_inaccurate_vertex_solve_is_repeated_with_the_users_settings(backend, example_spec, example_design,
                                                                       monkeypatch):
    """The vertex form runs Clarabel without iterative refinement; a step that ends AlmostSolved
    is solved again with the user's settings (here forced by a status that always says so)."""
    pr, d = example_spec.problem, example_design
    plain, vertex = solvers(tube_data(pr, d), backend)
    if backend == "drake":
        monkeypatch.setattr(vertex._solver, "status", lambda result: SolveStatus.INACCURATE)
        users = vertex._plain_solver
    else:
        # the compiled route gives no answer (as an AlmostSolved one does), then Problem.solve says "inaccurate"
        monkeypatch.setattr(vertex, "_solve_compiled", lambda form: (None, 0.0))
        fast_solve = vertex._call.solve
        monkeypatch.setattr(vertex._call, "solve", lambda problem: (SolveStatus.INACCURATE,) + fast_solve(problem)[1:])
        users = vertex._plain_call
    again: list = []
    real_again = users.solve
    monkeypatch.setattr(users, "solve", lambda *a, **k: again.append(a[1:] or k) or real_again(*a, **k))
    x, h = np.asarray(example_spec.scenario.x0, float), np.max(d.theta_vertices @ d.H_theta.T, axis=0)
    sol = vertex.solve(x, h, np.zeros(pr.p))
    # solved again with the user's settings as they are (a spy on that solver: no options added, unlike the
    # retry ladder's rungs)
    assert again and again[0] in ((), {}), again
    assert_same_optimum(plain.solve(x, h, np.zeros(pr.p)), sol, "re-solved")
