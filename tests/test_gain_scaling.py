"""The gain LMI (16) does not depend on the units of x and u (amcp_drake/backends/gain_scaling.py,
docs/decisions.md "Gain LMI (16) on badly scaled systems").

Expected values are invariances (a change of units x' = D x maps K to K D⁻¹ and P to D⁻ᵀ P D⁻¹, and
the whole design of a uniformly rescaled problem to the rescaled design) and (16) itself, re-checked
here with numpy; none comes from the code under test. Before the scaling, Example 1 with x in units
1e3 smaller was "infeasible" (S ⪰ 1e-6 I is then as large as S), and the two-mass spring below ended
"optimal_inaccurate" in the cvxpy backend and with a numerical error (R x 100) in the Drake backend.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.backends import available_backends, get_backend
from amcp_drake.model.problem import Problem
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design
from tests.guards import GUARD_SECONDS

BACKENDS = [b for b in ("drake", "cvxpy") if b in available_backends()]


def _rescaled(problem: Problem, D: np.ndarray) -> Problem:
    """The same problem in the state x' = D x (cost, W and Z carried along)."""
    Di = np.linalg.inv(D)
    return problem.with_changes(A0=D @ problem.A0 @ Di, B0=D @ problem.B0,
                                A=np.array([D @ a @ Di for a in problem.A]), B=np.array([D @ b for b in problem.B]),
                                H_w=problem.H_w @ Di, F=problem.F @ Di, Q=Di.T @ problem.Q @ Di)


def _vertex_data(problem: Problem):
    theta = problem.theta_vertices()
    return np.array([problem.A_of(t) for t in theta]), np.array([problem.B_of(t) for t in theta])


def _worst_16(A_v, B_v, Q, R, K, P) -> float:
    """Largest eigenvalue of A_clᵀ P A_cl + Q + KᵀRK − P over the vertices, relative to ‖P‖ (numpy)."""
    worst = max(float(np.max(np.linalg.eigvalsh((A + B @ K).T @ P @ (A + B @ K) + Q + K.T @ R @ K - P)))
                for A, B in zip(A_v, B_v))
    return worst / np.linalg.norm(P, 2)


def two_mass_spring(k_min: float = 0.5, k_max: float = 10.0, dt: float = 0.1) -> Problem:
    """Euler-discretised two-mass spring (Kothare, Balakrishnan & Morari 1996, Example 2): m1 = m2 = 1,
    spring constant θ = k ∈ [k_min, k_max], force on mass 1; x = [x1, x2, x1', x2']."""
    A0 = np.eye(4) + dt * np.array([[0, 0, 1, 0], [0, 0, 0, 1], [0, 0, 0, 0], [0, 0, 0, 0.]])
    A1 = dt * np.array([[0, 0, 0, 0], [0, 0, 0, 0], [-1, 1, 0, 0], [1, -1, 0, 0.]])
    B0 = np.array([[0], [0], [dt], [0.]])
    F = np.vstack([np.eye(4) / 2, -np.eye(4) / 2, np.zeros((2, 4))])
    G = np.vstack([np.zeros((8, 1)), [[1.0]], [[-1.0]]])
    return Problem(A0=A0, B0=B0, A=A1[None], B=np.zeros((1, 4, 1)), H_w=np.vstack([np.eye(4), -np.eye(4)]) / 1e-3,
                   H_theta=np.array([[1.0], [-1.0]]), h_theta=np.array([k_max, -k_min]), F=F, G=G, Q=np.eye(4),
                   R=np.eye(1), N=10, theta_hat0=np.array([0.5 * (k_min + k_max)]), name="two_mass_spring")


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("c", [1e-3, 1e3])
def test_example_1_in_other_units_designs_to_the_same_design(example_spec, example_design, backend, c):
    # x' = c x for every state: K' = K / c, P' = P / c², X0, X_f scale with c, λ̄ and μ·c² unchanged
    problem = _rescaled(example_spec.problem, c * np.eye(example_spec.problem.n))
    options = replace(example_spec.design, mu_state_bound=example_spec.design.mu_state_bound * c)
    d = design(problem, options, backend=backend)
    reference = example_design if backend == "drake" else design(example_spec.problem, example_spec.design, backend)
    scale_K = np.linalg.norm(reference.K)
    np.testing.assert_allclose(d.K * c, reference.K, rtol=0, atol=1e-5 * scale_K)
    np.testing.assert_allclose(d.P * c * c, reference.P, rtol=0, atol=1e-5 * np.linalg.norm(reference.P, 2))
    assert d.info["x0_template"] == reference.info["x0_template"]
    assert len(d.H_x) == len(reference.H_x) and len(d.H_T) == len(reference.H_T)
    assert d.lambda_bar == pytest.approx(reference.lambda_bar, abs=1e-6)
    assert not [c.name for c in verify_design(problem, d, options.mu_state_bound) if not c.passed]


