"""The cvxpy backend (``amcp_reference``) on problems whose answers are computed by hand or by a
separate numpy/scipy calculation in the test, never by the code under test; plus the Drake
cross-check on the tube MPC QP (20) when the Drake backend is importable."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are
from scipy.optimize import linprog, minimize_scalar

from amcp_drake.backends import Backend, TubeMPCData, TubeMPCSolver, get_backend
from amcp_drake.model.status import SolveStatus
from amcp_reference import STATUS_MAP, CvxpyBackend
from amcp_reference.tube_mpc import GROUPS

#: Clarabel's default tolerances are 1e-8; hand values are exact.
TOL = 1e-6
#: Cross-backend agreement in v required by the brief.
CROSS_TOL = 1e-6


@pytest.fixture(scope="module")
def be():
    return CvxpyBackend()


# -- registry and status map -----------------------------------------------------------------

def test_registry_returns_the_cvxpy_backend_which_satisfies_the_protocol():
    backend = get_backend("cvxpy")
    assert isinstance(backend, CvxpyBackend)
    assert backend.name == "cvxpy"
    assert isinstance(backend, Backend)


@pytest.mark.parametrize("cvxpy_status, expected", [
    ("optimal", SolveStatus.OPTIMAL),
    ("optimal_inaccurate", SolveStatus.INACCURATE),
    ("infeasible", SolveStatus.INFEASIBLE),
    ("infeasible_inaccurate", SolveStatus.INFEASIBLE),
    ("unbounded", SolveStatus.UNBOUNDED),
    ("unbounded_inaccurate", SolveStatus.UNBOUNDED),
    ("infeasible_or_unbounded", SolveStatus.INFEASIBLE),
    ("user_limit", SolveStatus.INACCURATE),
    ("solver_error", SolveStatus.ERROR),
])
def test_status_map_sends_each_cvxpy_status_to_the_canonical_one(cvxpy_status, expected):
    assert STATUS_MAP[cvxpy_status] is expected


def test_status_map_covers_every_status_string_cvxpy_defines():
    import cvxpy.settings as s

    defined = {s.OPTIMAL, s.OPTIMAL_INACCURATE, s.INFEASIBLE, s.INFEASIBLE_INACCURATE, s.UNBOUNDED,
               s.UNBOUNDED_INACCURATE, s.INFEASIBLE_OR_UNBOUNDED, s.USER_LIMIT, s.SOLVER_ERROR}
    assert defined <= set(STATUS_MAP)


def test_unknown_solver_name_is_rejected_at_construction():
    with pytest.raises(ValueError, match="not installed"):
        CvxpyBackend(solver="NO_SUCH_SOLVER")


# -- support ---------------------------------------------------------------------------------

BOX_H = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])


def test_support_of_a_box_matches_hand_values(be):
    # box [-1, 2] x [-3, 4]
    values = be.support(BOX_H, [2.0, 1.0, 4.0, 3.0], [[1, 0], [-1, 0], [0, 1], [0, -1], [1, 1], [1, -1], [-2, 0.5]])
    np.testing.assert_allclose(values, [2.0, 1.0, 4.0, 3.0, 6.0, 5.0, 2.0 + 2.0], atol=TOL)


def test_support_reuses_the_problem_for_a_new_set_of_the_same_shape(be):
    first = be.support(BOX_H, [2.0, 1.0, 4.0, 3.0], [[1.0, 1.0]])
    # same shape, different data: must not return the cached answer
    second = be.support(BOX_H, [0.5, 0.5, 0.25, 0.25], [[1.0, 1.0]])
    np.testing.assert_allclose(first, [6.0], atol=TOL)
    np.testing.assert_allclose(second, [0.75], atol=TOL)


def test_support_is_infinite_when_unbounded_and_nan_when_empty(be):
    half_plane = be.support([[1.0, 0.0]], [1.0], [[0.0, 1.0], [1.0, 0.0]])
    assert half_plane[0] == np.inf
    assert half_plane[1] == pytest.approx(1.0, abs=TOL)
    empty = be.support([[1.0], [-1.0]], [-1.0, -1.0], [[1.0]])  # x <= -1 and x >= 1
    assert np.isnan(empty[0])


def test_support_with_non_finite_data_is_nan_not_an_exception(be):
    assert np.all(np.isnan(be.support(BOX_H, [np.nan, 1.0, 1.0, 1.0], [[1.0, 0.0]])))


def test_support_problem_is_dpp():
    from amcp_reference.offline import SupportLP

    assert SupportLP((4, 2)).problem.is_dpp()


# -- set-membership LP (9) ---------------------------------------------------------------------

def _check_certificate(H_theta, h_prev, H_data, h_data, res):
    """Λ >= 0, Λ H̃ = H_θ, Λ h̃ <= h: the constraints of (9)."""
    H_tilde = np.vstack([H_theta, H_data])
    h_tilde = np.concatenate([h_prev, h_data])
    assert res.Lambda.shape == (len(H_theta), len(H_tilde))
    assert np.all(res.Lambda >= 0.0)
    np.testing.assert_allclose(res.Lambda @ H_tilde, H_theta, atol=TOL)
    assert np.all(res.Lambda @ h_tilde <= res.h + TOL)


def test_set_update_one_dimensional_hand_case(be):
    # Θ = [-1, 1], one data row θ <= 0.3: h = [0.3, 1]; Λ row 0 = [0, 0, 1], row 1 = [0, 1, 0] (unique)
    H_theta, h_prev = np.array([[1.0], [-1.0]]), np.array([1.0, 1.0])
    H_data, h_data = np.array([[1.0]]), np.array([0.3])
    res = be.set_update(H_theta, h_prev, H_data, h_data)
    assert res.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(res.h, [0.3, 1.0], atol=TOL)
    np.testing.assert_allclose(res.Lambda, [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]], atol=TOL)
    _check_certificate(H_theta, h_prev, H_data, h_data, res)


def test_set_update_two_data_rows_on_a_box(be):
    # Θ = [-1, 1]², data θ1 >= 0.2 and θ2 <= -0.4: h = [1, -0.2, -0.4, 1]
    h_prev = np.ones(4)
    H_data, h_data = np.array([[-1.0, 0.0], [0.0, 1.0]]), np.array([-0.2, -0.4])
    res = be.set_update(BOX_H, h_prev, H_data, h_data)
    assert res.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(res.h, [1.0, -0.2, -0.4, 1.0], atol=TOL)
    _check_certificate(BOX_H, h_prev, H_data, h_data, res)


@pytest.mark.parametrize("seed", range(5))
def test_set_update_matches_row_wise_scipy_lps_and_never_grows(be, seed):
    rng = np.random.default_rng(seed)
    p = 3
    H_theta = np.vstack([np.eye(p), -np.eye(p), rng.normal(size=(3, p))])
    h_prev = np.concatenate([np.ones(2 * p), np.abs(H_theta[2 * p:]).sum(axis=1)])  # supports of the unit box
    inside = rng.uniform(-0.5, 0.5, p)
    H_data = rng.normal(size=(4, p))
    h_data = H_data @ inside + rng.uniform(0.0, 0.5, 4)  # the point `inside` satisfies the data rows
    res = be.set_update(H_theta, h_prev, H_data, h_data)
    assert res.status is SolveStatus.OPTIMAL
    H_tilde, h_tilde = np.vstack([H_theta, H_data]), np.concatenate([h_prev, h_data])
    expected = [-linprog(-row, A_ub=H_tilde, b_ub=h_tilde, bounds=[(None, None)] * p, method="highs").fun
                for row in H_theta]
    np.testing.assert_allclose(res.h, expected, atol=TOL)
    assert np.all(res.h <= h_prev + TOL)  # Lemma 3, (10): Θ_k ⊆ Θ_{k-1}
    _check_certificate(H_theta, h_prev, H_data, h_data, res)


def test_set_update_with_empty_intersection_is_not_optimal_and_has_no_solution(be):
    res = be.set_update([[1.0], [-1.0]], [1.0, 1.0], [[1.0]], [-2.0])  # θ ∈ [-1, 1] and θ <= -2
    assert res.status in (SolveStatus.INFEASIBLE, SolveStatus.UNBOUNDED)
    assert res.h is None and res.Lambda is None


def test_set_update_problem_is_dpp():
    from amcp_reference.online import SetUpdateLP

    assert SetUpdateLP((4, 2, 2)).problem.is_dpp()


# -- projection of (12) ------------------------------------------------------------------------

def test_projection_onto_a_box_is_clipping(be):
    rng = np.random.default_rng(7)
    lo, hi = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.5, 2.0])
    H = np.vstack([np.eye(3), -np.eye(3)])
    h = np.concatenate([hi, -lo])
    for point in rng.normal(scale=2.0, size=(8, 3)):
        res = be.project(point, H, h)
        assert res.status is SolveStatus.OPTIMAL
        np.testing.assert_allclose(res.theta, np.clip(point, lo, hi), atol=TOL)


def test_projection_onto_a_half_plane_hand_case(be):
    res = be.project([2.0, 2.0], [[1.0, 1.0]], [1.0])  # onto θ1 + θ2 <= 1: (0.5, 0.5)
    np.testing.assert_allclose(res.theta, [0.5, 0.5], atol=TOL)


def test_projection_onto_an_empty_set_has_no_solution(be):
    res = be.project([0.0], [[1.0], [-1.0]], [-1.0, -1.0])
    assert res.status is not SolveStatus.OPTIMAL and res.theta is None


# -- robust gain LMI (16) ----------------------------------------------------------------------

def _scalar_best_P(a_vertices, b=1.0, q=1.0, r=1.0):
    """Scalar (16): P >= (q + r K²)/(1 − (a + bK)²) at each vertex; the LMI's max trace(S) =
    min P, found here by a bounded scalar search over K (independent of the backend)."""
    def worst(K):
        values = [(q + r * K * K) / (1.0 - (a + b * K) ** 2) if abs(a + b * K) < 1 else np.inf for a in a_vertices]
        return max(values)

    res = minimize_scalar(worst, bounds=(-2.0, 0.0), method="bounded", options={"xatol": 1e-10})
    return res.x, res.fun


def test_robust_gain_scalar_system_is_the_min_max_of_the_hand_formula(be):
    a_vertices = [0.5, 1.2]
    res = be.robust_gain(np.array(a_vertices).reshape(2, 1, 1), np.ones((2, 1, 1)), np.eye(1), np.eye(1), 1e-9)
    assert res.status is SolveStatus.OPTIMAL
    K_ref, P_ref = _scalar_best_P(a_vertices)
    assert res.K[0, 0] == pytest.approx(K_ref, abs=1e-4)
    assert res.P[0, 0] == pytest.approx(P_ref, rel=1e-5)
    for a in a_vertices:  # (16) by hand: (a+K)² P − P + 1 + K² <= 0, and A_cl stable
        acl = a + res.K[0, 0]
        assert abs(acl) < 1
        assert acl * acl * res.P[0, 0] - res.P[0, 0] + 1 + res.K[0, 0] ** 2 <= 1e-7


def test_robust_gain_example1_satisfies_16_at_every_vertex_and_matches_spec(be, example_spec):
    pr = example_spec.problem
    verts = pr.theta_vertices()
    A_v = np.array([pr.A_of(t) for t in verts])
    B_v = np.array([pr.B_of(t) for t in verts])
    res = be.robust_gain(A_v, B_v, pr.Q, pr.R, 1e-9)
    assert res.status is SolveStatus.OPTIMAL
    assert np.all(np.linalg.eigvalsh(res.P) > 0)
    for A, B in zip(A_v, B_v):
        Acl = A + B @ res.K
        lhs = Acl.T @ res.P @ Acl - res.P + pr.Q + res.K.T @ pr.R @ res.K
        assert np.max(np.linalg.eigvalsh(lhs)) <= 1e-7
    # Example 1 (docs/explanation/paper.md §9): K ≈ [0.0176 −0.4152], P ≈ [1.468 0.208; 0.208 1.733]
    np.testing.assert_allclose(res.K, [[0.0176, -0.4152]], atol=5e-4)
    np.testing.assert_allclose(res.P, [[1.468, 0.208], [0.208, 1.733]], atol=1e-3)


def test_robust_gain_rejects_an_unstabilisable_vertex(be):
    # x+ = 1.5 x + 0·u: no K; the solver may accept S of the order of its tolerance
    res = be.robust_gain(np.array([[[1.5]]]), np.zeros((1, 1, 1)), np.eye(1), np.eye(1), 1e-9)
    assert res.status is not SolveStatus.OPTIMAL
    assert res.K is None and res.P is None


def test_solver_error_becomes_a_status_not_an_exception():
    # OSQP has no PSD cone: cvxpy raises SolverError, the backend must return ERROR
    res = CvxpyBackend(solver="OSQP").robust_gain(np.array([[[0.5]]]), np.ones((1, 1, 1)), np.eye(1), np.eye(1), 1e-9)
    assert res.status is SolveStatus.ERROR
    assert res.K is None



def test_a_solver_panic_becomes_a_status_not_an_exception(monkeypatch):
    """Clarabel's Rust panics reach Python as pyo3_runtime.PanicException, a BaseException (the gain LMI
    of the unstabilisable vertex above panicked in the slack form with "Eigval error: Eigen(1)"); the
    class is not importable, so one of that module and name stands in for it. Other BaseExceptions
    (KeyboardInterrupt) still propagate."""
    import cvxpy as cp

    from amcp_reference.solver_call import SolverCall

    panic = type("PanicException", (BaseException,), {"__module__": "pyo3_runtime"})
    x = cp.Variable()
    problem = cp.Problem(cp.Minimize(x), [x >= 1])
    call = SolverCall("CLARABEL", None)
    for raised, expected in ((panic("Eigval error: Eigen(1)"), SolveStatus.ERROR), (KeyboardInterrupt(), None)):
        def solve(*args, _raised=raised, **kwargs):
            raise _raised

        monkeypatch.setattr(problem, "solve", solve)
        if expected is None:
            with pytest.raises(KeyboardInterrupt):
                call.solve(problem)
        else:
            status, _, detail = call.solve(problem)
            assert status is expected and "Eigval error" in detail

# -- tube MPC QP (20), scalar system ---------------------------------------------------------

def scalar_tube_data(u_max=10.0, x_max=10.0, N=5, K=-0.5, P=1.5, Q=1.0, R=1.0, H_theta=((1.0,), (-1.0,))):
    """x+ = (0.9 + 0.1 θ) x + u + w, θ ∈ Θ_k, |w| <= 0.1; X0 = [-1, 1] (H_x = [1; −1], vertices ±1).

    w̄ = [0.1, 0.1]; Z: |x| <= x_max, |u| <= u_max, so f̄_i = max_{x∈[-1,1]} [F+GK]_i x = |F+GK|_i.
    Terminal set |z_N| + α_N <= 5 (loose; only used as a constraint of this single QP).
    """
    F = np.array([[1 / x_max], [-1 / x_max], [0.0], [0.0]])
    G = np.array([[0.0], [0.0], [1 / u_max], [-1 / u_max]])
    Kmat = np.array([[K]])
    return TubeMPCData(
        A0=np.array([[0.9]]), B0=np.array([[1.0]]), A=np.array([[[0.1]]]), B=np.array([[[0.0]]]),
        F=F, G=G, Q=np.array([[Q]]), R=np.array([[R]]), N=N, K=Kmat, P=np.array([[P]]),
        H_x=np.array([[1.0], [-1.0]]), X0_vertices=np.array([[1.0], [-1.0]]),
        w_bar=np.array([0.1, 0.1]), f_bar=np.abs(F + G @ Kmat).ravel(),
        H_T=np.array([[0.2], [-0.2]]), h_T=np.array([0.2, 0.2]), H_theta=np.array(H_theta))


def check_tube_solution(data, sol, x, h_theta, H_theta=None, tol=TOL):
    """Every constraint of (20), evaluated in numpy from the returned z, α, v, Λ
    (docs/explanation/paper.md §4, §6)."""
    H_theta = np.asarray(data.H_theta if H_theta is None else H_theta, float)
    N, nv, u, q = sol.Lambda.shape
    n, p = data.A0.shape[0], data.A.shape[0]
    assert sol.v.shape == (N, data.B0.shape[1]) and sol.z.shape == (N + 1, n) and sol.alpha.shape == (N + 1,)
    assert np.all(sol.alpha >= -tol) and np.all(sol.Lambda >= -tol)
    FGK = data.F + data.G @ data.K
    ones = np.ones(u)
    assert np.all(-data.H_x @ sol.z[0] - sol.alpha[0] * ones <= -data.H_x @ x + tol)          # (15b)
    for l in range(N):
        assert np.all(FGK @ sol.z[l] + data.G @ sol.v[l] + sol.alpha[l] * data.f_bar <= 1 + tol)  # (15a)
        for j, xj in enumerate(data.X0_vertices):
            x_lj = sol.z[l] + sol.alpha[l] * xj
            u_lj = data.K @ x_lj + sol.v[l]
            d_lj = data.A0 @ x_lj + data.B0 @ u_lj - sol.z[l + 1]
            D_lj = np.column_stack([data.A[i] @ x_lj + data.B[i] @ u_lj for i in range(p)])
            Lam = sol.Lambda[l, j]
            assert np.all(Lam @ h_theta + data.H_x @ d_lj - sol.alpha[l + 1] * ones <= -data.w_bar + tol)  # (15c)
            np.testing.assert_allclose(data.H_x @ D_lj, Lam @ H_theta, atol=tol)                          # (15d)
    assert np.all(data.H_T @ sol.z[N] + data.h_T * sol.alpha[N] <= 1 + tol)                    # terminal


def check_scalar_tube_semantics(data, sol, x, theta_lo, theta_hi, tol=TOL):
    """(5a)-(5c) directly on intervals: x_k ∈ X_0; every vertex of X_l, θ ∈ {lo, hi}, w = ±0.1 lands
    in X_{l+1}; (x, Kx + v_l) ∈ Z at the vertices of X_l."""
    z, a, v = sol.z[:, 0], sol.alpha, sol.v[:, 0]
    K = data.K[0, 0]
    assert z[0] - a[0] - tol <= x[0] <= z[0] + a[0] + tol
    for l in range(data.N):
        for xv in (z[l] - a[l], z[l] + a[l]):
            uv = K * xv + v[l]
            assert np.all(data.F[:, 0] * xv + data.G[:, 0] * uv <= 1 + tol)
            for theta in (theta_lo, theta_hi):
                for w in (-0.1, 0.1):
                    nxt = (data.A0[0, 0] + data.A[0, 0, 0] * theta) * xv + data.B0[0, 0] * uv + w
                    assert z[l + 1] - a[l + 1] - tol <= nxt <= z[l + 1] + a[l + 1] + tol


def unconstrained_optimum(data, x, theta_hat):
    """argmin of (17)-(18) over v with no constraints, by least squares on the stacked residuals
    (x̂ and û are affine in v); returns (v (N, m), J)."""
    m, N = data.B0.shape[1], data.N
    A = data.A0 + np.tensordot(theta_hat, data.A, axes=1)
    B = data.B0 + np.tensordot(theta_hat, data.B, axes=1)
    Qh, Rh, Ph = (np.linalg.cholesky(M).T for M in (data.Q, data.R, data.P))

    def residual(vflat):
        vv = vflat.reshape(N, m)
        res, xh = [], np.asarray(x, float)
        for l in range(N):
            uh = data.K @ xh + vv[l]
            res += [Qh @ xh, Rh @ uh]
            xh = A @ xh + B @ uh
        res.append(Ph @ xh)
        return np.concatenate(res)

    c = residual(np.zeros(N * m))
    M = np.column_stack([residual(e) - c for e in np.eye(N * m)])
    vflat = np.linalg.lstsq(M, -c, rcond=None)[0]
    return vflat.reshape(N, m), float(np.sum(residual(vflat) ** 2))


def cost_17(data, x, theta_hat, v):
    A = data.A0 + np.tensordot(theta_hat, data.A, axes=1)
    B = data.B0 + np.tensordot(theta_hat, data.B, axes=1)
    xh, J = np.asarray(x, float), 0.0
    for l in range(data.N):
        uh = data.K @ xh + v[l]
        J += xh @ data.Q @ xh + uh @ data.R @ uh
        xh = A @ xh + B @ uh
    return J + xh @ data.P @ xh


def test_tube_problem_is_dpp_and_solver_satisfies_the_protocol(be):
    mpc = be.tube_mpc(scalar_tube_data())
    assert isinstance(mpc, TubeMPCSolver)
    assert mpc.problem.is_dpp()


def test_loose_tube_mpc_gives_the_unconstrained_optimum_and_a_valid_tube(be):
    data = scalar_tube_data()
    x, h_theta, theta_hat = np.array([2.0]), np.array([1.0, 1.0]), np.array([0.3])
    sol = be.tube_mpc(data).solve(x, h_theta, theta_hat)
    assert sol.status is SolveStatus.OPTIMAL
    v_ref, J_ref = unconstrained_optimum(data, x, theta_hat)
    np.testing.assert_allclose(sol.v, v_ref, atol=TOL)
    assert sol.cost == pytest.approx(J_ref, abs=TOL)
    assert sol.cost == pytest.approx(cost_17(data, x, theta_hat, sol.v), abs=1e-9)
    assert sol.Lambda.shape == (5, 2, 2, 2)
    check_tube_solution(data, sol, x, h_theta)
    check_scalar_tube_semantics(data, sol, x, -1.0, 1.0)
    assert sol.solver_time > 0 and sol.update_time > 0


def test_with_lqr_gain_and_riccati_weight_the_optimal_v_is_zero(be):
    # K, P from the Riccati equation of A(θ̂), B(θ̂): Bellman optimality makes v* = 0 (loose problem)
    theta_hat = np.array([-0.4])
    a, b = 0.9 + 0.1 * theta_hat[0], 1.0
    P = solve_discrete_are(np.array([[a]]), np.array([[b]]), np.eye(1), np.eye(1))[0, 0]
    K = -(b * P * a) / (1.0 + b * P * b)
    data = scalar_tube_data(K=K, P=P)
    x = np.array([1.5])
    sol = be.tube_mpc(data).solve(x, np.array([1.0, 1.0]), theta_hat)
    assert sol.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(sol.v, 0.0, atol=TOL)
    assert sol.cost == pytest.approx(P * x[0] ** 2, rel=1e-8)  # J* = x_kᵀ P x_k


def test_tight_input_bound_is_active_and_the_tube_is_valid_on_a_shrunk_theta(be):
    # |u| <= 0.5 with u_0 = K x + v_0 = -1 + v_0 unconstrained: the bound must be active at l = 0
    data = scalar_tube_data(u_max=0.5)
    x, h_theta, theta_hat = np.array([2.0]), np.array([0.5, 0.2]), np.array([0.1])  # Θ_k = [-0.2, 0.5]
    sol = be.tube_mpc(data).solve(x, h_theta, theta_hat)
    assert sol.status is SolveStatus.OPTIMAL
    u0 = data.K[0, 0] * x[0] + sol.v[0, 0]
    assert u0 == pytest.approx(-0.5, abs=TOL)
    check_tube_solution(data, sol, x, h_theta)
    check_scalar_tube_semantics(data, sol, x, -0.2, 0.5)
    _, J_free = unconstrained_optimum(data, x, theta_hat)
    assert sol.cost >= J_free - TOL


def test_infeasible_state_gives_status_no_arrays_and_names_a_group(be):
    data = scalar_tube_data()
    sol = be.tube_mpc(data).solve(np.array([100.0]), np.array([1.0, 1.0]), np.array([0.0]))  # |x| <= 10
    assert sol.status is SolveStatus.INFEASIBLE
    assert sol.v is None and sol.z is None and sol.alpha is None and sol.Lambda is None and sol.cost is None
    assert sol.infeasible_constraints and set(sol.infeasible_constraints) <= set(GROUPS)


def test_non_finite_input_is_an_error_status(be):
    sol = be.tube_mpc(scalar_tube_data()).solve(np.array([np.nan]), np.array([1.0, 1.0]), np.array([0.0]))
    assert sol.status is SolveStatus.ERROR and sol.v is None


@pytest.mark.parametrize("x, h_theta, theta_hat, H_theta", [
    ([1.0, 0.0], [1.0, 1.0], [0.0], None),          # x of the wrong length
    ([1.0], [1.0, 1.0, 1.0], [0.0], None),          # h_theta with more rows than H_theta
    ([1.0], [1.0, 1.0], [0.0], [[1.0, 0.0], [-1.0, 0.0]]),  # H_theta with p = 2 columns
])
def test_wrong_shapes_are_an_error_status_and_the_solver_still_works(be, x, h_theta, theta_hat, H_theta):
    mpc = be.tube_mpc(scalar_tube_data())
    args = [np.array(a, float) for a in (x, h_theta, theta_hat)]
    sol = mpc.solve(*args, H_theta=None if H_theta is None else np.array(H_theta))
    assert sol.status is SolveStatus.ERROR and sol.v is None and "shape" in sol.detail
    assert mpc.solve(np.array([1.0]), np.array([1.0, 1.0]), np.array([0.0])).status is SolveStatus.OPTIMAL


def test_iteration_limit_is_reported_without_arrays():
    mpc = CvxpyBackend(solver_options={"max_iter": 1}).tube_mpc(scalar_tube_data())
    sol = mpc.solve(np.array([2.0]), np.array([1.0, 1.0]), np.array([0.0]))
    assert sol.status is not SolveStatus.OPTIMAL and sol.v is None


def test_re_solving_the_same_problem_equals_a_fresh_build(be):
    data = scalar_tube_data(u_max=0.5)
    mpc = be.tube_mpc(data)
    problem = mpc.problem
    mpc.solve(np.array([-1.0]), np.array([1.0, 1.0]), np.array([0.5]))
    second = mpc.solve(np.array([2.5]), np.array([0.3, 0.6]), np.array([-0.2]))
    assert mpc.problem is problem  # parameters updated, no rebuild
    fresh = be.tube_mpc(data).solve(np.array([2.5]), np.array([0.3, 0.6]), np.array([-0.2]))
    np.testing.assert_allclose(second.v, fresh.v, atol=1e-7)
    assert second.cost == pytest.approx(fresh.cost, abs=1e-7)


def test_h_theta_of_same_rows_updates_and_more_rows_rebuilds(be):
    # |u| <= 0.5 makes the optimal v depend on Θ_k (the tube width α enters (15a))
    data = scalar_tube_data(u_max=0.5)
    x, theta_hat = np.array([2.0]), np.array([0.0])
    mpc = be.tube_mpc(data)
    wider = mpc.solve(x, np.array([1.0, 0.4]), theta_hat)  # Θ_k = [-0.4, 1]
    base = mpc.solve(x, np.array([0.5, 0.2]), theta_hat)   # Θ_k = [-0.2, 0.5]
    assert np.max(np.abs(wider.v - base.v)) > 1e-2  # so the comparisons below can fail
    problem = mpc.problem
    # the same set Θ_k = [-0.2, 0.5] written with scaled rows: parameter update, same optimum
    scaled = mpc.solve(x, np.array([1.0, 0.4]), theta_hat, H_theta=np.array([[2.0], [-2.0]]))
    assert mpc.problem is problem
    np.testing.assert_allclose(scaled.v, base.v, atol=1e-7)
    # plus a redundant row θ <= 3: rebuild with q = 3, same optimum
    H3 = np.array([[1.0], [-1.0], [1.0]])
    more = mpc.solve(x, np.array([0.5, 0.2, 3.0]), theta_hat, H_theta=H3)
    assert mpc.problem is not problem and mpc.problem.is_dpp()
    assert more.Lambda.shape == (data.N, 2, 2, 3)
    np.testing.assert_allclose(more.v, base.v, atol=1e-7)
    check_tube_solution(data, more, x, np.array([0.5, 0.2, 3.0]), H_theta=H3)



def test_a_rebuilt_problem_holds_more_rows_and_pads_fewer(be):
    """A new number of rows of H_θ (the exact update (7)) builds a problem holding the next multiple of
    ROW_CAPACITY_STEP rows; fewer rows are padded with 0·θ <= 1 and answered by the same problem, with
    the optimum of the unpadded program and Λ of the true q columns (checked by check_tube_solution);
    more rows than it holds build a new one. (Each new q used to build a new problem: 0.35-0.57 s of
    canonicalisation on campaign seed 13 #6, at most steps of (7).)"""
    from amcp_reference.tube_mpc import ROW_CAPACITY_STEP

    data = scalar_tube_data(u_max=0.5)
    x, theta_hat = np.array([2.0]), np.array([0.0])
    mpc = be.tube_mpc(data)
    base = mpc.solve(x, np.array([0.5, 0.2]), theta_hat)   # Θ_k = [-0.2, 0.5], the design's two rows
    wider = mpc.solve(x, np.array([1.0, 0.4]), theta_hat)
    assert np.max(np.abs(wider.v - base.v)) > 1e-2  # so the comparisons below can fail
    H3, h3 = np.array([[1.0], [-1.0], [1.0]]), np.array([0.5, 0.2, 3.0])
    mpc.solve(x, h3, theta_hat, H_theta=H3)          # 3 rows: a new problem, holding ROW_CAPACITY_STEP
    problem = mpc.problem
    for q in (2, 3, 5, ROW_CAPACITY_STEP):
        H = np.vstack([[[1.0], [-1.0]], np.ones((q - 2, 1))])
        h = np.concatenate([[0.5, 0.2], 3.0 + np.arange(q - 2)])  # redundant rows θ <= 3, 4, ...
        sol = mpc.solve(x, h, theta_hat, H_theta=H)
        assert mpc.problem is problem, q
        assert sol.status is SolveStatus.OPTIMAL and sol.Lambda.shape == (data.N, 2, 2, q)
        np.testing.assert_allclose(sol.v, base.v, atol=1e-7)
        check_tube_solution(data, sol, x, h, H_theta=H)
    H = np.vstack([[[1.0], [-1.0]], np.ones((ROW_CAPACITY_STEP - 1, 1))])
    h = np.concatenate([[0.5, 0.2], 3.0 + np.arange(ROW_CAPACITY_STEP - 1)])
    sol = mpc.solve(x, h, theta_hat, H_theta=H)        # one row more than it holds: a new problem
    assert mpc.problem is not problem and mpc.problem.is_dpp()
    np.testing.assert_allclose(sol.v, base.v, atol=1e-7)
    check_tube_solution(data, sol, x, h, H_theta=H)


# -- Example 1 and the Drake cross-check -----------------------------------------------------

def example_tube_data(problem, d):
    return TubeMPCData(A0=problem.A0, B0=problem.B0, A=problem.A, B=problem.B, F=problem.F, G=problem.G,
                       Q=problem.Q, R=problem.R, N=problem.N, K=d.K, P=d.P, H_x=d.H_x,
                       X0_vertices=d.X0_vertices, w_bar=d.w_bar, f_bar=d.f_bar, H_T=d.H_T, h_T=d.h_T,
                       H_theta=d.H_theta)


def test_example1_qp_is_dpp_feasible_and_its_solution_satisfies_15(be, example_spec, example_design):
    pr, d = example_spec.problem, example_design
    data = example_tube_data(pr, d)
    mpc = be.tube_mpc(data)
    assert mpc.problem.is_dpp()
    x = np.asarray(example_spec.scenario.x0, float)
    sol = mpc.solve(x, d.h_theta0, pr.theta_hat0)
    assert sol.status is SolveStatus.OPTIMAL
    nv, u, q = len(d.X0_vertices), len(d.H_x), len(d.H_theta)
    assert sol.Lambda.shape == (pr.N, nv, u, q)
    check_tube_solution(data, sol, x, d.h_theta0, tol=1e-6)
    assert sol.cost == pytest.approx(cost_17(data, x, pr.theta_hat0, sol.v), abs=1e-9)


DRAKE_MISSING = importlib.util.find_spec("amcp_drake.backends.drake_") is None or importlib.util.find_spec("pydrake") is None


@pytest.mark.skipif(DRAKE_MISSING, reason="amcp_drake.backends.drake_ (or pydrake) is not importable yet")
@pytest.mark.parametrize("case", ["loose", "tight"])
def test_cvxpy_and_drake_give_the_same_scalar_mpc_optimum(be, case):
    data = scalar_tube_data(u_max=10.0 if case == "loose" else 0.5)
    args = (np.array([2.0]), np.array([0.5, 0.2]), np.array([0.1]))
    sol_c = be.tube_mpc(data).solve(*args)
    sol_d = get_backend("drake").tube_mpc(data).solve(*args)
    assert sol_c.status is SolveStatus.OPTIMAL and sol_d.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(sol_c.v, sol_d.v, atol=CROSS_TOL)
    assert sol_c.cost == pytest.approx(sol_d.cost, abs=CROSS_TOL)


@pytest.mark.skipif(DRAKE_MISSING, reason="amcp_drake.backends.drake_ (or pydrake) is not importable yet")
def test_cvxpy_and_drake_agree_on_example1_over_three_states(be, example_spec, example_design):
    pr, d = example_spec.problem, example_design
    data = example_tube_data(pr, d)
    mpc_c, mpc_d = be.tube_mpc(data), get_backend("drake").tube_mpc(data)
    theta_hat = np.array([0.3, -0.2, 0.1])
    for x in ([2.0, 3.0], [0.5, -0.1], [-1.0, 1.0]):
        sol_c = mpc_c.solve(np.array(x), d.h_theta0, theta_hat)
        sol_d = mpc_d.solve(np.array(x), d.h_theta0, theta_hat)
        assert sol_c.status is SolveStatus.OPTIMAL and sol_d.status is SolveStatus.OPTIMAL
        np.testing.assert_allclose(sol_c.v, sol_d.v, atol=CROSS_TOL)
        assert sol_c.cost == pytest.approx(sol_d.cost, abs=CROSS_TOL)


@pytest.mark.skipif(DRAKE_MISSING, reason="amcp_drake.backends.drake_ (or pydrake) is not importable yet")
def test_cvxpy_per_row_lp_and_drake_matrix_lp_give_the_same_offsets(be):
    rng = np.random.default_rng(3)
    H_theta = np.vstack([np.eye(3), -np.eye(3)])
    h_prev = np.ones(6)
    H_data = rng.normal(size=(2, 3))
    h_data = H_data @ rng.uniform(-0.5, 0.5, 3) + 0.1
    res_c = be.set_update(H_theta, h_prev, H_data, h_data)
    res_d = get_backend("drake").set_update(H_theta, h_prev, H_data, h_data)
    np.testing.assert_allclose(res_c.h, res_d.h, atol=CROSS_TOL)


@pytest.mark.skipif(DRAKE_MISSING, reason="amcp_drake.backends.drake_ (or pydrake) is not importable yet")
@pytest.mark.parametrize("update", ["fixed", "exact"])
def test_closed_loop_in_lock_step_with_drake_on_example1(example_spec, example_design, update):
    """Both controllers see the same states (the Drake run's); (9)/(7), (12) and (20) must agree."""
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online.controller import AdaptiveMPC

    pr, d = example_spec.problem, example_design
    options = OnlineOptions(update=update)
    ctrl_c = AdaptiveMPC(pr, d, backend="cvxpy", options=options)
    ctrl_d = AdaptiveMPC(pr, d, backend="drake", options=options)
    rng = np.random.default_rng(0)
    theta_star = np.asarray(example_spec.scenario.theta_star, float)
    x = np.asarray(example_spec.scenario.x0, float)
    for _ in range(8):
        u_c, rec_c = ctrl_c.step(x)
        u_d, rec_d = ctrl_d.step(x)
        assert rec_c.status is SolveStatus.OPTIMAL and rec_d.status is SolveStatus.OPTIMAL
        np.testing.assert_allclose(rec_c.h_theta, rec_d.h_theta, atol=CROSS_TOL)
        np.testing.assert_allclose(rec_c.theta_hat, rec_d.theta_hat, atol=CROSS_TOL)
        np.testing.assert_allclose(rec_c.v, rec_d.v, atol=CROSS_TOL)
        np.testing.assert_allclose(u_c, u_d, atol=CROSS_TOL)
        x = pr.step(x, u_d, theta_star, rng.uniform(-0.1, 0.1, pr.n))


@pytest.mark.parametrize("formulation", ["vertex", "plain"])
def test_the_kept_clarabel_solver_answers_as_a_fresh_one(example_spec, example_design, formulation):
    """The tube QP keeps its Clarabel solver between steps (SolverCall keep_solver: cvxpy's
    warm_start passes the new data to Clarabel's update). Over a closed loop, v equals that of a
    controller whose solver is built anew at every step (keep_solver off) to 1e-9. The vertex form
    through ``Problem.solve`` (its compiled route off; that route's kept solver is tested in
    tests/test_compiled_clarabel.py)."""
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence

    pr, sc = example_spec.problem, example_spec.scenario
    route = {"compiled_qp": False} if formulation == "vertex" else {}
    kept = AdaptiveMPC(pr, example_design, backend="cvxpy", formulation=formulation, **route)
    fresh = AdaptiveMPC(pr, example_design, backend="cvxpy", formulation=formulation, **route)
    assert kept.mpc._call.keep_solver
    fresh.mpc._call.keep_solver = False
    w = disturbance_sequence(pr, "uniform", 12, seed=3)
    x = np.asarray(sc.x0, float)
    solvers = {"kept": [], "fresh": []}
    for k in range(12):
        u, r = kept.step(x)
        _, r_fresh = fresh.step(x)
        assert r.status is SolveStatus.OPTIMAL and r_fresh.status is SolveStatus.OPTIMAL
        assert np.max(np.abs(r.v - r_fresh.v)) <= 1e-9
        x = pr.step(x, u, sc.theta_star, w[k])
        solvers["kept"].append(kept.mpc.problem._solver_cache["CLARABEL"])
        solvers["fresh"].append(fresh.mpc.problem._solver_cache["CLARABEL"])
    assert all(s is solvers["kept"][1] for s in solvers["kept"][1:])          # one solver, updated
    assert all(a is not b for a, b in zip(solvers["fresh"], solvers["fresh"][1:]))  # a new one per step


def test_options_of_one_solve_do_not_stick_to_the_kept_clarabel_solver():
    """cvxpy's warm start applies a call's options on top of the kept solver's settings, so the
    options of one solve (a rung of the retry ladder, the first try without iterative refinement)
    used to stay in force for every later solve of the same problem: found on massera2017 (cvxpy,
    θ* = −1), where after one full retry ladder later steps ran with max_step_fraction 0.5, no
    equilibration and no refinement, and stalled "AlmostSolved" though a fresh solver solved them.
    Here a solve with max_iter = 1 (stops "inaccurate") must not limit the next solve."""
    import cvxpy as cp

    from amcp_reference.solver_call import SolverCall

    x = cp.Variable(3)
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x - np.array([1.0, -2.0, 0.5]))), [cp.sum(x) <= 0, x >= -1])
    call = SolverCall("CLARABEL", {}, keep_solver=True)
    assert call.solve(problem)[0] is SolveStatus.OPTIMAL
    assert call.solve(problem, {"max_iter": 1})[0] is SolveStatus.INACCURATE
    status, _, detail = call.solve(problem)
    assert status is SolveStatus.OPTIMAL, detail
    assert problem._solver_cache["CLARABEL"].get_settings().max_iter == 200  # Clarabel's default again
    # the projection of (1, -2, 0.5) onto {Σx <= 0, x >= -1} by hand (KKT): x2 = -1, x1 = 1 - λ,
    # x3 = 0.5 - λ, Σx = 0 gives λ = 0.25
    np.testing.assert_allclose(x.value, [0.75, -1.0, 0.25], atol=1e-7)


