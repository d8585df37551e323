"""Every certificate claim at its tolerance edge: one test parametrised over the rows of the table of claims
(:mod:`amcp_drake.model.claim_table`), in which a recorded run of Example 1 (or the design of a scalar system)
is edited so that the claim's margin is −2× its tolerance, which must fail, and −0.5× its tolerance, which must
pass (a claim passes when margin >= −tolerance). A row without an edge case here fails the test.

The tolerances are the documented ones, written here (not read from the modules), so that a loosened constant
fails a test instead of moving it. Each edit sets the margin through this file's own formula of the claim's
quantity (the paper's definition, evaluated on the recorded numbers), never through the certificate's code; the
edit is made on one step (the last one where that is possible, so that no other step's quantity moves), and the
certificate's claim function is called on the edited run.

Claims with a tolerance of 0 are tested just outside and just inside: (11) at margins ∓1e-9, recursive
feasibility (a count of unsolved steps) at one and at no unsolved step.
"""

from __future__ import annotations

import dataclasses
import inspect
import itertools
from collections.abc import Callable
from types import SimpleNamespace

import numpy as np
import pytest

from amcp_drake.certificate import claims as cl
from amcp_drake.certificate.section4 import cost_value
from amcp_drake.certificate.tube import tube_checks, x0_vertex_list
from amcp_drake.model.claim_table import BY_ID, CLAIMS
from amcp_drake.online.simulate import Trajectory
from tests.recorded_runs import as_recorded, example_1_recorded
from tests.recorded_runs import fresh as _fresh

STEPS = 8
MEMBERSHIP_TOL = 1e-9     # θ* ∈ Θ, w_k ∈ W
IDENTITY_TOL = 1e-9       # (1), (21)
MU_TOL = 1e-12            # μ‖D‖² <= 1
SET_LP_TOL = 1e-7         # θ* ∈ Θ_k, (x, u) ∈ Z, Θ ⊆ Θ_0, (10) both sides
PROJECTION_TOL = 1e-7     # θ̂_k ∈ Θ, (12)
LEMMA5_TOL = 1e-8
QP_TOL = 1e-6             # tube claims, multipliers
COST_REL_TOL = 1e-6       # cost (17), relative to max(|J|, 1)
VERTEX_TOL = 1e-8         # X0 vertex list, relative to max(1, largest coordinate)
W_BAR_TOL = 1e-6          # w̄, f̄ recomputed
CONSISTENCY_TOL = 1e-7    # Θ_(k−1) ∩ Δ_k ≠ ∅, θ units
EDGES = [(2.0, "fail"), (0.5, "pass")]  # (−margin / tolerance, status)

#: claim id -> its edge case: a function of (fixtures..., factor, status) that edits a run or a design so that the
#: claim's margin is −factor × its documented tolerance and asserts the claim's status.
EDGE_CASES: dict[str, Callable] = {}


def edge(claim_id: str):
    """Register the decorated function as the edge case of ``claim_id``."""
    def register(fn):
        assert claim_id not in EDGE_CASES, claim_id
        EDGE_CASES[claim_id] = fn
        return fn
    return register


@pytest.mark.parametrize("factor, status", EDGES)
@pytest.mark.parametrize("claim_id", [c.id for c in CLAIMS])
def test_claim_at_its_edge(request, claim_id, factor, status):
    """The row's claim, edited to −factor × its documented tolerance, has ``status``."""
    assert claim_id in EDGE_CASES, f"the claim {claim_id!r} of the table of claims has no edge case in this file"
    case = EDGE_CASES[claim_id]
    fixtures = [request.getfixturevalue(name) for name in inspect.signature(case).parameters
                if name not in ("factor", "status")]
    case(*fixtures, factor, status)


def test_every_edge_case_names_a_claim_of_the_table():
    assert set(EDGE_CASES) <= set(BY_ID), sorted(set(EDGE_CASES) - set(BY_ID))


@pytest.fixture(scope="module")
def recorded(example_spec, example_design) -> dict:
    from amcp_drake.online.controller import AdaptiveMPC

    return example_1_recorded(example_spec, AdaptiveMPC(example_spec.problem, example_design, backend="drake"), STEPS)


def _view(traj: Trajectory) -> cl.RunView:
    return cl.RunView(traj)


def _claim(results, claim_id: str):
    found = [c for c in results if c.data.get("id") == claim_id]
    assert len(found) == 1, [c.data.get("id") for c in results]
    return found[0]


def _unit(H, h):
    H, h = np.asarray(H, float), np.asarray(h, float)
    n = np.linalg.norm(H, axis=1)
    return H / n[:, None], h / n


def _vertices(H, h) -> np.ndarray:
    """Vertices of {H θ <= h} by every choice of p rows (this file's own enumeration)."""
    H, h = np.asarray(H, float), np.asarray(h, float)
    p = H.shape[1]
    out = []
    for rows in itertools.combinations(range(len(H)), p):
        M = H[list(rows)]
        if abs(np.linalg.det(M)) < 1e-12:
            continue
        x = np.linalg.solve(M, h[list(rows)])
        if np.all(H @ x <= h + 1e-9 * np.maximum(1.0, np.abs(h))):
            out.append(x)
    return np.array(out)


def _bisect(value, target, hi):
    """s in [0, hi] with value(s) = target, value continuous and increasing, value(0) < target < value(hi)."""
    lo = 0.0
    assert value(lo) < target < value(hi), (value(lo), target, value(hi))
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if value(mid) < target else (lo, mid)
    return 0.5 * (lo + hi)


def _assert_edge(claim, margin: float, factor: float, tol: float, status: str, rel: float = 1e-6):
    assert claim.tolerance == tol, (claim.data["id"], claim.tolerance)
    assert margin == pytest.approx(-factor * tol, rel=rel)       # the edge this file means, by its own formula
    assert claim.margin == pytest.approx(margin, rel=1e-3, abs=1e-3 * factor * tol), (claim.margin, margin)
    assert claim.status == status, (claim.data["id"], claim.margin, claim.tolerance)