@pytest.mark.parametrize("backend", BACKENDS)
def test_gain_lmi_is_covariant_under_a_change_of_units_of_x_and_u(example_spec, backend):
    # x' = c x, u' = c_u u: K' = c_u K / c, P' = P / c² (the objective trace(P⁻¹) only scales by c², so
    # its maximiser is the same; for a non-uniform D it is another objective, see the next test)
    problem = example_spec.problem
    be = get_backend(backend)
    A_v, B_v = _vertex_data(problem)
    base = be.robust_gain(A_v, B_v, problem.Q, problem.R, 1e-6)
    c, c_u = 1e-3, 1e2
    scaled = be.robust_gain(A_v, B_v * c / c_u, problem.Q / c**2, problem.R / c_u**2, 1e-6)
    assert base.status is SolveStatus.OPTIMAL and scaled.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(scaled.K * c / c_u, base.K, rtol=0, atol=1e-5 * np.linalg.norm(base.K))
    np.testing.assert_allclose(scaled.P * c**2, base.P, rtol=0, atol=1e-5 * np.linalg.norm(base.P, 2))


@pytest.mark.parametrize("backend", BACKENDS)
def test_gain_lmi_of_a_badly_scaled_system_is_optimal_and_satisfies_16(example_spec, backend):
    # x' = D x with D = diag(1e3, 1e-3): P' = D⁻ᵀ P D⁻¹ has entries from 1e-6 to 1e6
    problem = example_spec.problem
    A_v, B_v = _vertex_data(problem)
    D = np.diag([1e3, 1e-3])
    Di = np.linalg.inv(D)
    A_s, B_s, Q_s = np.array([D @ A @ Di for A in A_v]), np.array([D @ B for B in B_v]), Di.T @ problem.Q @ Di
    gain = get_backend(backend).robust_gain(A_s, B_s, Q_s, problem.R, 1e-6)
    assert gain.status is SolveStatus.OPTIMAL
    assert _worst_16(A_s, B_s, Q_s, problem.R, gain.K, gain.P) < 0.0


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("r_scale", [1.0, 10.0])
def test_two_mass_spring_gain_lmi_is_optimal_and_satisfies_16(backend, r_scale):
    # the robust P of this system is ~30x the vertex Riccati solutions (eigenvalues 22 .. 6.6e4 at R);
    # before the scaling cvxpy ended "optimal_inaccurate" at R x 1 and R x 10, Drake at R x 10
    problem = two_mass_spring()
    A_v, B_v = _vertex_data(problem)
    R = r_scale * problem.R
    gain = get_backend(backend).robust_gain(A_v, B_v, problem.Q, R, 1e-6)
    assert gain.status is SolveStatus.OPTIMAL
    assert _worst_16(A_v, B_v, problem.Q, R, gain.K, gain.P) < 0.0
    assert max(np.max(np.abs(np.linalg.eigvals(A + B @ gain.K)))for A, B in zip(A_v, B_v)) < 1.0


