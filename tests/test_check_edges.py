"""Every answer check of amcp_drake.online.answer_checks at its tolerance edge: an answer whose measured
violation is 2× the tolerance is rejected, one at 0.5× passes.

The tolerances are the documented ones, written here (not read from the module), so that a loosened
constant fails a test instead of moving it. Each answer is built so that its violation is known without
the code under test: by hand for the projection (12) and the set update (9); for the tube QP (20), from a
real answer of Example 1 moved along one direction until the violation, computed by this file's own
formula of the row from (14)-(15) and (5b), is the wanted one.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from amcp_drake.online import answer_checks as ac

PROJECTION_MEMBERSHIP_TOL = 1e-8
PROJECTION_CANDIDATE_RTOL = 1e-8
PROJECTION_KKT_RTOL = 1e-7
SET_NESTED_TOL = 1e-8
SET_OUTER_TOL = 1e-7
SET_POINT_TOL = 1e-7
TUBE_ROW_TOL = 1e-6
EDGES = [(2.0, False), (0.5, True)]  # (violation / tolerance, passes)


def _named(checks, name):
    found = [c for c in checks if c.name == name]
    assert len(found) == 1, [c.name for c in checks]
    return found[0]


# -- projection (12) onto the box [-1, 1]^2 ------------------------------------------------------------
BOX_H = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
BOX_h = np.ones(4)


@pytest.mark.parametrize("factor, passes", EDGES)
def test_projection_membership_at_its_edge(factor, passes):
    """θ̃ = (2, 0), answer (1 + δ, 0): outside the row x <= 1 by δ; its KKT residual is 0."""
    delta = factor * PROJECTION_MEMBERSHIP_TOL
    checks = ac.check_projection(np.array([1.0 + delta, 0.0]), np.array([2.0, 0.0]), BOX_H, BOX_h)
    assert _named(checks, "projection in set").passed is passes
    assert _named(checks, "projection KKT residual").passed


@pytest.mark.parametrize("factor, passes", EDGES)
def test_projection_candidate_at_its_edge(factor, passes):
    """θ̃ = (2, 0), answer (1 − δ, 0) (inside, the row still active), known point (1, 0) of the set at
    distance 1: the answer is δ farther (relative to max(1, 1))."""
    delta = factor * PROJECTION_CANDIDATE_RTOL
    checks = ac.check_projection(np.array([1.0 - delta, 0.0]), np.array([2.0, 0.0]), BOX_H, BOX_h,
                                 (np.array([1.0, 0.0]),))
    assert _named(checks, "projection no farther than a known point of the set").passed is passes
    assert _named(checks, "projection in set").passed and _named(checks, "projection KKT residual").passed


@pytest.mark.parametrize("factor, passes", EDGES)
def test_projection_kkt_at_its_edge(factor, passes):
    """θ̃ = (2, η), answer (1, 0) (the projection is (1, η)): the gap (1, η) leaves η off the active
    normal (1, 0); relative to max(‖gap‖, 1) = 1 + O(η²)."""
    eta = factor * PROJECTION_KKT_RTOL
    checks = ac.check_projection(np.array([1.0, 0.0]), np.array([2.0, eta]), BOX_H, BOX_h)
    assert _named(checks, "projection KKT residual").passed is passes
    assert _named(checks, "projection in set").passed


# -- set update (9) on Θ_(k−1) = [-1, 1] (p = 1) with one data row θ <= 5 that does not cut -------------------
SET_H = np.array([[1.0], [-1.0]])
SET_h_prev = np.array([1.0, 1.0])
DATA_H, DATA_h = np.array([[1.0]]), np.array([5.0])
BOX = np.array([1.0])
LAMBDA = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # row i of Θ_k from row i of Θ_(k−1): Λ H̃ = H_θ exactly


def _set_checks(h, points=None):
    return ac.check_set_update(h, LAMBDA, points, SET_H, SET_h_prev, DATA_H, DATA_h, BOX)


@pytest.mark.parametrize("factor, passes", EDGES)
def test_set_update_nesting_at_its_edge(factor, passes):
    checks = _set_checks(SET_h_prev + np.array([factor * SET_NESTED_TOL, 0.0]))
    assert _named(checks, "set update nested h <= h_prev (10)").passed is passes
    assert _named(checks, "set update outer bound (dual certificate)").passed


@pytest.mark.parametrize("factor, passes", EDGES)
def test_set_update_dual_certificate_at_its_edge(factor, passes):
    """h below the dual bound Λ h̃ = h_prev by factor × tolerance."""
    checks = _set_checks(SET_h_prev - np.array([factor * SET_OUTER_TOL, 0.0]))
    assert _named(checks, "set update outer bound (dual certificate)").passed is passes
    assert _named(checks, "set update nested h <= h_prev (10)").passed


@pytest.mark.parametrize("factor, passes", EDGES)
def test_set_update_maximisers_at_their_edge(factor, passes):
    """The maximiser of row 1 (θ <= 1) given at 1 + δ: outside Θ_(k−1) by δ and off its offset by δ."""
    delta = factor * SET_POINT_TOL
    checks = _set_checks(SET_h_prev, np.array([[1.0 + delta], [-1.0]]))
    assert _named(checks, "set update maximisers feasible and tight").passed is passes


# -- tube QP (20) on Example 1 at x0 -------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tube(example_spec, example_design):
    """(data, x0, plain-form answer, vertex-form answer, vertices of Θ0) of Example 1's first step."""
    from amcp_drake.model import polytope
    from amcp_drake.online.controller import AdaptiveMPC

    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake")
    vert = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="vertex")
    x0 = np.asarray(example_spec.scenario.x0, float)
    h0, th0 = np.asarray(example_design.h_theta0, float), example_spec.problem.theta_hat0
    plain = ctrl.mpc.solve(x0, h0, th0)
    vertex = vert.mpc.solve(x0, h0, th0)
    verts = polytope.theta_vertices(np.asarray(example_design.H_theta, float), h0)
    return ctrl.data, x0, plain, vertex, verts