# -- Assumption 1, (1), (21), μ ---------------------------------------------------------------------------------
@edge("theta_star_in_Theta")
def theta_star_in_theta_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    H, h = _unit(tr.problem.H_theta, tr.problem.h_theta)
    star = np.asarray(tr.theta_star, float)
    i = int(np.argmin(h - H @ star))                      # the nearest facet: moving to it leaves the others
    tr.theta_star = star + (h[i] - H[i] @ star + factor * MEMBERSHIP_TOL) * H[i]
    margin = float(np.min(h - H @ tr.theta_star))
    _assert_edge(cl.theta_star_in_theta(_view(tr)), margin, factor, MEMBERSHIP_TOL, status)


@edge("w_in_W")
def w_in_w_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    H_w = np.asarray(tr.problem.H_w, float)
    k = STEPS - 1
    tr.w[k] = (1.0 + factor * MEMBERSHIP_TOL) * H_w[0] / float(H_w[0] @ H_w[0])   # on the ray of row 0, past it
    margin = min(float(np.min(1.0 - H_w @ w)) for w in tr.w)
    _assert_edge(cl.disturbances_in_w(_view(tr)), margin, factor, MEMBERSHIP_TOL, status)


@edge("model_consistent")
def model_consistency_at_its_edge(recorded, factor, status):
    """w_(T−1) moved by δ in one coordinate: x_T − A(θ*)x − B(θ*)u − w is then off by exactly δ."""
    tr = _fresh(recorded)
    k = STEPS - 1
    tr.w[k, 0] += factor * IDENTITY_TOL
    pr = tr.problem
    res = tr.x[k + 1] - pr.A_of(tr.theta_star) @ tr.x[k] - pr.B_of(tr.theta_star) @ tr.u[k] - tr.w[k]
    _assert_edge(cl.model_consistency(_view(tr)), -float(np.max(np.abs(res))), factor, IDENTITY_TOL, status, rel=1e-4)


@edge("control_law")
def control_law_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    k = STEPS - 1
    r = tr.records[k]
    r.v = np.array(r.v, float)
    r.v[0] = tr.u[k] - np.asarray(tr.design.K) @ tr.x[k] + factor * IDENTITY_TOL
    margin = -float(np.max(np.abs(tr.u[k] - (np.asarray(tr.design.K) @ tr.x[k] + r.v[0]))))
    _assert_edge(cl.control_law(_view(tr)), margin, factor, IDENTITY_TOL, status, rel=1e-4)


@edge("mu_precondition")
def mu_precondition_at_its_edge(recorded, example_spec, factor, status):
    """μ raised until μ max_k ‖D(x_k, u_k)‖₂² = 1 + factor × tolerance."""
    tr = _fresh(recorded)
    pr = tr.problem
    worst = max(float(np.linalg.norm(pr.regressor(tr.x[k], tr.u[k]), 2) ** 2) for k in range(STEPS))
    tr.design = dataclasses.replace(tr.design, mu=(1.0 + factor * MU_TOL) / worst)
    margin = 1.0 - tr.design.mu * worst
    _assert_edge(cl.mu_precondition(_view(tr), example_spec.design.mu_state_bound), margin, factor, MU_TOL, status,
                 rel=1e-3)


@edge("data_consistency")
def data_consistency_at_its_edge(factor, status):
    """One transition of x+ = (0.5 + 0.2θ)x + u + w, |w| <= 0.1, from x_0 = 1, u_0 = 0, Θ_0 = [−1, 1]:
    Δ_1 = [(x_1 − 0.6)/0.2, (x_1 − 0.4)/0.2], and x_1 = 0.8 + 0.4·gap puts its lower end at 1 + 2·gap, so Θ_0 ∩ Δ_1
    is empty by 2·gap and its signed Chebyshev radius (half that, this file's arithmetic) is −gap."""
    from amcp_drake.certificate.consistency import data_consistency
    from tests.conftest import scalar_problem

    gap = factor * CONSISTENCY_TOL
    record = SimpleNamespace(H_theta=np.array([[1.0], [-1.0]]), h_theta=np.array([1.0, 1.0]))
    traj = SimpleNamespace(problem=scalar_problem(), x=np.array([[1.0], [0.8 + 0.4 * gap]]), u=np.array([[0.0]]),
                           records=[record, record])
    out = data_consistency(cl.RunView(traj))
    _assert_edge(out, -gap, factor, CONSISTENCY_TOL, status, rel=1e-12)


# -- Theorem 14 ---------------------------------------------------------------------------------------------------
@edge("recursive_feasibility")
def recursive_feasibility_at_its_edge(recorded, factor, status):
    """Tolerance 0 on a count: no unsolved step passes (margin 0, the inside case), one unsolved step fails
    (margin −1, the outside case)."""
    from amcp_drake.model.status import SolveStatus

    tr = _fresh(recorded)
    at_edge = cl.recursive_feasibility(_view(tr))
    assert (at_edge.tolerance, at_edge.margin, at_edge.status) == (0.0, 0.0, "pass")
    if status == "pass":
        return
    r = tr.records[STEPS]
    r.status, r.answers = SolveStatus.INFEASIBLE, None
    r.u = r.v = r.z = r.alpha = r.Lambda = r.cost = None
    out = cl.recursive_feasibility(_view(tr))
    assert (out.margin, out.status, out.data["worst_step"]) == (-1.0, "fail", STEPS)


@edge("theta_star_in_Theta_k")
def theta_star_in_theta_k_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    H = np.asarray(r.H_theta, float)
    n = np.linalg.norm(H, axis=1)
    star = np.asarray(tr.theta_star, float)
    i = int(np.argmin((np.asarray(r.h_theta) - H @ star) / n))
    r.h_theta = np.array(r.h_theta, float)
    r.h_theta[i] = H[i] @ star - factor * SET_LP_TOL * n[i]
    margin = min(float(np.min(_unit(q.H_theta, q.h_theta)[1] - _unit(q.H_theta, q.h_theta)[0] @ star))
                 for q in tr.records)
    _assert_edge(cl.theta_star_in_theta_k(_view(tr)), margin, factor, SET_LP_TOL, status)