def test_design_check_of_16_is_relative_to_the_size_of_p(example_spec):
    # Example 1 in x units 1e3 larger: ‖P‖ = 1.8e-6. A P lowered by 0.05 % violates (16) by about
    # 5e-10, i.e. 3e-4 of ‖P‖: the former absolute round-off allowance 1e-9 let it pass
    from amcp_drake.offline.checks import verify_design

    c = 1e3
    problem = _rescaled(example_spec.problem, c * np.eye(example_spec.problem.n))
    options = replace(example_spec.design, mu_state_bound=example_spec.design.mu_state_bound * c)
    d = design(problem, options, backend="drake")
    tampered = replace(d, P=d.P * (1.0 - 5e-4))
    A_v, B_v = _vertex_data(problem)
    violation = _worst_16(A_v, B_v, problem.Q, problem.R, tampered.K, tampered.P) * np.linalg.norm(tampered.P, 2)
    assert 0.0 < violation < 1e-9 and violation / np.linalg.norm(d.P, 2) > 1e-5
    by_name = {c.name: c for c in verify_design(problem, tampered, options.mu_state_bound)}
    assert not by_name["terminal cost (16)"].passed
    assert {c.name: c for c in verify_design(problem, d, options.mu_state_bound)}["terminal cost (16)"].passed


# -- the shared driver gain_scaling.solve_scaled, with a stub solver (scalar system, P by Riccati) -----

def _scalar_lqr():
    import scipy.linalg as sla

    A, B, Q, R = np.array([[[0.5]]]), np.array([[[1.0]]]), np.eye(1), np.eye(1)
    P = sla.solve_discrete_are(A[0], B[0], Q, R)
    K = -np.linalg.solve(R + B[0].T @ P @ B[0], B[0].T @ P @ A[0])
    return A, B, Q, R, K, P


def test_an_inaccurate_answer_is_solved_again_in_its_own_coordinates():
    from amcp_drake.backends.gain_scaling import solve_scaled

    A, B, Q, R, K, P = _scalar_lqr()
    P_inaccurate = 3.0 * P
    scales = []

    def stub(A_t, B_t, Q_t, R_t, weight, options):
        T = np.sqrt(Q_t)  # Q = 1, so Q̃ = TᵀQT = T²; U = R^{-1/2} = 1, so K̃ = K T and P̃ = T P T
        scales.append(float(T[0, 0]))
        answer = P_inaccurate if len(scales) == 1 else P
        return (SolveStatus.INACCURATE if len(scales) == 1 else SolveStatus.OPTIMAL), K @ T, T @ answer @ T

    gain = solve_scaled(stub, A, B, Q, R)
    assert gain.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(gain.K, K, rtol=1e-12)
    np.testing.assert_allclose(gain.P, P, rtol=1e-12)
    assert len(scales) == 2
    assert scales[0] ** 2 * P[0, 0] == pytest.approx(1.0)              # first: the Riccati solution is I
    assert scales[1] ** 2 * P_inaccurate[0, 0] == pytest.approx(1.0)   # then: the inaccurate answer's P is I


def test_an_optimal_answer_that_violates_16_is_not_returned():
    from amcp_drake.backends.gain_scaling import solve_scaled

    A, B, Q, R, K, P = _scalar_lqr()
    calls = []

    def stub(A_t, B_t, Q_t, R_t, weight, options):
        calls.append(1)
        T = np.sqrt(Q_t)
        return SolveStatus.OPTIMAL, K @ T, T @ (0.5 * P) @ T  # half the cost-to-go: (16) fails by O(‖P‖)

    gain = solve_scaled(stub, A, B, Q, R)
    assert gain.status is SolveStatus.INACCURATE and gain.K is None and gain.P is None
    assert len(calls) == 3  # scaled, in the answer's coordinates, as written


def test_an_infeasible_lmi_is_reported_without_a_second_solve():
    from amcp_drake.backends.gain_scaling import solve_scaled

    A, B, Q, R, _, _ = _scalar_lqr()
    calls = []

    def stub(*args):
        calls.append(1)
        return SolveStatus.INFEASIBLE, None, None

    assert solve_scaled(stub, A, B, Q, R).status is SolveStatus.INFEASIBLE
    assert len(calls) == 1