def _stage_points(d, sol, l):
    """Vertices x^j_l = z_l + α_l x^j of X_(l|k) and their inputs u^j_l = K x^j_l + v_l (14)."""
    X = np.asarray(sol.z)[l] + np.asarray(sol.alpha)[l] * np.asarray(d.X0_vertices, float)
    return X, X @ np.asarray(d.K).T + np.asarray(sol.v)[l]


def _row_15a(d, sol, x):
    return max(float(np.max(X @ np.asarray(d.F).T + U @ np.asarray(d.G).T - 1.0))
               for X, U in (_stage_points(d, sol, l) for l in range(int(d.N))))


def _row_15b(d, sol, x):
    return float(np.max(np.asarray(d.H_x) @ (x - np.asarray(sol.z)[0]) - np.asarray(sol.alpha)[0]))


def _row_terminal(d, sol, x):
    N = int(d.N)
    return float(np.max(np.asarray(d.H_T) @ np.asarray(sol.z)[N] + np.asarray(d.h_T) * np.asarray(sol.alpha)[N] - 1.0))


def _row_5b(d, sol, verts):
    """max over l, x^j, θ^s of H_x(A(θ)x + B(θ)u − z_(l+1)) − α_(l+1) + w̄, (5b) at the vertices."""
    worst = -np.inf
    for l in range(int(d.N)):
        X, U = _stage_points(d, sol, l)
        for th in verts:
            A = np.asarray(d.A0) + np.tensordot(th, np.asarray(d.A), axes=1)
            B = np.asarray(d.B0) + np.tensordot(th, np.asarray(d.B), axes=1)
            nxt = X @ A.T + U @ B.T - np.asarray(sol.z)[l + 1]
            worst = max(worst, float(np.max(nxt @ np.asarray(d.H_x).T - np.asarray(sol.alpha)[l + 1] + np.asarray(d.w_bar))))
    return worst