@edge("theta_hat_in_Theta")
def theta_hat_in_theta_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    H, h = _unit(tr.problem.H_theta, tr.problem.h_theta)
    r = tr.records[STEPS]
    th = np.asarray(r.theta_hat, float)
    i = int(np.argmin(h - H @ th))
    r.theta_hat = th + (h[i] - H[i] @ th + factor * PROJECTION_TOL) * H[i]
    margin = min(float(np.min(h - H @ q.theta_hat)) for q in tr.records)
    _assert_edge(cl.theta_hat_in_theta(_view(tr)), margin, factor, PROJECTION_TOL, status)


@edge("state_input_constraints")
def state_input_constraints_at_its_edge(recorded, factor, status):
    """u_(T−1) moved until a row of Z with an input coefficient is violated by factor × tolerance."""
    tr = _fresh(recorded)
    pr = tr.problem
    F, G = np.asarray(pr.F, float), np.asarray(pr.G, float)
    k = STEPS - 1
    i = int(np.flatnonzero(G[:, 0] > 0)[0])
    tr.u[k] = (1.0 + factor * SET_LP_TOL - F[i] @ tr.x[k]) / G[i, 0] * np.ones(1)
    tr.records[k].u = tr.u[k].copy()
    margin = min(float(np.min(1.0 - F @ tr.x[j] - G @ tr.u[j])) for j in range(STEPS))
    _assert_edge(cl.state_input_constraints(_view(tr)), margin, factor, SET_LP_TOL, status)


# -- Lemma 3, (10) ------------------------------------------------------------------------------------------------
@edge("Theta0_contains_Theta")
def prior_in_theta_0_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r0 = tr.records[0]
    H = np.asarray(r0.H_theta, float)
    n = np.linalg.norm(H, axis=1)
    verts = _vertices(tr.problem.H_theta, tr.problem.h_theta)
    r0.h_theta = np.array(r0.h_theta, float)
    r0.h_theta[0] = float(np.max(verts @ H[0])) - factor * SET_LP_TOL * n[0]
    margin = float(np.min(r0.h_theta / n - np.max(verts @ (H / n[:, None]).T, axis=0)))
    _assert_edge(cl.prior_contains_theta(_view(tr)), margin, factor, SET_LP_TOL, status)


@edge("Theta_k_nested")
def nested_sets_at_their_edge(recorded, factor, status):
    """h_T raised above h_(T−1) in one row (same shape: componentwise)."""
    tr = _fresh(recorded)
    a, b = tr.records[STEPS - 1], tr.records[STEPS]
    assert np.array_equal(a.H_theta, b.H_theta)
    n = np.linalg.norm(np.asarray(a.H_theta, float), axis=1)
    b.h_theta = np.array(b.h_theta, float)
    b.h_theta[0] = a.h_theta[0] + factor * SET_LP_TOL * n[0]
    margin = min(float(np.min((p.h_theta - q.h_theta) / n)) for p, q in zip(tr.records, tr.records[1:]))
    _assert_edge(cl.nested_sets(_view(tr)), margin, factor, SET_LP_TOL, status)


@edge("Theta_k_lower_inclusion")
def lower_inclusion_at_its_edge(recorded, factor, status):
    """h_T lowered in one row below the support of Θ_(T−1) ∩ Δ_T (this file's LP, scipy HiGHS) by factor × tol."""
    from scipy.optimize import linprog

    tr = _fresh(recorded)
    pr = tr.problem
    k = STEPS - 1
    a, b = tr.records[k], tr.records[k + 1]
    D = pr.regressor(tr.x[k], tr.u[k])
    d = pr.A0 @ tr.x[k] + pr.B0 @ tr.u[k] - tr.x[k + 1]
    H_w = np.asarray(pr.H_w, float)
    A_ub = np.vstack([a.H_theta, -H_w @ D])
    b_ub = np.concatenate([a.h_theta, 1.0 + H_w @ d])
    Hb = np.asarray(b.H_theta, float)
    n = np.linalg.norm(Hb, axis=1)
    res = linprog(-Hb[0], A_ub=A_ub, b_ub=b_ub, bounds=[(None, None)] * pr.p, method="highs")
    assert res.status == 0
    support = -res.fun
    b.h_theta = np.array(b.h_theta, float)
    b.h_theta[0] = support - factor * SET_LP_TOL * n[0]
    margin = (b.h_theta[0] - support) / n[0]
    out = cl.lower_inclusion(_view(tr))
    assert out.data["worst_step"] == STEPS
    _assert_edge(out, margin, factor, SET_LP_TOL, status, rel=1e-2)


# -- (12), Lemma 5 --------------------------------------------------------------------------------------------------
def _lms_margin(tr, k, theta_next):
    """−max(max_{θ ∈ vert Θ} (θ̃ − θ̂)ᵀ(θ − θ̂), max_i ([H]_i θ̂ − h_i)) for step k → k+1 (projection onto Θ)."""
    pr = tr.problem
    th = tr.records[k].theta_hat
    D = pr.regressor(tr.x[k], tr.u[k])
    tilde = th + tr.design.mu * D.T @ (tr.x[k + 1] - pr.A_of(th) @ tr.x[k] - pr.B_of(th) @ tr.u[k])
    H, h = _unit(pr.H_theta, pr.h_theta)
    verts = _vertices(pr.H_theta, pr.h_theta)
    gap = tilde - theta_next
    return -max(float(np.max((verts - theta_next) @ gap)), float(np.max(H @ theta_next - h)))