def test_the_lmi_as_written_is_the_last_resort():
    from amcp_drake.backends.gain_scaling import solve_scaled

    A, B, Q, R, K, P = _scalar_lqr()
    seen = []

    def stub(A_t, B_t, Q_t, R_t, weight, options):
        seen.append(float(Q_t[0, 0]))
        if not np.allclose(Q_t, Q):  # any scaled formulation: the solver gives up without an answer
            return SolveStatus.ERROR, None, None
        return SolveStatus.OPTIMAL, K, P

    gain = solve_scaled(stub, A, B, Q, R)
    assert gain.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(gain.K, K, rtol=1e-12)
    assert len(seen) == 2 and seen[-1] == 1.0


@pytest.mark.parametrize("backend", BACKENDS)
def test_generated_problem_the_scaled_lmi_leaves_almost_solved_is_solved(backend):
    # tests/data/gain-lmi-almost-solved.json: Clarabel (cvxpy) ended AlmostSolved on both scaled
    # formulations with P̃ ≈ I; before the last-resort formulation the design rejected this problem
    import json
    from pathlib import Path

    data = json.loads((Path(__file__).parent / "data" / "gain-lmi-almost-solved.json").read_text())
    A_v, B_v = np.array(data["A_vertices"]), np.array(data["B_vertices"])
    Q, R = np.array(data["Q"]), np.array(data["R"])
    gain = get_backend(backend).robust_gain(A_v, B_v, Q, R, 1e-6)
    assert gain.status is SolveStatus.OPTIMAL
    assert _worst_16(A_v, B_v, Q, R, gain.K, gain.P) < 0.0


# -- the first try at tight tolerances (gain_scaling.GAIN_TIGHT) ----------------------------------------

@pytest.mark.parametrize("first_status", [SolveStatus.INACCURATE, SolveStatus.ERROR, SolveStatus.INFEASIBLE])
def test_a_first_try_without_an_answer_is_decided_at_the_backends_options(first_status):
    """Any status of the tight first try but an accepted "optimal" (an "infeasible" at 1e-10 too) is
    decided again at the backend's own options, in the same scaling."""
    from amcp_drake.backends.gain_scaling import GAIN_TIGHT, GAIN_TIGHT_RETRIES, solve_scaled

    A, B, Q, R, K, P = _scalar_lqr()
    seen = []

    def stub(A_t, B_t, Q_t, R_t, weight, options):
        seen.append((float(Q_t[0, 0]), options))
        T = np.sqrt(Q_t)
        if options:
            return first_status, None, None
        return SolveStatus.OPTIMAL, K @ T, T @ P @ T

    gain = solve_scaled(stub, A, B, Q, R, first=GAIN_TIGHT)
    assert gain.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(gain.K, K, rtol=1e-12)
    # a stalled ("inaccurate") first try is tried again with less regularisation before the defaults
    retries = [{**GAIN_TIGHT, **rung} for rung in GAIN_TIGHT_RETRIES] if first_status is SolveStatus.INACCURATE else []
    assert [o for _, o in seen] == [GAIN_TIGHT, *retries, None]
    assert len({q for q, _ in seen}) == 1  # the same scaling: the re-solves are at other settings, not in other units


def test_a_stalled_first_try_solved_with_less_regularisation_is_the_answer():
    """Example 1 in x' = 1e3 x (Drake, AMD EPYC): the first try stalled where Example 1's own was
    solved; the same tolerances with static regularisation 1e-10 solved it, 1e-10 from Example 1's K,
    where the backend's defaults had given a K 3.3e-5 away."""
    from amcp_drake.backends.gain_scaling import GAIN_TIGHT, GAIN_TIGHT_RETRIES, solve_scaled

    A, B, Q, R, K, P = _scalar_lqr()
    seen = []

    def stub(A_t, B_t, Q_t, R_t, weight, options):
        seen.append(options)
        T = np.sqrt(Q_t)
        if options and "static_regularization_constant" in options:
            return SolveStatus.OPTIMAL, K @ T, T @ P @ T
        if options:
            return SolveStatus.INACCURATE, K @ T, T @ P @ T
        return SolveStatus.OPTIMAL, 1.01 * K @ T, T @ P @ T  # the defaults' answer: elsewhere on the flat optimum

    gain = solve_scaled(stub, A, B, Q, R, first=GAIN_TIGHT)
    assert gain.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(gain.K, K, rtol=1e-12)
    assert seen == [GAIN_TIGHT, {**GAIN_TIGHT, **GAIN_TIGHT_RETRIES[0]}]