def test_a_kept_clarabel_solver_that_gave_no_answer_is_built_anew_for_the_next_solve():
    """A kept solver is updated with the new data but keeps the scaling and state of its first
    setup; found on massera2017 (cvxpy, θ* = −1, vertex disturbances, Θ_k 1e-6 wide): the kept
    solver updated from step 17 ended step 18 "AlmostSolved" under the whole retry ladder, while a
    solver built for step 18 solved it. So after a solve without an answer (inaccurate or a solver
    error) the next solve builds a new solver; after an answer the solver is kept."""
    import cvxpy as cp

    from amcp_reference.solver_call import SolverCall

    x = cp.Variable(3)
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x - np.array([1.0, -2.0, 0.5]))), [cp.sum(x) <= 0, x >= -1])
    call = SolverCall("CLARABEL", {}, keep_solver=True)
    assert call.solve(problem)[0] is SolveStatus.OPTIMAL
    first = problem._solver_cache["CLARABEL"]
    assert call.solve(problem)[0] is SolveStatus.OPTIMAL
    assert problem._solver_cache["CLARABEL"] is first                      # an answer: kept
    assert call.solve(problem, {"max_iter": 1})[0] is SolveStatus.INACCURATE
    assert problem._solver_cache["CLARABEL"] is first                      # updated, not rebuilt
    assert call.solve(problem)[0] is SolveStatus.OPTIMAL
    rebuilt = problem._solver_cache["CLARABEL"]
    assert rebuilt is not first                                            # no answer: built anew
    assert call.solve(problem)[0] is SolveStatus.OPTIMAL
    assert problem._solver_cache["CLARABEL"] is rebuilt                    # and kept again