@edge("lms_update")
def lms_update_at_its_edge(recorded, factor, status):
    """θ̂_T moved along one axis until the projection's variational inequality (12) is off by factor × tol."""
    tr = _fresh(recorded)
    k = STEPS - 1
    base = np.asarray(tr.records[k + 1].theta_hat, float)
    assert _lms_margin(tr, k, base) > -1e-12
    e = np.eye(len(base))[0]
    s = _bisect(lambda s: -_lms_margin(tr, k, base + s * e), factor * PROJECTION_TOL, hi=1e-3)
    tr.records[k + 1].theta_hat = base + s * e
    margin = _lms_margin(tr, k, tr.records[k + 1].theta_hat)
    out = cl.lms_update(_view(tr))
    assert out.data["worst_step"] == STEPS
    _assert_edge(out, margin, factor, PROJECTION_TOL, status)


@edge("lemma5")
def lemma5_at_its_edge(recorded, factor, status):
    """θ̂_T moved away from θ* until the left side of Lemma 5 at m = T−1 exceeds the right by factor × tol."""
    tr = _fresh(recorded)
    pr, mu, star = tr.problem, tr.design.mu, np.asarray(tr.theta_star, float)
    M = STEPS
    x_tilde = sum(float(np.sum((pr.regressor(tr.x[k], tr.u[k]) @ (star - tr.records[k].theta_hat)) ** 2))
                  for k in range(M))
    rhs = float(np.sum((tr.records[0].theta_hat - star) ** 2)) / mu + float(np.sum(tr.w[:M] ** 2))
    radius = np.sqrt(mu * (rhs - x_tilde + factor * LEMMA5_TOL))
    th = np.asarray(tr.records[M].theta_hat, float)
    tr.records[M].theta_hat = star + radius * (th - star) / np.linalg.norm(th - star)
    margin = rhs - (float(np.sum((tr.records[M].theta_hat - star) ** 2)) / mu + x_tilde)
    view = _view(tr)
    out = cl.lemma5(view, cl.lemma5_series(view))
    assert out.data["worst_step"] == M - 1
    _assert_edge(out, margin, factor, LEMMA5_TOL, status, rel=1e-3)


# -- Proposition 9: the tube of step T, and its multipliers ---------------------------------------------------------
def _tube(tr, claim_id):
    return _claim(tube_checks(_view(tr)), claim_id)


def _stage(tr, r, l):
    """Vertices z_l + α_l x^j of X_(l|T) (the QP's vertex list of X0) and their inputs K x + v_l."""
    X = np.asarray(r.z, float)[l] + np.asarray(r.alpha, float)[l] * np.asarray(tr.design.X0_vertices, float)
    return X, X @ np.asarray(tr.design.K, float).T + np.asarray(r.v, float)[l]


@edge("tube_contains_state")
def tube_contains_state_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    H_x = np.asarray(tr.design.H_x, float)
    m = lambda r: float(np.min(r.alpha[0] - H_x @ (tr.x[STEPS] - r.z[0])))  # noqa: E731
    r.alpha = np.array(r.alpha, float)
    r.alpha[0] -= m(r) + factor * QP_TOL
    _assert_edge(_tube(tr, "tube_contains_state"), m(r), factor, QP_TOL, status)


@edge("tube_contains_next_state")
def tube_contains_next_state_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    k = STEPS - 1
    r = tr.records[k]
    H_x = np.asarray(tr.design.H_x, float)
    m = lambda r: float(np.min(r.alpha[1] - H_x @ (tr.x[k + 1] - r.z[1])))  # noqa: E731
    r.alpha = np.array(r.alpha, float)
    r.alpha[1] -= m(r) + factor * QP_TOL
    _assert_edge(_tube(tr, "tube_contains_next_state"), m(r), factor, QP_TOL, status)


@edge("tube_alpha_nonneg")
def tube_alpha_nonneg_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    r.alpha = np.array(r.alpha, float)
    r.alpha[-1] = -factor * QP_TOL
    _assert_edge(_tube(tr, "tube_alpha_nonneg"), float(r.alpha[-1]), factor, QP_TOL, status)


@edge("terminal_set")
def terminal_set_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    H_T, h_T = np.asarray(tr.design.H_T, float), np.asarray(tr.design.h_T, float)
    base = np.array(r.alpha, float)

    def violation(s):
        return -float(np.min(1.0 - H_T @ r.z[-1] - h_T * (base[-1] + s)))

    s = _bisect(violation, factor * QP_TOL, hi=100.0)
    r.alpha = base.copy()
    r.alpha[-1] += s
    _assert_edge(_tube(tr, "terminal_set"), -violation(s), factor, QP_TOL, status)


@edge("tube_constraints")
def tube_constraints_at_their_edge(recorded, factor, status):
    """v_0 of step T moved until a vertex of X_(0|T) with its input leaves Z by factor × tol."""
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    F, G = np.asarray(tr.problem.F, float), np.asarray(tr.problem.G, float)
    base = np.array(r.v, float)

    def violation(s):
        r.v = base.copy()
        r.v[0] += s
        return -min(float(np.min(1.0 - X @ F.T - U @ G.T)) for X, U in (_stage(tr, r, l) for l in range(len(base))))

    s = _bisect(violation, factor * QP_TOL, hi=100.0)
    margin = -violation(s)
    _assert_edge(_tube(tr, "tube_constraints"), margin, factor, QP_TOL, status)


def _propagation_rows(tr, r, l):
    """α_(l+1) − max_i [H_x]_i (A(θ)x + B(θ)(Kx + v_l) + w − z_(l+1)) over x ∈ vert X_(l|T), θ ∈ vert Θ_T, w ∈ vert W."""
    pr = tr.problem
    H_x = np.asarray(tr.design.H_x, float)
    X, U = _stage(tr, r, l)
    worst = -np.inf
    for th in _vertices(r.H_theta, r.h_theta):
        for w in _vertices(pr.H_w, np.ones(len(pr.H_w))):
            nxt = X @ pr.A_of(th).T + U @ pr.B_of(th).T + w - np.asarray(r.z, float)[l + 1]
            worst = max(worst, float(np.max(nxt @ H_x.T)))
    return float(r.alpha[l + 1]) - worst