def test_an_accepted_first_try_is_the_answer():
    from amcp_drake.backends.gain_scaling import GAIN_TIGHT, solve_scaled

    A, B, Q, R, K, P = _scalar_lqr()
    seen = []

    def stub(A_t, B_t, Q_t, R_t, weight, options):
        seen.append(options)
        T = np.sqrt(Q_t)
        return SolveStatus.OPTIMAL, K @ T, T @ (P if options else 0.5 * P) @ T  # the default answer violates (16)

    gain = solve_scaled(stub, A, B, Q, R, first=GAIN_TIGHT)
    assert gain.status is SolveStatus.OPTIMAL and seen == [GAIN_TIGHT]
    np.testing.assert_allclose(gain.P, P, rtol=1e-12)


def test_the_users_solver_options_override_the_tight_first_try():
    from amcp_drake.backends.gain_scaling import GAIN_TIGHT, tight_first

    assert tight_first(True, {}) == GAIN_TIGHT
    assert tight_first(True, {"tol_gap_rel": 1e-6}) == {"tol_gap_abs": 1e-10, "tol_feas": 1e-10}
    assert tight_first(True, dict.fromkeys(GAIN_TIGHT, 1e-7)) is None
    assert tight_first(False, {}) is None  # the settings are Clarabel's


@pytest.mark.parametrize("backend", BACKENDS)
def test_both_backends_try_the_gain_lmi_at_tight_tolerances_first(backend, monkeypatch):
    import amcp_drake.backends.gain_scaling as gs

    firsts = []
    original = gs.solve_scaled

    def spy(solve, *args, first=None):
        firsts.append(first)
        return original(solve, *args, first=first)

    monkeypatch.setattr(gs, "solve_scaled", spy)
    if backend == "drake":
        monkeypatch.setattr("amcp_drake.backends.drake_.solve_scaled", spy)
    else:
        monkeypatch.setattr("amcp_reference.offline.solve_scaled", spy)
    A, B, Q, R, _, _ = _scalar_lqr()
    assert get_backend(backend).robust_gain(A, B, Q, R, 1e-6).status is SolveStatus.OPTIMAL
    assert firsts == [gs.GAIN_TIGHT]


# -- generated problems the cvxpy form left inaccurate (tests/data/gain-lmi-generated-twins.json) -----------

def _generated(name: str):
    import json
    from pathlib import Path

    data = json.loads((Path(__file__).parent / "data" / "gain-lmi-generated-twins.json").read_text())
    entry = data[name]
    return (np.array(entry["A_vertices"]), np.array(entry["B_vertices"]), np.array(entry["Q"]), np.array(entry["R"]),
            float(entry["margin"]))


@pytest.mark.parametrize("backend", BACKENDS)
def test_generated_problem_whose_lmi_ended_inaccurate_on_every_rung_is_solved(backend):
    """Draw 12 of seed 0 (normalised units): the cvxpy backend's LMI, posed with affine PSD cones that
    Clarabel split by chordal decomposition, ended optimal_inaccurate on every rung, so the design
    rejected a problem the Drake backend designs; posed as Drake poses it, it is solved."""
    A_v, B_v, Q, R, margin = _generated("draw_12")
    gain = get_backend(backend).robust_gain(A_v, B_v, Q, R, margin)
    assert gain.status is SolveStatus.OPTIMAL
    assert _worst_16(A_v, B_v, Q, R, gain.K, gain.P) < 0.0