def _row_15c(d, sol, h):
    """max over l, x^j of Λ^j_l h + H_x(A0 x + B0 u − z_(l+1)) − α_(l+1) + w̄ (15c)."""
    worst = -np.inf
    for l in range(int(d.N)):
        X, U = _stage_points(d, sol, l)
        base = X @ np.asarray(d.A0).T + U @ np.asarray(d.B0).T - np.asarray(sol.z)[l + 1]
        for j in range(len(X)):
            row = np.asarray(sol.Lambda)[l, j] @ h + np.asarray(d.H_x) @ base[j] - np.asarray(sol.alpha)[l + 1] + np.asarray(d.w_bar)
            worst = max(worst, float(np.max(row)))
    return worst


def _bisect(value, target, hi=1.0):
    """s >= 0 with value(s) = target, value convex piecewise linear with value(0) <= target < value(hi)."""
    lo = 0.0
    assert value(lo) <= target < value(hi), (value(lo), target, value(hi))
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if value(mid) <= target else (lo, mid)
    return hi


def _both_check_paths(d, sol, x, h, verts, name):
    """The check ``name`` by check_tube and by the preassembled TubeCheck (the online loop's)."""
    first = _named(ac.check_tube(sol, d, x, h, None, verts), name)
    second = _named(ac.TubeCheck(d).check(sol, x, verts, h, None), name)
    assert first.passed == second.passed and first.value == pytest.approx(second.value, abs=1e-12)
    return first


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_alpha_nonneg_at_its_edge(tube, factor, passes):
    d, x, plain, _, verts = tube
    alpha = np.array(plain.alpha)
    alpha[-1] = -factor * TUBE_ROW_TOL
    sol = dataclasses.replace(plain, alpha=alpha)
    assert _both_check_paths(d, sol, x, d.h_theta0, verts, "tube alpha >= 0").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_15b_at_its_edge(tube, factor, passes):
    """x_k moved along H_x's first row until x_k leaves X_(0|k) by factor × tolerance."""
    d, x, plain, _, verts = tube
    e = np.asarray(d.H_x)[0]
    s = _bisect(lambda s: _row_15b(d, plain, x + s * e), factor * TUBE_ROW_TOL, hi=10.0)
    assert _row_15b(d, plain, x + s * e) == pytest.approx(factor * TUBE_ROW_TOL, rel=1e-6)
    assert _both_check_paths(d, plain, x + s * e, d.h_theta0, verts, "tube x_k in X_0|k (15b)").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_15a_at_its_edge(tube, factor, passes):
    """v_0 moved until the tube leaves Z (15a) by factor × tolerance."""
    d, x, plain, _, verts = tube
    direction = np.sign(np.asarray(d.G).sum(axis=0)) + (np.asarray(d.G).sum(axis=0) == 0)

    def moved(s):
        v = np.array(plain.v)
        v[0] = v[0] + s * direction
        return dataclasses.replace(plain, v=v)

    s = _bisect(lambda s: _row_15a(d, moved(s), x), factor * TUBE_ROW_TOL, hi=100.0)
    assert _row_15a(d, moved(s), x) == pytest.approx(factor * TUBE_ROW_TOL, rel=1e-6)
    assert _both_check_paths(d, moved(s), x, d.h_theta0, verts, "tube constraints (15a)").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_terminal_set_at_its_edge(tube, factor, passes):
    """α_N raised until (z_N, α_N) leaves X_f by factor × tolerance."""
    d, x, plain, _, verts = tube

    def moved(s):
        alpha = np.array(plain.alpha)
        alpha[-1] += s
        return dataclasses.replace(plain, alpha=alpha)

    s = _bisect(lambda s: _row_terminal(d, moved(s), x), factor * TUBE_ROW_TOL, hi=100.0)
    assert _both_check_paths(d, moved(s), x, d.h_theta0, verts, "tube terminal set").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_lambda_nonneg_at_its_edge(tube, factor, passes):
    d, x, plain, _, verts = tube
    Lam = np.array(plain.Lambda)
    Lam[0, 0, 0, 0] = -factor * TUBE_ROW_TOL
    sol = dataclasses.replace(plain, Lambda=Lam)
    assert _both_check_paths(d, sol, x, d.h_theta0, verts, "tube Lambda >= 0").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_15d_at_its_edge(tube, factor, passes):
    """One entry of Λ moved by δ: H_x D − Λ H_θ changes by δ·[H_θ]_q in one block (the rest is ~1e-12)."""
    d, x, plain, _, verts = tube
    H = np.asarray(d.H_theta, float)
    q = 0
    Lam = np.array(plain.Lambda)
    Lam[0, 0, 0, q] += factor * TUBE_ROW_TOL / float(np.max(np.abs(H[q])))
    sol = dataclasses.replace(plain, Lambda=Lam)
    assert _both_check_paths(d, sol, x, d.h_theta0, verts, "tube (15d)").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_15c_at_its_edge(tube, factor, passes):
    """The offsets h of Θ_k raised uniformly until (15c) is violated by factor × tolerance (Λ >= 0, so the
    rows grow with h)."""
    d, x, plain, _, verts = tube
    h0 = np.asarray(d.h_theta0, float)
    s = _bisect(lambda s: _row_15c(d, plain, h0 + s), factor * TUBE_ROW_TOL, hi=10.0)
    assert _row_15c(d, plain, h0 + s) == pytest.approx(factor * TUBE_ROW_TOL, rel=1e-6)
    checks = ac.check_tube(plain, d, x, h0 + s)  # without vertices: (15c) and (15d) are the checks
    assert _named(checks, "tube (15c)").passed is passes
    assert _named(ac.TubeCheck(d).check(plain, x, None, h0 + s, None), "tube (15c)").passed is passes