@edge("tube_propagation")
def tube_propagation_at_its_edge(recorded, factor, status):
    """α_N of step T lowered: the rows of the last stage (l = N − 1) move by exactly the same amount."""
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    N = len(r.v)
    r.alpha = np.array(r.alpha, float)
    r.alpha[N] -= _propagation_rows(tr, r, N - 1) + factor * QP_TOL
    margin = min(_propagation_rows(tr, r, l) for l in range(N))
    _assert_edge(_tube(tr, "tube_propagation"), margin, factor, QP_TOL, status, rel=1e-4)


@edge("multipliers_nonneg")
def multipliers_nonneg_at_their_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    r.Lambda = np.array(r.Lambda, float)
    r.Lambda[0, 0, 0, 0] = -factor * QP_TOL
    _assert_edge(_tube(tr, "multipliers_nonneg"), float(np.min(r.Lambda)), factor, QP_TOL, status)


def _rows_15c(tr, r, l):
    """min over x^j of −w̄ − Λ^j h_θ − H_x (A0 x + B0 u − z_(l+1)) + α_(l+1) (w̄ from the vertices of W)."""
    pr = tr.problem
    H_x = np.asarray(tr.design.H_x, float)
    w_bar = np.max(H_x @ _vertices(pr.H_w, np.ones(len(pr.H_w))).T, axis=1)
    X, U = _stage(tr, r, l)
    d = X @ pr.A0.T + U @ pr.B0.T - np.asarray(r.z, float)[l + 1]
    lam_h = np.asarray(r.Lambda, float)[l] @ np.asarray(r.h_theta, float)       # (v, u)
    return float(np.min(-w_bar - lam_h - d @ H_x.T + r.alpha[l + 1]))


@edge("multipliers_15c")
def multipliers_15c_at_its_edge(recorded, factor, status):
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    N = len(r.v)
    r.alpha = np.array(r.alpha, float)
    r.alpha[N] -= _rows_15c(tr, r, N - 1) + factor * QP_TOL
    margin = min(_rows_15c(tr, r, l) for l in range(N))
    _assert_edge(_tube(tr, "multipliers_15c"), margin, factor, QP_TOL, status, rel=1e-4)


@edge("multipliers_15d")
def multipliers_15d_at_its_edge(recorded, factor, status):
    """One entry Λ[0, 0, 0, q] moved by δ: H_x D − Λ H_θ changes by δ·[H_θ]_q in one row (the rest is ~1e-15)."""
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    H = np.asarray(r.H_theta, float)
    r.Lambda = np.array(r.Lambda, float)
    r.Lambda[0, 0, 0, 0] += factor * QP_TOL / float(np.max(np.abs(H[0])))
    _assert_edge(_tube(tr, "multipliers_15d"), -factor * QP_TOL, factor, QP_TOL, status, rel=1e-12)


# -- cost, design ---------------------------------------------------------------------------------------------------
@edge("cost_value")
def cost_value_at_its_edge(recorded, factor, status):
    """The recorded cost of step T raised by factor × tol × max(|J|, 1) (relative tolerance)."""
    tr = _fresh(recorded)
    r = tr.records[STEPS]
    J = float(r.cost)
    r.cost = J + factor * COST_REL_TOL * max(abs(J), 1.0)
    out = cost_value(_view(tr))
    assert out.data["worst_step"] == STEPS
    _assert_edge(out, -factor * COST_REL_TOL, factor, COST_REL_TOL, status, rel=1e-9)


OPTIMALITY_TOL = 1e-5     # KKT residuals of (20); primal infeasibility on rows of unit norm


@edge("qp_optimality")
def qp_optimality_at_its_edge(recorded, factor, status):
    """α_N of step T raised until the terminal set, on rows [H_T | h_T] of unit norm, is violated by factor × tol:
    the rebuilt QP (20)'s primal infeasibility at the recorded plan (α is not in the cost, so its stationarity
    residual, ~1e-9, does not move)."""
    from amcp_drake.certificate.optimality import qp_optimality

    tr = _fresh(recorded)
    r = tr.records[STEPS]
    H_T, h_T = np.asarray(tr.design.H_T, float), np.asarray(tr.design.h_T, float)
    n = np.linalg.norm(np.hstack([H_T, h_T[:, None]]), axis=1)
    base = float(r.alpha[-1])

    def violation(t):
        return float(np.max(-(1.0 - H_T @ r.z[-1] - h_T * (base + t)) / n))

    t = _bisect(violation, factor * OPTIMALITY_TOL, hi=10.0)
    r.alpha = np.array(r.alpha, float)
    r.alpha[-1] = base + t
    out = qp_optimality(_view(tr))
    assert out.data["worst_step"] == STEPS
    _assert_edge(out, -violation(t), factor, OPTIMALITY_TOL, status, rel=1e-6)


@edge("design.x0_vertices")
def x0_vertex_list_at_its_edge(recorded, factor, status):
    """One recorded vertex of X0 moved by factor × tol × max(1, largest coordinate) (relative tolerance)."""
    tr = _fresh(recorded)
    V = np.array(tr.design.X0_vertices, float)
    tol = VERTEX_TOL * max(1.0, float(np.max(np.abs(V))))
    V[0, 0] += factor * tol
    tr.design = dataclasses.replace(tr.design, X0_vertices=V)
    out = x0_vertex_list(_view(tr))
    _assert_edge(out, -factor * tol, factor, tol, status, rel=1e-5)


@edge("design.w_bar_f_bar_recomputed")
def w_bar_recomputed_at_its_edge(recorded, example_spec, factor, status):
    from amcp_drake.offline.checks import verify_design

    tr = _fresh(recorded)
    w_bar = np.array(tr.design.w_bar, float)
    w_bar[0] += factor * W_BAR_TOL
    design = dataclasses.replace(tr.design, w_bar=w_bar)
    out = next(c for c in verify_design(tr.problem, design, example_spec.design.mu_state_bound)
               if c.name == "w_bar, f_bar recomputed")
    _assert_edge(out, -factor * W_BAR_TOL, factor, W_BAR_TOL, status, rel=1e-6)