#: Relative agreement of the gains of two problems that differ by a common factor of the state (x' = c x).
#: Posed alike, both are solved by the same Clarabel iterates up to rounding (measured 6e-10 cvxpy, 1.5e-9
#: Drake); the optimum of trace(S) is flat in K, so answers taken on different iterations or rungs differ
#: by ~√(relative gap): the cvxpy K's were 3.5e-4 apart on these twins (decisions, "The cvxpy gain LMI in
#: Drake's form").
TWIN_K_RTOL = 1e-6


@pytest.mark.parametrize("backend", BACKENDS)
def test_generated_twins_differing_by_a_common_factor_get_the_same_gain(backend):
    A_s, B_s, Q_s, R_s, margin = _generated("draw_76_scaled")
    A_t, B_t, Q_t, R_t, _ = _generated("draw_76_twin")
    c = 40.0 / 9.0  # the data are the same system in states ξ_scaled = c ξ_twin:
    np.testing.assert_allclose(A_s, A_t, atol=1e-14)
    np.testing.assert_allclose(B_s, c * B_t, rtol=1e-14)
    np.testing.assert_allclose(Q_s, Q_t / c**2, rtol=1e-14)
    np.testing.assert_array_equal(R_s, R_t)
    be = get_backend(backend)
    scaled = be.robust_gain(A_s, B_s, Q_s, R_s, margin)
    twin = be.robust_gain(A_t, B_t, Q_t, R_t, margin)
    assert scaled.status is SolveStatus.OPTIMAL and twin.status is SolveStatus.OPTIMAL
    assert np.max(np.abs(c * scaled.K - twin.K)) <= TWIN_K_RTOL * np.max(np.abs(twin.K))
    assert np.max(np.abs(scaled.P * c**2 - twin.P)) <= TWIN_K_RTOL * np.linalg.norm(twin.P, 2)


@pytest.mark.parametrize(("A", "B", "index"), [
    ([[[1.5]]], [[[0.0]]], 0),                                            # x⁺ = 1.5 x, no input
    ([[[1.0]]], [[[0.0]]], 0),                                            # an integrator without input
    ([[[0.5]]], [[[0.0]]], None),                                         # stable: K = 0 will do
    ([np.diag([1.5, 0.5])], [[[0.0], [1.0]]], 0),                         # the unstable mode unreachable
    ([np.diag([0.5, 1.5])], [[[0.0], [1.0]]], None),                      # ... reachable
    ([[[1.0, 1.0], [0.0, 1.0]]], [[[0.0], [1.0]]], None),                 # double integrator, controllable
    ([[[0.5]], [[2.0]]], [[[1.0]], [[0.0]]], 1),                          # the second vertex
])
def test_unstabilisable_vertex_by_the_pbh_test(A, B, index):
    from amcp_drake.backends.gain_scaling import unstabilisable_vertex

    assert unstabilisable_vertex(np.asarray(A, float), np.asarray(B, float)) == index


@pytest.mark.parametrize("margin", [1e-8, 1e-9])
def test_drake_gain_lmi_of_an_unstabilisable_vertex_is_infeasible_not_an_aborted_process(margin):
    """x⁺ = 1.5 x + 0·u at design.lmi_margin 1e-8 or 1e-9: Clarabel panicked inside Rust ("Eigval
    error") and Drake, which cannot catch it, aborted the Python process (SIGABRT). Run in
    a child so that a regression fails this test instead of killing the suite."""
    import subprocess
    import sys

    code = ("import numpy as np; from amcp_drake.backends import get_backend; "
            f"r = get_backend('drake').robust_gain(np.array([[[1.5]]]), np.zeros((1, 1, 1)), np.eye(1), np.eye(1), {margin}); "
            "print(r.status.value, r.K is None, r.P is None)")
    child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert child.returncode == 0, child.stderr[-2000:]
    assert child.stdout.split() == ["infeasible", "True", "True"]
