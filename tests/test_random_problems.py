"""The library's numpy problem generator (amcp_drake.studies.random_problems): explicit seeds, the paper's
Assumption 1 by construction, and the hard cases it builds (pinning, θ* on vertices and facets).

Expected values are computed here from the definitions with scipy's LP (Θ ∩ Δ_1 written out from
(6), docs/explanation/paper.md §2), never by the generator's own helpers."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from amcp_drake.model.errors import ProblemError
from amcp_drake.studies.pinning import apply_pin, can_pin_at, pin_first_disturbance, pinning_disturbance
from amcp_drake.studies.random_problems import (
    ProblemShape,
    random_case,
    random_problem,
    random_shape,
    random_theta_star,
    theta_star_face,
)


def _problem(seed: int, **shape):
    spec, labels = random_problem(np.random.default_rng(seed), ProblemShape(**shape))
    return spec.problem, labels


def _chebyshev_radius(H, h) -> float:
    """Largest ball in {H θ <= h} (signed: negative when empty), scipy HiGHS."""
    norms = np.linalg.norm(H, axis=1)
    p = H.shape[1]
    res = linprog(np.r_[np.zeros(p), -1.0], A_ub=np.hstack([H, norms[:, None]]), b_ub=h,
                  bounds=[(None, None)] * (p + 1), method="highs")
    assert res.status == 0, res.message
    return float(res.x[-1])


def _theta_1(problem, x0, theta_star, w0):
    """Θ ∩ Δ_1 for the data x_1 = A(θ*) x0 + w0 (B_i = 0, u0 = 0 wlog since B(θ) u0 is known):
    Δ_1 = {θ | H_w (x_1 − A0 x0 − D(x0) θ) <= 1}, written from (6)."""
    D = np.stack([A_i @ x0 for A_i in problem.A], axis=1)
    x1 = (problem.A0 + np.tensordot(theta_star, problem.A, axes=1)) @ x0 + w0
    H = np.vstack([problem.H_theta, -problem.H_w @ D])
    h = np.concatenate([problem.h_theta, 1.0 - problem.H_w @ (x1 - problem.A0 @ x0)])
    return H, h


def test_same_seed_same_problem_and_different_seed_different_problem():
    shape = ProblemShape(n=2, m=1, p=2, theta_cuts=True, w_cuts=True, mixed_row=True)
    a, _ = _problem(7, **shape.__dict__)
    b, _ = _problem(7, **shape.__dict__)
    c, _ = _problem(8, **shape.__dict__)
    for name in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "Q", "R"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.A0, c.A0)


@pytest.mark.parametrize("seed", range(25))
def test_random_problems_meet_assumption_1(seed):
    rng = np.random.default_rng(seed)
    shape = random_shape(rng)
    problem = random_problem(rng, shape)[0].problem
    # θ̂0 ∈ Θ, 0 strictly inside Θ and W = {H_w w <= 1}, both bounded (every LP max ±e_i finite)
    assert np.all(problem.H_theta @ problem.theta_hat0 <= problem.h_theta + 1e-12)
    assert np.all(problem.h_theta > 0)
    for H, h in ((problem.H_theta, problem.h_theta), (problem.H_w, np.ones(len(problem.H_w)))):
        for d in np.vstack([np.eye(H.shape[1]), -np.eye(H.shape[1])]):
            res = linprog(-d, A_ub=H, b_ub=h, bounds=[(None, None)] * H.shape[1], method="highs")
            assert res.status == 0, "unbounded or infeasible"
    if not shape.input_uncertainty:
        assert not np.any(problem.B)
        assert problem.p <= problem.n


@pytest.mark.parametrize("seed", range(4))
def test_scaled_states_is_the_same_system_in_the_units_x_tilde_equal_T_x(seed):
    """The scaled problem of a seed is the unscaled problem of the same seed in x̃ = T x: its steps,
    W, Z and stage cost agree point by point with the unscaled ones mapped by T (checked through
    Problem.step and plain products, on random points), and T = diag(10^e), e from the documented
    exponents, not all 0."""
    shape = ProblemShape(n=3, m=2, p=2, theta_cuts=True, w_cuts=True, mixed_row=True, coupled_Q=True)
    plain, _ = _problem(seed, **shape.__dict__)
    scaled, labels = _problem(seed, **dict(shape.__dict__, scaled_states=True))
    exponents = [float(e.removeprefix("1e")) for e in labels["state scaling"].split(", ")]
    assert len(exponents) == 3 and any(exponents) and set(exponents) <= {-2, -1, 0, 1, 2}
    T = np.diag(10.0 ** np.array(exponents))
    rng = np.random.default_rng(seed)
    for _ in range(5):
        x, u, theta, w = rng.normal(size=3), rng.normal(size=2), rng.normal(size=2), rng.normal(size=3)
        np.testing.assert_allclose(scaled.step(T @ x, u, theta, T @ w), T @ plain.step(x, u, theta, w), rtol=1e-12,
                                   atol=1e-12 * np.abs(T @ x).max())
        np.testing.assert_allclose(scaled.H_w @ (T @ w), plain.H_w @ w, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(scaled.F @ (T @ x) + scaled.G @ u, plain.F @ x + plain.G @ u, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose((T @ x) @ scaled.Q @ (T @ x), x @ plain.Q @ x, rtol=1e-12)
    for name in ("H_theta", "h_theta", "theta_hat0", "R", "G"):
        np.testing.assert_array_equal(getattr(scaled, name), getattr(plain, name))
    assert not np.allclose(scaled.A0, plain.A0) or not np.allclose(scaled.B0, plain.B0)
    assert labels["state scaling"] != _problem(seed, **shape.__dict__)[1]["state scaling"] == "1"


def test_bad_shape_is_a_typed_error_naming_the_field():
    with pytest.raises(ProblemError, match="shape.n"):
        ProblemShape(n=0)
    with pytest.raises(ProblemError, match="shape.delta_range"):
        ProblemShape(delta_range=(0.1, 0.05))


@pytest.mark.parametrize("kind", ["vertex", "facet", "interior"])
def test_theta_star_kinds_are_where_their_name_says(kind):
    problem, _ = _problem(3, n=2, m=1, p=2, theta_cuts=True)
    theta = random_theta_star(np.random.default_rng(1), problem, kind)
    slack = (problem.h_theta - problem.H_theta @ theta) / np.linalg.norm(problem.H_theta, axis=1)
    assert np.all(slack >= -1e-12)
    active = np.flatnonzero(slack <= 1e-9)
    rank = np.linalg.matrix_rank(problem.H_theta[active]) if len(active) else 0
    assert {"vertex": rank == 2, "facet": rank == 1, "interior": rank == 0}[kind]
    assert theta_star_face(problem, theta) == kind


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("theta_cuts, w_cuts", [(False, False), (True, True)])
def test_pinning_at_a_vertex_collapses_theta_1_to_theta_star(seed, theta_cuts, w_cuts):
    problem, _ = _problem(seed, n=3, m=1, p=2, input_uncertainty=False, theta_cuts=theta_cuts, w_cuts=w_cuts)
    rng = np.random.default_rng(seed)
    theta_star = random_theta_star(rng, problem, "vertex")
    x0 = rng.uniform(-2, 2, size=problem.n)
    w0 = pinning_disturbance(problem, problem.regressor(x0, np.zeros(problem.m)), theta_star)
    assert np.all(problem.H_w @ w0 <= 1 + 1e-12)  # a point of W ...
    assert np.sum(np.abs(problem.H_w @ w0 - 1) <= 1e-9) >= problem.n  # ... at a vertex
    H, h = _theta_1(problem, x0, theta_star, w0)
    assert abs(_chebyshev_radius(H, h)) <= 1e-9
    # the intersection is {θ*}: every support value equals θ*'s
    for d in np.vstack([np.eye(problem.p), -np.eye(problem.p)]):
        res = linprog(-d, A_ub=H, b_ub=h + 1e-9, bounds=[(None, None)] * problem.p, method="highs")
        assert res.status == 0
        assert -res.fun == pytest.approx(d @ theta_star, abs=1e-6)
    # a random vertex of W instead of the pinning one leaves a full-dimensional set in most draws:
    # the collapse is the construction's doing, not chance (negative control)
    other = [v for v in problem.w_vertices() if not np.allclose(v, w0)]
    radii = [_chebyshev_radius(*_theta_1(problem, x0, theta_star, v)) for v in other]
    assert max(radii) > 1e-4


def test_pinning_on_a_facet_keeps_theta_1_in_the_facet_hyperplane_and_thin_leaves_a_sliver():
    problem, _ = _problem(11, n=2, m=1, p=2, input_uncertainty=False)
    rng = np.random.default_rng(2)
    theta_star = random_theta_star(rng, problem, "facet")
    x0 = np.array([1.3, -0.7])
    D = problem.regressor(x0, np.zeros(1))
    w0 = pinning_disturbance(problem, D, theta_star)
    H, h = _theta_1(problem, x0, theta_star, w0)
    assert abs(_chebyshev_radius(H, h)) <= 1e-9
    thin = pinning_disturbance(problem, D, theta_star, thin=True)
    radius = _chebyshev_radius(*_theta_1(problem, x0, theta_star, thin))
    assert 0.0 < radius <= 1e-6


def test_pinning_needs_theta_star_on_the_boundary_and_a_regressor_of_full_rank():
    problem, _ = _problem(4, n=2, m=1, p=2, input_uncertainty=False)
    with pytest.raises(ProblemError, match="theta_star"):
        pinning_disturbance(problem, np.eye(2), np.zeros(2))
    vertex = problem.theta_vertices()[0]
    with pytest.raises(ProblemError, match="regressor"):
        pinning_disturbance(problem, np.zeros((2, 2)), vertex)
    with_b, _ = _problem(4, n=2, m=1, p=2, input_uncertainty=True)
    with pytest.raises(ProblemError, match="u0"):  # input uncertainty: D(x_0, u_0) needs the first input
        apply_pin(with_b, np.ones(2), with_b.theta_vertices()[0], np.zeros((3, 2)), "point")
    assert not can_pin_at(with_b, np.ones(2), with_b.theta_vertices()[0])


def test_can_pin_at_refuses_an_x0_where_the_regressor_loses_rank():
    """D(x_0) = [A_1 x_0, A_2 x_0] has rank 1 when A_2 x_0 is parallel to A_1 x_0 (the thorough
    profile drew such an x_0: the generator raised instead of not pinning)."""
    problem, _ = _problem(4, n=2, m=1, p=2, input_uncertainty=False)
    vertex = problem.theta_vertices()[0]
    A1, A2 = problem.A
    # an x_0 with A_2 x_0 ∥ A_1 x_0: an eigenvector of A_1^{-1} A_2 (real for this draw, or x_0 = 0)
    values, vectors = np.linalg.eig(np.linalg.solve(A1, A2)) if abs(np.linalg.det(A1)) > 1e-9 else (None, None)
    x_bad = np.real(vectors[:, 0]) if values is not None and np.all(np.isreal(values)) else np.zeros(2)
    assert np.linalg.matrix_rank(problem.regressor(x_bad, np.zeros(1)), tol=1e-9) < 2
    assert not can_pin_at(problem, x_bad, vertex)
    x_good = np.array([1.3, -0.7])
    assert np.linalg.matrix_rank(problem.regressor(x_good, np.zeros(1))) == 2
    assert can_pin_at(problem, x_good, vertex)
    assert not can_pin_at(problem, x_good, np.zeros(2))  # θ* inside Θ: nothing to pin


def test_random_case_is_reproducible_and_labels_what_it_built():
    a = random_case(np.random.default_rng(12), steps=5)
    b = random_case(np.random.default_rng(12), steps=5)
    assert a.key() == b.key()
    assert a.w.shape == (5, a.problem.n)
    assert theta_star_face(a.problem, a.theta_star) in ("vertex", "facet", "interior")
    assert a.labels["pin"] in ("none", "point", "thin")


def test_hard_case_coverage_of_a_pinned_run_and_of_a_plain_one():
    """A run whose w_0 pins Θ_1 at a vertex θ* reports a lower-dimensional Θ_k and θ* at a vertex;
    the same run with w = 0 (no information) reports neither."""
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate
    from amcp_drake.studies.random_problems import hard_case_coverage

    spec, _ = random_problem(np.random.default_rng(5), ProblemShape(n=2, m=1, p=2, N=3, input_uncertainty=False))
    problem = spec.problem
    offline = design(problem, spec.design)
    theta_star = problem.theta_vertices()[0]
    x0 = np.array([0.3, -0.2])
    pinned = apply_pin(problem, x0, theta_star, np.zeros((3, 2)), "point")
    ctrl = AdaptiveMPC(problem, offline)
    cov = hard_case_coverage(simulate(ctrl, x0, theta_star, 3, pinned))
    assert cov == {"theta_k_lower_dim": 1.0, "theta_star_vertex": 1.0, "theta_star_facet": 0.0}
    plain = hard_case_coverage(simulate(ctrl, x0, np.zeros(2), 3, np.zeros((3, 2))))
    assert plain == {"theta_k_lower_dim": 0.0, "theta_star_vertex": 0.0, "theta_star_facet": 0.0}


def _run_of_sets(*sets):
    """A stand-in trajectory whose records hold only the sets Θ_0, Θ_1, ... (what the coverage reads)."""
    from types import SimpleNamespace

    return SimpleNamespace(records=[SimpleNamespace(H_theta=np.asarray(H, float), h_theta=np.asarray(h, float))
                                    for H, h in sets])


BOX = (np.vstack([np.eye(2), -np.eye(2)]), np.ones(4))  # Θ_0 = [−1, 1]²


@pytest.mark.parametrize(("later", "shrank"), [
    (BOX, False),                                                            # nothing learned
    ((BOX[0], np.array([1.0 - 2e-6, 1, 1, 1])), True),                       # (9): an offset lowered by 2e-6
    ((BOX[0], np.array([1.0 - 5e-7, 1, 1, 1])), False),                      # ... by less than SHRINK_TOL
    ((np.vstack([BOX[0], [[1.0, 1.0]]]), np.r_[BOX[1], 1.9]), True),         # (7): a row cuts the corner (1, 1)
    ((np.vstack([BOX[0], [[1.0, 1.0]]]), np.r_[BOX[1], 2.0]), False),        # (7): a row through the corner only
    ((np.vstack([BOX[0][1:], [[2.0, 2.0]]]), np.r_[BOX[1][1:], 3.8]), True), # (7): a row removed, one cut in
])
def test_theta_shrank_sees_every_update_whatever_its_rows(later, shrank):
    """Θ_k shrank below Θ_0 exactly when a vertex of Θ_0 is cut off: the exact update (7) appends rows
    (the earlier offset comparison on Θ_0's rows never saw it shrink); the cuts are by hand
    ((2 − 1.9)/√2 ≈ 0.07 at the corner (1, 1))."""
    from amcp_drake.studies.random_problems import theta_shrank

    assert theta_shrank(_run_of_sets(BOX, BOX, later)) is shrank


def test_the_radius_of_the_last_set_is_measured_when_the_update_changed_its_rows():
    """The exact update (7) records Θ_k with rows of its own: Θ_0 ∩ {θ_1 <= 0.5} = [−1, 0.5] × [−1, 1]
    has Chebyshev radius 0.75 (by hand), which was "not measured" while only Θ_0's row count was read."""
    from amcp_drake.studies.random_problems import last_theta_k_radius

    cut = (np.vstack([BOX[0], [[2.0, 0.0]]]), np.r_[BOX[1], 1.0])
    assert last_theta_k_radius(_run_of_sets(BOX, cut)) == pytest.approx(0.75, abs=1e-9)
    assert np.isnan(last_theta_k_radius(_run_of_sets(BOX)))


def _theta_1_recorded(problem, x0, u0, x1):
    """Θ ∩ Δ_1 from recorded data (x_0, u_0, x_1), written from (6) with input uncertainty:
    Δ_1 = {θ | H_w (x_1 − A0 x0 − B0 u0 − D(x0, u0) θ) <= 1}, D = [A_i x0 + B_i u0]_i."""
    D = np.stack([A_i @ x0 + B_i @ u0 for A_i, B_i in zip(problem.A, problem.B)], axis=1)
    H = np.vstack([problem.H_theta, -problem.H_w @ D])
    h = np.concatenate([problem.h_theta, 1.0 - problem.H_w @ (x1 - problem.A0 @ x0 - problem.B0 @ u0)])
    return H, h


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
@pytest.mark.parametrize(("kind", "mode"), [("vertex", "point"), ("facet", "point"), ("vertex", "thin")])
def test_pinning_with_input_uncertainty_collapses_theta_1_on_the_closed_loop(backend, kind, mode):
    """Generator version 5: with B_i != 0, w_0 is chosen for the controller's first input u_0
    (computed on Drake), so the closed loop of either backend has a Θ_1 of zero volume (radius of
    the controller's 1e-6 widening of Δ_1 at most), which contains θ*. Θ_1 is recomputed here from
    the recorded x_0, u_0, x_1 with scipy's LP. Negative control: w_0 chosen as if u_0 = 0 (the
    regressor without the input) picks another vertex of W on this draw and leaves Θ_1
    full-dimensional (radius 0.24 at the vertex, 0.11 on the facet)."""
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import DELTA_MARGIN, AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec, _ = random_problem(np.random.default_rng(8), ProblemShape(n=2, m=1, p=2, N=3, input_uncertainty=True))
    problem = spec.problem
    assert np.any(problem.B)
    offline = design(problem, spec.design)
    theta_star = random_theta_star(np.random.default_rng(2), problem, kind)
    assert theta_star_face(problem, theta_star) == kind
    x0 = np.array([0.3, -0.2])
    w, pin = pin_first_disturbance(problem, offline, x0, theta_star, np.zeros((2, 2)), mode)
    assert pin == mode and np.any(w[0])
    traj = simulate(AdaptiveMPC(problem, offline, backend=backend), x0, theta_star, 2, w)
    H, h = _theta_1_recorded(problem, traj.x[0], traj.u[0], traj.x[1])
    assert np.all(H @ theta_star <= h + 1e-9)
    assert _chebyshev_radius(H, h) <= 1e-6
    # the backend's own Θ_1 (recorded at step 1, Δ_1 widened by DELTA_MARGIN) is as thin: the pin reached it
    rec = traj.records[1]
    assert _chebyshev_radius(np.asarray(rec.H_theta), np.asarray(rec.h_theta)) <= 5 * DELTA_MARGIN
    # negative control: w_0 pinning for u_0 = 0 instead of the controller's u_0
    w_wrong = np.zeros((2, 2))
    w_wrong[0] = pinning_disturbance(problem, problem.regressor(x0, np.zeros(problem.m)), theta_star)
    wrong = simulate(AdaptiveMPC(problem, offline, backend=backend), x0, theta_star, 2, w_wrong)
    assert _chebyshev_radius(*_theta_1_recorded(problem, wrong.x[0], wrong.u[0], wrong.x[1])) > 1e-2