@edge("design.mu_condition_11")
def mu_condition_11_at_factor(recorded, example_spec, factor, status):
    """Tolerance 0 (strict): the outside case at margin −1e-9, the inside case at +1e-9."""
    test_mu_condition_11_at_its_edge(recorded, example_spec, -1e-9 if status == "fail" else 1e-9, status)


@pytest.mark.parametrize("margin, status", [(-1e-9, "fail"), (1e-9, "pass")])
def test_mu_condition_11_at_its_edge(recorded, example_spec, margin, status):
    """Tolerance 0: μ set so that 1 − μ sup‖D‖² is −1e-9 (fails) or +1e-9 (passes). sup‖D‖² over the μ box is
    read back from the passing design's margin (1 − μ sup)."""
    from amcp_drake.offline.checks import verify_design

    tr = _fresh(recorded)
    bound = example_spec.design.mu_state_bound
    base = next(c for c in verify_design(tr.problem, tr.design, bound) if c.name == "mu condition (11)")
    sup = (1.0 - base.margin) / tr.design.mu
    design = dataclasses.replace(tr.design, mu=(1.0 - margin) / sup)
    out = next(c for c in verify_design(tr.problem, design, bound) if c.name == "mu condition (11)")
    assert out.tolerance == 0.0 and out.margin == pytest.approx(margin, rel=1e-5)
    assert out.status == status


def _mu_on_the_boundary(problem, bound) -> float:
    """A μ with 1 − μ·sup‖D‖² == 0.0 exactly in floating point (sup as the design check evaluates it)."""
    from amcp_drake.offline.result import regressor_bound

    sup, _ = regressor_bound(problem, bound)
    mu = 1.0 / sup
    for _ in range(8):
        if 1.0 - mu * sup == 0.0:
            return mu
        mu = np.nextafter(mu, np.inf if mu * sup < 1.0 else -np.inf)
    raise AssertionError(f"no float μ with μ·{sup!r} == 1")


def test_mu_condition_11_fails_at_margin_exactly_0(recorded, example_spec):
    """(11) is strict, 1/μ > sup‖D‖²: μ·sup‖D‖² = 1 exactly (margin 0.0) fails, a margin of 1e-12 passes."""
    from amcp_drake.offline.checks import verify_design

    tr = _fresh(recorded)
    bound = example_spec.design.mu_state_bound
    mu0 = _mu_on_the_boundary(tr.problem, bound)
    for mu, margin, status in ((mu0, 0.0, "fail"), (mu0 * (1.0 - 1e-12), 1e-12, "pass")):
        design = dataclasses.replace(tr.design, mu=mu)
        out = next(c for c in verify_design(tr.problem, design, bound) if c.name == "mu condition (11)")
        assert out.margin == pytest.approx(margin, abs=1e-15) and out.status == status, (margin, out)


# -- design checks on a scalar system: x+ = (0.5 + 0.2θ)x + u + w, θ ∈ [−1, 1], |w| <= 0.1 (tests/conftest.py) ---------
# With one state, X0 = {|c x| <= 1} and A_cl(θ) = 0.5 + 0.2θ + K, every quantity of these checks is a number:
# spectral radius = λ̄ = max |0.5 ± 0.2 + K|, w̄ = 0.1 c, and (16) reads (a² − 1) P + Q + K R K <= 0 at both vertices.
EIG_TOL_REL = 1e-12       # (16), relative to the size of its terms


@pytest.fixture(scope="module")
def scalar():
    from amcp_drake.offline.design import design
    from tests.conftest import scalar_problem

    problem = scalar_problem()
    offline = design(problem, backend="drake")
    assert np.asarray(offline.H_x).shape == (2, 1)
    return problem, offline


def _design_check(problem, offline, name, **changes):
    from amcp_drake.offline.checks import verify_design

    return next(c for c in verify_design(problem, dataclasses.replace(offline, **changes)) if c.name == name)


@edge("design.assumption_8")
def assumption_8_at_factor(scalar, factor, status):
    """Tolerance 0 (strict): the outside case at spectral radius 1 + 1e-9, the inside case at 1 − 1e-9."""
    test_assumption_8_at_its_edge(scalar, 1e-9 if status == "fail" else -1e-9, status)


@pytest.mark.parametrize("delta, status", [(1e-9, "fail"), (-1e-9, "pass")])
def test_assumption_8_at_its_edge(scalar, delta, status):
    """Tolerance 0: K = 0.3 + δ puts the vertex θ = 1 at a = 1 + δ (spectral radius 1 + δ)."""
    problem, offline = scalar
    out = _design_check(problem, offline, "Assumption 8", K=np.array([[0.3 + delta]]))
    assert out.tolerance == 0.0 and out.margin == pytest.approx(-delta, rel=1e-6)
    assert out.status == status


def test_assumption_8_fails_at_spectral_radius_exactly_1(scalar):
    """Assumption 8 is strict (Schur stable: spectral radius < 1): K with a = 0.7 + K == 1.0 exactly at the
    vertex θ = 1 (margin 0.0) fails; the next float K whose a is below 1 (margin ~1e-16 > 0) passes."""
    problem, offline = scalar
    a_vertex = float(problem.A_of(np.array([1.0]))[0, 0])          # 0.5 + 0.2 at θ = 1; B = 1
    K = 1.0 - a_vertex
    assert a_vertex + K == 1.0 and abs(float(problem.A_of(np.array([-1.0]))[0, 0]) + K) < 1.0
    out = _design_check(problem, offline, "Assumption 8", K=np.array([[K]]))
    assert out.margin == 0.0 and out.status == "fail"
    inside = K
    while a_vertex + inside == 1.0:  # the next K below whose a is below 1 (a few ulps of 1)
        inside = np.nextafter(inside, -np.inf)
    assert 0.0 < 1.0 - (a_vertex + inside) < 1e-15
    out = _design_check(problem, offline, "Assumption 8", K=np.array([[inside]]))
    assert 0.0 < out.margin < 1e-15 and out.status == "pass"