def test_offset_split_is_the_least_squares_point_and_its_residual():
    """h = H_θ κ + s with s orthogonal to the columns of H_θ; for the slab [−1, −1 + w] (H_θ = [1; −1])
    κ is the mid-plane −1 + w/2 and s = (w/2, w/2) (by hand), per stage row."""
    from amcp_reference.tube_mpc import offset_split

    w = 1e-6
    H = np.array([[1.0], [-1.0]])
    h = np.array([[-1.0 + w, 1.0], [0.5, 0.5]])
    kappa, s = offset_split(H, h)
    np.testing.assert_allclose(kappa, [[-1.0 + w / 2], [0.0]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(s, [[w / 2, w / 2], [0.5, 0.5]], rtol=0, atol=1e-15)
    rng = np.random.default_rng(3)
    H, h = rng.normal(size=(7, 3)), rng.normal(size=(4, 7))
    kappa, s = offset_split(H, h)
    np.testing.assert_allclose(kappa @ H.T + s, h, atol=1e-12)
    np.testing.assert_allclose(s @ H, 0.0, atol=1e-12)


@pytest.fixture(scope="module")
def massera2017_cvxpy():
    """massera2017 (the built-in example) and its design on the cvxpy backend."""
    from amcp_drake.model.examples import get_example
    from amcp_drake.offline.design import design

    spec = get_example("massera2017")
    return spec, design(spec.problem, spec.design, backend="cvxpy")


#: (x_k, θ̂_k) at steps of massera2017 with θ* = −1 and vertex disturbances (seed 0 steps 24 and 29,
#: seed 2 steps 28 and 36) where Θ_k = [−1, −1 + 1e-6]; recorded with an earlier design of massera2017.
MASSERA_THIN_STEPS = [
    ([0.18585618017650496, 0.2936495867467874, -0.03536531471134703], [-0.19919544911107998]),
    ([-0.12651280990886932, -0.18886391313985462, 0.1110682270409442], [-0.23045744732494922]),
    ([0.11186461464968366, 0.2591430236598355, -0.11847232688511873], [-0.2690583459858816]),
    ([0.19694985530700815, 0.38784374406530514, 0.020248258963603438], [-0.3212010174320591]),
]


@pytest.mark.parametrize("x, theta_hat", MASSERA_THIN_STEPS)
def test_massera2017_plain_form_on_a_theta_k_1e_6_wide_is_solved_without_fallback(massera2017_cvxpy, x, theta_hat):
    """massera2017, θ* = −1, vertex disturbances: Θ_k = [−1, −1 + 1e-6]. With (15c) written as Λ h_θk,
    its multiplier coefficients (−1 + 1e-6, 1) nearly equal −1 times those of (15d), (1, −1), and
    Clarabel ended "AlmostSolved" under the whole retry ladder at each of these steps (gap 1.06e-8 at
    the first one measured), so the step was answered by the vertex-form fallback. Written as
    c κ + Λ s (tube_mpc.offset_split), the plain form solves them; the cost is the Drake vertex
    form's (another program, another backend)."""
    from amcp_drake.online import answer_checks
    from amcp_drake.online.controller import AdaptiveMPC

    spec, offline = massera2017_cvxpy
    ctrl = AdaptiveMPC(spec.problem, offline, backend="cvxpy", formulation="plain")
    x, theta_hat = np.array(x), np.array(theta_hat)
    h_theta = np.array([-0.9999990000000002, 0.9999999999994115])
    sol = ctrl.mpc.solve(x, h_theta, theta_hat)
    assert sol.status is SolveStatus.OPTIMAL, sol.detail
    fresh = get_backend("drake", formulation="vertex").tube_mpc(ctrl.data).solve(x, h_theta, theta_hat)
    assert fresh.status is SolveStatus.OPTIMAL
    assert abs(sol.cost - fresh.cost) <= 1e-6 and np.max(np.abs(sol.v - fresh.v)) <= 1e-5
    # and the controller's answer checks ((15c) with Λ h_θk itself, (15d), Λ >= 0, (5b)) pass on it
    assert not answer_checks.failures(ctrl._tube_checks(sol, x, h_theta, None))


def _recorded_tube_step(name: str):
    """(TubeMPCData, x_k, θ̂_k, h_θk) of a tube QP recorded in tests/data (the design's data included, so
    the step does not move when the offline design does)."""
    import json
    from pathlib import Path

    step = json.loads((Path(__file__).parent / "data" / name).read_text())
    fields = {k: (v if k in ("N", "cost") else np.asarray(v, float)) for k, v in step["tube_data"].items()}
    return (TubeMPCData(**fields), np.asarray(step["x"], float), np.asarray(step["theta_hat"], float),
            np.asarray(step["h_theta"], float))


def test_massera2017_plain_form_on_a_theta_k_1e_4_wide_is_answered_and_verified():
    """massera2017, θ* = −1, vertex disturbances, seed 2 step 4 with Θ_k = [−1, −0.9999]
    (benchmarks/massera_plain_qps.py): with Clarabel's QDLDL factorisation the plain form ended
    "AlmostSolved" under the whole retry ladder (gap stalled at 4.1e-8, μ 1.6e-10, the step length
    collapsing to 0: iterative refinement could not repair the KKT solves). With faer's LDLᵀ
    (tube_mpc.PLAIN_FORM_CLARABEL_OPTIONS) it is "Solved"; the answer passes the controller's answer
    checks ((15a)-(15d), Λ >= 0, (5b) at Θ_k's two vertices) and its plan is the Drake vertex form's
    (another program, another backend)."""
    from amcp_drake.online.answer_checks import TubeCheck, failures

    data, x, theta_hat, h_theta = _recorded_tube_step("massera2017-plain-stall-step.json")
    sol = get_backend("cvxpy", formulation="plain").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert sol.status is SolveStatus.OPTIMAL, sol.detail
    vertices = np.array([[-1.0], [-0.9999]])                 # Θ_k = [−1, −0.9999], by hand
    assert not failures(TubeCheck(data).check(sol, x, vertices, h_theta, None))
    other = get_backend("drake", formulation="vertex").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert other.status is SolveStatus.OPTIMAL
    assert abs(sol.cost - other.cost) <= 1e-6 and np.max(np.abs(sol.v - other.v)) <= 1e-5


def _mass_chain3_stall():
    """(TubeMPCData, x_k, θ̂_k, h_θk, vertices of Θ_k) of mass_chain3's step 3 (tests/data/mass-chain3-plain-stall-step.json)."""
    data, x, theta_hat, h_theta = _recorded_tube_step("mass-chain3-plain-stall-step.json")
    lo1, hi1, lo2, hi2 = -h_theta[2], h_theta[0], -h_theta[3], h_theta[1]      # H_θ = [I; −I], by hand
    np.testing.assert_array_equal(data.H_theta, [[1, 0], [0, 1], [-1, 0], [0, -1]])
    vertices = np.array([[lo1, lo2], [hi1, lo2], [lo1, hi2], [hi1, hi2]])
    return data, x, theta_hat, h_theta, vertices


def test_mass_chain3_plain_form_stall_is_answered_with_the_tie_break_and_verified():
    """mass_chain3 (n = 6, a 64-vertex X0: 30 989 variables), step 3, Θ_k 0.02 x 0.009: the plain form ended
    "AlmostSolved" under the whole retry ladder (the optimal (z, α, Λ) of the cost (17), which depends on v only,
    is a face on which Λ is unbounded in the free directions of (15d)). With the tie-break ε·Σα the step is
    answered by the plain form itself: the answer passes the controller's checks ((15a)-(15d), Λ >= 0, (5b) at
    Θ_k's four vertices) and its plan is the Drake vertex form's (another program, another backend)."""
    from amcp_drake.online.answer_checks import TubeCheck, failures

    data, x, theta_hat, h_theta, vertices = _mass_chain3_stall()
    sol = get_backend("cvxpy", formulation="plain").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert sol.status is SolveStatus.OPTIMAL, sol.detail
    assert sol.Lambda is not None
    assert not failures(TubeCheck(data).check(sol, x, vertices, h_theta, None))
    other = get_backend("drake", formulation="vertex").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert other.status is SolveStatus.OPTIMAL
    assert abs(sol.cost - other.cost) <= 1e-7 and np.max(np.abs(sol.v - other.v)) <= 1e-6


def _ladder_exhausted(monkeypatch):
    """The retry ladder of the plain form replaced by a fake that ends without an answer (status INACCURATE,
    as after every rung on the machine where the step was recorded): the step always goes on to the
    tie-break solve, whatever this machine's Clarabel does at the first tries."""
    from amcp_reference.tube_mpc import CvxpyTubeMPC

    monkeypatch.setattr(CvxpyTubeMPC, "_solve", lambda self, problem, refine=False: (SolveStatus.INACCURATE, 0.0, "fake", ()))


def test_a_tie_broken_answer_that_moves_the_optimum_is_rejected(monkeypatch):
    """Tampered: a tie-break weight of 0.1 moves the plan (its cost (17) far above the vertex form's optimum:
    shown first with the optimality check switched off); with the check the tampered plan is never returned:
    the step is either answered with the vertex form's plan (another program, another backend) or
    "inaccurate" with no answer (the controller then answers it by the other formulation, checked)."""
    import amcp_reference.tube_mpc as tube_mpc

    monkeypatch.setattr(tube_mpc, "TIE_BREAK_WEIGHT", 0.1)
    _ladder_exhausted(monkeypatch)
    data, x, theta_hat, h_theta, _ = _mass_chain3_stall()
    other = get_backend("drake", formulation="vertex").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert other.status is SolveStatus.OPTIMAL
    with monkeypatch.context() as unchecked:       # the tamper is real: unchecked, its plan is off the optimum
        unchecked.setattr(tube_mpc.CvxpyTubeMPC, "_checked_optimal", lambda self, sol, *args: sol)
        moved = get_backend("cvxpy", formulation="plain").tube_mpc(data).solve(x, h_theta, theta_hat)
        assert moved.status is SolveStatus.OPTIMAL and moved.cost - other.cost > 1e-5
    sol = get_backend("cvxpy", formulation="plain").tube_mpc(data).solve(x, h_theta, theta_hat)
    if sol.status is SolveStatus.OPTIMAL:
        assert abs(sol.cost - other.cost) <= 1e-7 and np.max(np.abs(sol.v - other.v)) <= 1e-6
    else:
        assert sol.status is SolveStatus.INACCURATE and sol.v is None


def test_the_tie_break_answers_a_step_the_ladder_left_unanswered(monkeypatch):
    """With the ladder's answer taken away (a fake), the tie-break ε·Σα answers mass_chain3's step 3 by the
    plain form itself: optimal, the controller's checks pass, and the plan is the Drake vertex form's."""
    from amcp_drake.online.answer_checks import TubeCheck, failures

    _ladder_exhausted(monkeypatch)
    data, x, theta_hat, h_theta, vertices = _mass_chain3_stall()
    sol = get_backend("cvxpy", formulation="plain").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert sol.status is SolveStatus.OPTIMAL and sol.Lambda is not None
    assert not failures(TubeCheck(data).check(sol, x, vertices, h_theta, None))
    other = get_backend("drake", formulation="vertex").tube_mpc(data).solve(x, h_theta, theta_hat)
    assert abs(sol.cost - other.cost) <= 1e-7 and np.max(np.abs(sol.v - other.v)) <= 1e-6


# -- the plain form's answer checked against the vertex form's optimum ---------------------------------------

def _suboptimal_step():
    """Step 8 of the recorded run (a generated case; tests/data/lockstep-plain-suboptimal: n = 1,
    p = 2, exact update (7), Θ_k a slab 1.3e-6 wide, x_8 = −0.023, cost 7.5e-4)."""
    from pathlib import Path

    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.simulate import Trajectory

    folder = Path(__file__).parent / "data" / "lockstep-plain-suboptimal"
    spec, traj = load_spec(folder / "problem.json"), Trajectory.load(folder / "trajectory.json.gz")
    return spec, traj, traj.records[8], np.asarray(traj.x[8], float)


def _plain(spec, traj, backend, options):
    from amcp_drake.online.controller import AdaptiveMPC

    return AdaptiveMPC(spec.problem, traj.design, backend=backend, formulation="plain", options=traj.options,
                       solver_options=options).mpc


ACCURATE_10 = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}


def test_a_suboptimal_plain_answer_is_caught_by_the_vertex_forms_optimum_and_solved_again():
    """At 1e-10 Clarabel ended "Solved" on cvxpy's plain form with a cost 8.2e-9 above the optimum and v
    1.3e-4 off (the Drake plain form at 1e-12, the reference here, and the lockstep property's leader);
    the answer is now checked against the vertex form's optimum and solved again at tol_feas 1e-12."""
    spec, traj, rec, x = _suboptimal_step()
    reference = _plain(spec, traj, "drake", {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12}).solve(
        x, rec.h_theta, rec.theta_hat, rec.H_theta)
    sol = _plain(spec, traj, "cvxpy", ACCURATE_10).solve(x, rec.h_theta, rec.theta_hat, rec.H_theta)
    assert sol.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(sol.v, reference.v, rtol=0, atol=1e-8)
    assert sol.Lambda is not None and sol.Lambda.shape[-1] == rec.H_theta.shape[0]


def test_a_plain_answer_that_stays_suboptimal_is_never_optimal(monkeypatch):
    """Tampered: the re-solve at the same feasibility tolerance (factor 1) gives the same answer again. A step
    is then either answered with the reference's plan (the first answer was already optimal on this machine)
    or "inaccurate" with no answer (the controller answers it by the other formulation, checked), never a
    suboptimal "optimal": the v of an optimal answer equals the Drake plain form's at 1e-12 to 1e-8."""
    import amcp_reference.tube_mpc as tube_mpc

    monkeypatch.setattr(tube_mpc, "TIGHTER_FEASIBILITY", 1.0)
    spec, traj, rec, x = _suboptimal_step()
    reference = _plain(spec, traj, "drake", {"tol_gap_abs": 1e-12, "tol_gap_rel": 1e-12, "tol_feas": 1e-12}).solve(
        x, rec.h_theta, rec.theta_hat, rec.H_theta)
    sol = _plain(spec, traj, "cvxpy", ACCURATE_10).solve(x, rec.h_theta, rec.theta_hat, rec.H_theta)
    if sol.status is SolveStatus.OPTIMAL:
        np.testing.assert_allclose(sol.v, reference.v, rtol=0, atol=1e-8)
    else:
        assert sol.status is SolveStatus.INACCURATE and sol.v is None