@pytest.mark.parametrize("factor, passes", EDGES)
def test_tube_5b_at_the_vertices_at_its_edge(tube, factor, passes):
    """The vertex form's answer, w̄ raised uniformly until (5b) at the vertices of Θ_k is violated by
    factor × tolerance."""
    d, x, _, vertex, verts = tube
    value0 = _row_5b(d, vertex, verts)
    assert value0 <= 1e-7  # a solved QP: its rows hold to the solver's accuracy
    shifted = dataclasses.replace(d, w_bar=np.asarray(d.w_bar, float) + (factor * TUBE_ROW_TOL - value0))
    assert _row_5b(shifted, vertex, verts) == pytest.approx(factor * TUBE_ROW_TOL, rel=1e-6)
    check = _both_check_paths(shifted, vertex, x, shifted.h_theta0, verts, "tube (5b) at the vertices of Θ_k")
    assert check.passed is passes


# -- exact update (7): a removed row is re-checked (HiGHS, certified) and put back when the kept rows allow
# exceeding it by more than SET_NESTED_TOL ---------------------------------------------------------------------------
@pytest.mark.parametrize("factor, put_back", [(2.0, True), (0.5, False)])
def test_exact_update_removed_row_recheck_at_its_edge(example_spec, example_design, monkeypatch, factor, put_back):
    """Θ_(k−1) = Θ_0 (irredundant) and one data row parallel to its first row, cutting it by factor × tol (unit row).
    The backend's support LPs answer 0.1 too low (tests/tampered_backends.py), so it removes that row; the
    re-check puts it back exactly when the cut exceeds the tolerance, and says so as a fallback."""
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.model.status import SolveStatus
    from amcp_drake.online.controller import AdaptiveMPC, StepRecord
    from tests import tampered_backends as tb

    tb.use_as_drake(monkeypatch, tb.LowSupportDrake)
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", options=OnlineOptions(update="exact"))
    s = ctrl.state.replace(exact_rows_irredundant=True).working()
    H0, h0 = np.array(s.H_theta, float), np.array(s.h_theta, float)
    row = H0[0]
    bound = h0[0] - factor * SET_NESTED_TOL * float(np.linalg.norm(row))
    record = StepRecord(k=1, x=np.zeros(example_spec.problem.n), u=None, status=SolveStatus.NOT_RUN, H_theta=H0,
                        h_theta=h0, theta_hat=np.zeros(example_spec.problem.p), answers=[])
    assert ctrl._update_exact(s, row[None, :], np.array([bound]), record)
    kept = any(np.array_equal(r, row) and b == bound for r, b in zip(s.H_theta, s.h_theta))
    assert kept is put_back
    [entry] = [e for e in record.answers if e["problem"] == "exact_update"]
    assert entry["outcome"] == ("fallback" if put_back else "first"), entry