@edge("design.x0_contractive")
def x0_contractive_at_its_edge(scalar, factor, status):
    """λ̄ = max |a| = 1 + factor × tol with K = 0.3 + factor × tol."""
    problem, offline = scalar
    out = _design_check(problem, offline, "X0 contractive", K=np.array([[0.3 + factor * VERTEX_TOL]]))
    _assert_edge(out, -factor * VERTEX_TOL, factor, VERTEX_TOL, status, rel=1e-6)


@edge("design.x0_robustly_invariant")
def x0_robustly_invariant_at_its_edge(scalar, factor, status):
    """max |a| + w̄ = 1 + factor × tol, w̄ = 0.1 c from X0 = {|c x| <= 1}."""
    problem, offline = scalar
    c = float(np.max(np.abs(offline.H_x)))
    K = 1.0 - 0.1 * c + factor * VERTEX_TOL - 0.7            # the vertex θ = 1: a = 0.7 + K
    out = _design_check(problem, offline, "X0 robustly invariant", K=np.array([[K]]))
    _assert_edge(out, -factor * VERTEX_TOL, factor, VERTEX_TOL, status, rel=1e-5)


@edge("design.terminal_cost_16")
def terminal_cost_16_at_its_edge(scalar, factor, status):
    """P = S / (1 − a² + factor·ε) with S = Q + K R K, a the larger |A_cl| and ε = EIG_TOL_REL: the largest
    eigenvalue of (16), S − (1 − a²) P, is then factor·ε·P, and P is the largest term (relative tolerance ε·P)."""
    problem, offline = scalar
    K = float(np.asarray(offline.K)[0, 0])
    a = max(abs(0.7 + K), abs(0.3 + K))
    S = 1.0 + K * K
    P = S / (1.0 - a * a + factor * EIG_TOL_REL)
    out = _design_check(problem, offline, "terminal cost (16)", P=np.array([[P]]))
    tol = EIG_TOL_REL * P
    assert out.tolerance == pytest.approx(tol, rel=1e-12)
    assert out.margin == pytest.approx(-factor * tol, rel=1e-3)
    assert out.status == status


@edge("design.x_f_non_empty")
def x_f_non_empty_at_its_edge(scalar, factor, status):
    """h_T scaled until the tube's steady state (0, α_∞), α_∞ = w̄ / (1 − λ̄) = 0.1 c / (1 − max |a|), meets
    max h_T α_∞ = 1 + factor × tol."""
    problem, offline = scalar
    c = float(np.max(np.abs(offline.H_x)))
    K = float(np.asarray(offline.K)[0, 0])
    alpha_inf = 0.1 * c / (1.0 - max(abs(0.7 + K), abs(0.3 + K)))
    h_T = np.asarray(offline.h_T, float)
    h_T = h_T * (1.0 + factor * VERTEX_TOL) / (float(np.max(h_T)) * alpha_inf)
    out = _design_check(problem, offline, "X_f non-empty", h_T=h_T)
    _assert_edge(out, -factor * VERTEX_TOL, factor, VERTEX_TOL, status, rel=1e-5)


@edge("design.x_f_in_z")
def x_f_in_z_at_its_edge(scalar, factor, status):
    """X_f = {H_T z + h_T α <= 1, α >= 0} is a cone cut at 1: its rows divided by 1 + s scale it by 1 + s, and
    the largest (F + G K)(z + α x^j) over its vertices with this file's enumeration, M, by 1 + s as well. s is
    chosen so that (1 + s) M = 1 + factor × tol."""
    problem, offline = scalar
    H_T, h_T = np.asarray(offline.H_T, float), np.asarray(offline.h_T, float)
    verts = _vertices(np.vstack([np.column_stack([H_T, h_T]), [[0.0, -1.0]]]), np.r_[np.ones(len(H_T)), 0.0])
    FGK = np.asarray(problem.F, float) + np.asarray(problem.G, float) @ np.asarray(offline.K, float)
    X0 = np.asarray(offline.X0_vertices, float)
    M = max(float(np.max(FGK @ (v[:1] + v[1] * x))) for v in verts for x in X0)
    assert 0.5 < M <= 1.0 + 1e-9
    scale = (1.0 + factor * VERTEX_TOL) / M
    out = _design_check(problem, offline, "X_f in Z", H_T=H_T / scale, h_T=h_T / scale)
    _assert_edge(out, -factor * VERTEX_TOL, factor, VERTEX_TOL, status, rel=1e-4)


# -- Section 4.2: persistent excitation (Example 1 with a PE window of 5 and level 0.2, 25 steps) ---------------------
PE_LEVEL_TOL = 1e-6       # relative to max(1, pe_level)
PE_BOUND_TOL = 1e-7       # relative to max(1, |bound|)
PE_WINDOW = 5


@pytest.fixture(scope="module")
def pe_recorded(example_spec, example_design) -> dict:
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design,
                       options=OnlineOptions(update="fixed", pe_window=PE_WINDOW, pe_level=0.2))
    traj = simulate(ctrl, sc.x0, sc.theta_star, 25, "uniform", seed=2, mu_state_bound=example_spec.design.mu_state_bound)
    assert traj.stop_reason == "completed"
    return as_recorded(traj)


def _gram(u: np.ndarray, k: int, dim: int) -> np.ndarray:
    """Σ_{j=k−P+1}^{k} ū_j ū_jᵀ with ū_j = (u_j, u_(j−1), …, u_(j−dim+1)) (this file's own indexing)."""
    rows = [u[j - dim + 1:j + 1][::-1] for j in range(k - PE_WINDOW + 1, k + 1)]
    return sum(np.outer(r, r) for r in rows)


def _pe_margins(tr) -> dict[int, float]:
    u = np.asarray(tr.u, float)[:, 0]
    return {r.k: (float(np.linalg.eigvalsh(_gram(u, r.k, r.pe_dim))[0]) - r.pe_level) / max(1.0, abs(r.pe_level))
            for r in tr.records[:-1] if r.pe_status.startswith("enforced")}


def _relative_bound(value: float, factor: float, tol: float, above: bool) -> float:
    """The bound b with (b − value)/max(1, |b|) = −factor·tol (above: b below value, an upper bound violated) or
    (value − b)/max(1, |b|) = −factor·tol (a lower bound above value)."""
    t = factor * tol
    candidate = value - t if above else value + t
    if abs(candidate) <= 1.0:
        return candidate
    return value / (1.0 + t) if (value > 0) == above else value / (1.0 - t)


@edge("pe_level")
def pe_level_at_its_edge(pe_recorded, factor, status):
    from amcp_drake.certificate.section4 import pe_level

    tr = _fresh(pe_recorded)
    margins = _pe_margins(tr)
    assert len(margins) > 5 and min(margins.values()) > -0.25 * PE_LEVEL_TOL
    k = max(margins)
    r = tr.records[k]
    lam = float(np.linalg.eigvalsh(_gram(np.asarray(tr.u, float)[:, 0], k, r.pe_dim))[0])
    r.pe_level = _relative_bound(lam, factor, PE_LEVEL_TOL, above=False)   # a level above λ_min
    margin = _pe_margins(tr)[k]
    out = pe_level(_view(tr))
    assert out.data["worst_step"] == k
    _assert_edge(out, margin, factor, PE_LEVEL_TOL, status, rel=1e-6)


@edge("pe_bounds")
def pe_bounds_at_their_edge(pe_recorded, factor, status):
    from amcp_drake.certificate.section4 import pe_bounds

    tr = _fresh(pe_recorded)
    k = max(r.k for r in tr.records[:-1] if r.pe_bounds is not None and np.isfinite(r.pe_bounds[1]))
    uk = float(tr.u[k][0])
    r = tr.records[k]
    hi = _relative_bound(uk, factor, PE_BOUND_TOL, above=True)
    r.pe_bounds = (min(float(r.pe_bounds[0]), hi), hi)
    margin = (hi - uk) / max(1.0, abs(hi))
    out = pe_bounds(_view(tr))
    assert out.data["worst_step"] == k
    _assert_edge(out, margin, factor, PE_BOUND_TOL, status, rel=1e-6)


def _x_f_invariance_margin(offline) -> float:
    """min over the vertices (z, α) of X_f of: 1 − max(H_T z⁺ + h_T α⁺), α⁺, and α⁺ − max_(θ, x^j, w) H_x(A_cl(θ)(z + α x^j)
    + w − z⁺), with z⁺ = A_z z and α⁺ = φ(z, α) = max_(θ, i) [H_x (A_cl(θ) − A_z) z]_i + h̄_i(θ) α + w̄_i (this file's
    enumeration of X_f, of the two vertices of Θ and of W = [−0.1, 0.1])."""
    K = float(np.asarray(offline.K)[0, 0])
    A_z = np.asarray(offline.A_z, float)
    H_x, X0 = np.asarray(offline.H_x, float), np.asarray(offline.X0_vertices, float)
    W = np.array([[0.1], [-0.1]])
    A = [np.array([[0.5 + s * 0.2 + K]]) for s in (1.0, -1.0)]
    w_bar = np.max(H_x @ W.T, axis=1)
    H_T, h_T = np.asarray(offline.H_T, float), np.asarray(offline.h_T, float)
    worst = np.inf
    for v in _vertices(np.vstack([np.column_stack([H_T, h_T]), [[0.0, -1.0]]]), np.r_[np.ones(len(H_T)), 0.0]):
        z, a = v[:1], v[1]
        a_next = max(float(np.max(H_x @ (Ak - A_z) @ z + np.max(H_x @ Ak @ X0.T, axis=1) * a + w_bar)) for Ak in A)
        z_next = A_z @ z
        member = min(1.0 - float(np.max(H_T @ z_next + h_T * a_next)), a_next)
        inclusion = a_next - max(float(np.max(H_x @ (Ak @ (z + a * x) + w - z_next))) for Ak in A for x in X0 for w in W)
        worst = min(worst, member, inclusion)
    return worst


@edge("design.x_f_invariant")
def x_f_invariant_at_its_edge(scalar, factor, status):
    """The terminal dynamics A_z of the design raised until z⁺ = A_z z carries a vertex of X_f out of it by
    factor × tol (the inclusion part is 0 by the definition of φ; the membership part moves with A_z)."""
    problem, offline = scalar
    base = float(np.asarray(offline.A_z)[0, 0])
    assert _x_f_invariance_margin(offline) > -1e-12

    def violation(s):
        return -_x_f_invariance_margin(dataclasses.replace(offline, A_z=np.array([[base + s]])))

    s = _bisect(violation, factor * VERTEX_TOL, hi=1.0)
    out = _design_check(problem, offline, "X_f invariant", A_z=np.array([[base + s]]))
    _assert_edge(out, -violation(s), factor, VERTEX_TOL, status, rel=1e-6)


@pytest.mark.parametrize("mu, status", [(1.0, "fail"), (1.0 - 1e-12, "pass"), (1.0 + 1e-12, "fail")])
def test_the_property_suites_11_check_is_strict_on_z(mu, status):
    """The property suite's (11) on the scalar system (Z bounded: |x| <= 5, |u| <= 2, D(x, u) = 0.2 x, so
    sup_Z ‖D‖² = 1 exactly): μ = 1 (margin 0) fails, 1 − 1e-12 passes, 1 + 1e-12 fails; the visited states
    (|x| <= 1) are far inside."""
    from types import SimpleNamespace

    from amcp_properties.claims import lms_precondition
    from tests.conftest import scalar_problem

    assert (0.2 * 5.0) ** 2 == 1.0
    traj = SimpleNamespace(problem=scalar_problem(), design=SimpleNamespace(mu=mu),
                           x=np.array([[1.0], [0.5], [0.2]]), u=np.array([[0.1], [0.0]]))
    out = lms_precondition(traj)
    assert out.margin == pytest.approx(1.0 - mu, abs=1e-15) and out.status == status
