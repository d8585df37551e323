"""The paper's claims as checks on a recorded closed loop, with numpy/scipy only.

Every function takes a :class:`amcp_drake.online.simulate.Trajectory` (or a problem and its design) and
returns an :class:`amcp_drake.model.check_result.CheckResult`: ``margin`` >= −``tolerance`` means the claim
holds on this run. Nothing here calls an optimisation backend or trusts a solver's multipliers:
sets are handled by vertex enumeration (Qhull) or, for sets with empty interior, HiGHS LPs
(:mod:`amcp_properties.geometry`); Δ_k, D(x,u), w̄ and f̄ are recomputed from their definitions.

Claims (spec numbering): Theorem 14 (i), (ii), (iii); Lemma 3 (10); Lemma 5 and its
precondition (11); Proposition 9 ((5a)-(5c) for the QP solution); Assumption 11 for X_f;
Corollary 16; the finite ℓ2 gain (22) (see :func:`l2_gain_ratios` for what it can show).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from amcp_drake.model import polytope
from amcp_drake.model.check_result import CheckResult, judge
from amcp_drake.model.status import SolveStatus
from amcp_drake.model.tolerances import LEMMA5_REL_TOL, PROJECTION_TOL, SET_TOL, TUBE_TOL
from amcp_drake.online.answers import qp_applied, rejected

from .geometry import delta_set, maxima, regressor, signed_chebyshev_radius, unit_rows, vertices
from .nversion import second_method

# Tolerances (model.tolerances, shared with the certificate's claims of the same ids): TUBE_TOL for the
# constraint margins of the QP (20) solution re-evaluated at the vertices of the tube, Θ_k, X0 and W (worst
# margins measured on 150 generated 20-step runs per backend, seed 31: -1.5e-7 Drake, -3e-10 cvxpy); SET_TOL
# for the set-membership margins θ* ∈ Θ_k and Lemma 3 (same runs: -2.2e-8, -3.9e-8); PROJECTION_TOL for
# θ̂_k ∈ Θ; LEMMA5_REL_TOL for this module's relative form of Lemma 5.
#: Row norms below this are not rescaled to unit norm (rescaling would amplify the round-off of
#: the right-hand side 1 + H_w d, ~1e-16, beyond 1e-10).
UNIT_ROW_MIN_NORM = 1e-6


def _theta_k(record) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(record.H_theta, float), np.asarray(record.h_theta, float)


def _x0_vertices(design) -> np.ndarray:
    H_x = np.asarray(design.H_x, float)
    return vertices(H_x, np.ones(len(H_x)))


def _w_vertices(problem) -> np.ndarray:
    return vertices(problem.H_w, np.ones(len(problem.H_w)))


def _prior_vertices(problem) -> np.ndarray:
    return vertices(problem.H_theta, problem.h_theta)


def _solved(traj) -> list[int]:
    """Steps k whose record holds an applied, checked answer of the QP (20): the backend's own or a checked
    fallback of the other formulation (:func:`amcp_drake.online.answers.qp_applied`, as the certificate:
    docs/decisions.md, "Verified solver answers"); its constraints are re-checked by the claims."""
    return [r.k for r in traj.records if qp_applied(r) and r.v is not None]


def _scaled_rows(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norms = np.linalg.norm(H, axis=1)
    scale = np.where(norms >= UNIT_ROW_MIN_NORM, norms, 1.0)
    return H / scale[:, None], h / scale


# -- Theorem 14 -----------------------------------------------------------------------------------
def tube_constraint_margins(traj, k: int, w_vertices: np.ndarray | None = None) -> dict[str, float]:
    """Margins of every constraint of 𝔻(x_k, Θ_k) at the recorded decision (z, α, v) of step k,
    without Λ: (15b) x_k ∈ X_{0|k}; (5c) (x, Kx + v_l) ∈ Z at every vertex x of X_{l|k}; (5b)
    X_{l+1|k} ⊇ A(θ)x + B(θ)(Kx + v_l) + w for every vertex x of X_{l|k}, θ of Θ_k and w of W
    (by Proposition 9 this is (15c)-(15d)); (z_N, α_N) ∈ X_f; α >= 0. Positive = satisfied."""
    pr, des, r = traj.problem, traj.design, traj.records[k]
    K, H_x = np.asarray(des.K, float), np.asarray(des.H_x, float)
    Xv = _x0_vertices(des)
    Wv = _w_vertices(pr) if w_vertices is None else w_vertices
    z, alpha, v = np.asarray(r.z, float), np.asarray(r.alpha, float), np.asarray(r.v, float)
    N = len(v)
    tube = z[:N, None, :] + alpha[:N, None, None] * Xv[None, :, :]       # (N, nv, n) vertices of X_{l|k}
    inputs = tube @ K.T + v[:, None, :]                                  # (N, nv, m)
    out = {"(15b) x_k in X_0|k": float(alpha[0] - np.max(H_x @ (r.x - z[0])))}
    out["(5c) tube in Z"] = float(np.min(1.0 - tube @ pr.F.T - inputs @ pr.G.T))
    H, h = _theta_k(r)
    theta_k = maxima(H, h)
    nominal = tube @ pr.A0.T + inputs @ pr.B0.T                          # (N, nv, n)
    D = np.stack([tube @ Ai.T + inputs @ Bi.T for Ai, Bi in zip(pr.A, pr.B)], axis=-1)  # (N, nv, n, p)
    HxD = np.einsum("in,ljnp->ljip", H_x, D)                             # (N, nv, u, p)
    if theta_k.vertices is not None:
        worst_theta = np.max(HxD @ theta_k.vertices.T, axis=-1)          # (N, nv, u)
    else:
        worst_theta = theta_k.max(HxD.reshape(-1, HxD.shape[-1])).reshape(HxD.shape[:-1])
    worst_w = np.max(H_x @ Wv.T, axis=1)                                 # (u,) = w̄ from W's vertices
    lhs = nominal @ H_x.T + worst_theta + worst_w - (z[1:N + 1] @ H_x.T)[:, None, :]
    out["(5b) tube propagation"] = float(np.min(alpha[1:N + 1, None, None] - lhs))
    out["terminal set"] = float(np.min(1.0 - des.H_T @ z[N] - des.h_T * alpha[N]))
    out["alpha >= 0"] = float(np.min(alpha))
    out["_theta_method"] = theta_k.method
    return out


@second_method("recursive_feasibility")
def recursive_feasibility(traj) -> CheckResult:
    """Theorem 14 (i): 𝔻(x_k, Θ_k) ≠ ∅ at every step k of the run.

    Certified by the recorded QP solution of every step, re-checked without Λ
    (:func:`tube_constraint_margins`); a step without an applied, checked answer of (20) (:func:`_solved`:
    a checked fallback of the other formulation counts, as in the certificate; whose answer it was is
    counted in the coverage's answers, not here), an inconsistent-data stop or an early end fails the claim."""
    claim = "Theorem 14 (i): the QP (20) is feasible at every step (recursive feasibility)"
    planned = len(traj.x) - 1
    solved = set(_solved(traj))
    bad = [r.k for r in traj.records if r.k not in solved]
    if traj.stop_reason != "completed" or bad:
        where = f"steps {bad}" if bad else ""
        return judge("Theorem 14 (i)", claim, -np.inf, TUBE_TOL,
                     f"run ended: {traj.stop_reason} {where}; {planned} transitions, {len(traj.records)} records")
    worst, where = np.inf, ""
    for k in _solved(traj):
        margins = tube_constraint_margins(traj, k)
        for name, value in margins.items():
            if not name.startswith("_") and value < worst:
                worst, where = value, f"step {k}, {name} (Θ_k by {margins['_theta_method']})"
    return judge("Theorem 14 (i)", claim, worst, TUBE_TOL, f"worst constraint margin of 𝔻(x_k,Θ_k) at {where}")


def backend_answers(traj) -> CheckResult:
    """Not a claim of the paper: every answer of the run was the backend's own (first or re-solved), none
    rejected by the answer checks (:func:`amcp_drake.online.answers.rejected`). A rejected answer replaced by a
    checked fallback keeps Theorem 14 (:func:`recursive_feasibility`); it is a backend defect, reported here
    (the mutants' runner lists it; the certificate's ``solver_answers``). Margin: −(number of rejected answers)."""
    bad = [(r.k, e["problem"], e["outcome"], e["kind"]) for r in traj.records for e in (r.answers or ()) if rejected(e)]
    detail = f"{len(bad)} answers rejected by the answer checks" + (f"; first: step {bad[0][0]}, {bad[0][1:]}" if bad else "")
    return judge("answer checks", "every answer of the run is the backend's own (none rejected by the answer checks)",
                 float(-len(bad)), 0.0, detail)


@second_method("theta_star_in_Theta_k")
def theta_star_in_sets(traj) -> CheckResult:
    """Theorem 14 (ii), first part: θ* ∈ Θ_k for every recorded k (unit rows, distance margin).
    A stop on "inconsistent data" (Θ_{k-1} ∩ Δ_k = ∅) contradicts it: θ* lies in both."""
    claim = "Theorem 14 (ii): θ* ∈ Θ_k for all k"
    if traj.stop_reason.startswith("inconsistent data"):
        return judge("Theorem 14 (ii) θ*", claim, -np.inf, SET_TOL,
                     f"{traj.stop_reason}: the controller found Θ_(k-1) ∩ Δ_k empty although θ* lies in it")
    worst, at = np.inf, -1
    for r in traj.records:
        H, h = unit_rows(*_theta_k(r))
        margin = float(np.min(h - H @ traj.theta_star_at(r.k)))
        if margin < worst:
            worst, at = margin, r.k
    return judge("Theorem 14 (ii) θ*", claim, worst, SET_TOL, f"min distance of θ* inside Θ_k, at step {at}")


@second_method("theta_hat_in_Theta")
def theta_hat_in_prior(traj) -> CheckResult:
    """Theorem 14 (ii), second part: θ̂_k ∈ Θ for every recorded k (the problem's Θ, unit rows)."""
    pr = traj.problem
    H, h = unit_rows(pr.H_theta, pr.h_theta)
    margins = [(float(np.min(h - H @ r.theta_hat)), r.k) for r in traj.records]
    worst, at = min(margins)
    return judge("Theorem 14 (ii) θ̂", "Theorem 14 (ii): θ̂_k ∈ Θ for all k", worst, PROJECTION_TOL,
                 f"min distance of θ̂_k inside Θ, at step {at}")


@second_method("state_input_constraints")
def constraints_satisfied(traj) -> CheckResult:
    """Theorem 14 (iii): F x_k + G u_k <= 1 for every applied input, eq. (4)."""
    pr = traj.problem
    if len(traj.u) == 0:
        return judge("Theorem 14 (iii)", "Theorem 14 (iii): (x_k, u_k) ∈ Z", None, TUBE_TOL, "no input was applied")
    slack = 1.0 - traj.x[:len(traj.u)] @ pr.F.T - traj.u @ pr.G.T
    k, i = np.unravel_index(np.argmin(slack), slack.shape)
    return judge("Theorem 14 (iii)", "Theorem 14 (iii): (x_k, u_k) ∈ Z for all k", float(slack[k, i]), TUBE_TOL,
                 f"min_i (1 − F x_k − G u_k)_i at step {k}, row {i}")


# -- Lemma 3 --------------------------------------------------------------------------------------
def _valid_set(traj, k: int) -> bool:
    r = traj.records[k]
    return k == 0 or r.set_status is SolveStatus.OPTIMAL


@second_method("Theta0_contains_Theta", "Theta_k_nested", "Theta_k_lower_inclusion")
def set_inclusions(traj) -> CheckResult:
    """Lemma 3, (10): Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1} ⊆ Θ_k, and its premise Θ ⊆ Θ_0.

    Δ_{k+1} is rebuilt from (x_k, u_k, x_{k+1}) by (6). For the moving window of Remark 4 the
    update intersects the last M data sets, so the left side is Θ_k ∩ Δ_{k+1} ∩ ... ∩ Δ_{k+2−M}
    ("without changing the results": for M = 1 it is (10)). Maxima by vertices or LPs
    (:class:`PolytopeMaxima`), margins in unit-row (distance) units."""
    claim = "Lemma 3 (10): Θ_k ∩ Δ_(k+1) ⊆ Θ_(k+1) ⊆ Θ_k, with Θ ⊆ Θ_0"
    pr, recs = traj.problem, traj.records
    window = traj.options.window if traj.options.update == "window" else 1
    H0, h0 = unit_rows(*_theta_k(recs[0]))
    worst = float(np.min(h0 - np.max(H0 @ _prior_vertices(pr).T, axis=1)))
    where = "premise Θ ⊆ Θ_0"
    for k in range(min(len(recs) - 1, len(traj.u))):
        if not (_valid_set(traj, k) and _valid_set(traj, k + 1)):
            continue
        Ha, ha = unit_rows(*_theta_k(recs[k]))
        Hb, hb = unit_rows(*_theta_k(recs[k + 1]))
        upper = float(np.min(ha - maxima(Hb, hb).max(Ha)))
        if upper < worst:
            worst, where = upper, f"Θ_{k + 1} ⊆ Θ_{k} at step {k + 1}"
        rows_H, rows_h = [Ha], [ha]
        for j in range(k, max(k - window, -1), -1):
            Hd, hd = _scaled_rows(*delta_set(pr, traj.x[j], traj.u[j], traj.x[j + 1]))
            rows_H.append(Hd)
            rows_h.append(hd)
        left = maxima(np.vstack(rows_H), np.concatenate(rows_h))
        if left.empty:
            # θ* lies in both sets, so emptiness can only be round-off in Θ_k: its size is the margin.
            # The LP's own primal tolerance (1e-7 in HiGHS) is SET_TOL's size, so θ* is a witness:
            # its largest violation of the unit rows bounds the signed radius from below.
            radius = _signed_radius_with_witness(np.vstack(rows_H), np.concatenate(rows_h), traj.theta_star)
            if radius < worst:
                worst, where = radius, f"Θ_{k} ∩ Δ_{k + 1} empty by {-radius:.2e} at step {k + 1} (θ* lies in both)"
            continue
        lower = float(np.min(hb - left.max(Hb)))
        if lower < worst:
            worst, where = lower, f"Θ_{k} ∩ Δ_{k + 1} ⊆ Θ_{k + 1} at step {k + 1} ({left.method})"
    return judge("Lemma 3", claim, worst, SET_TOL, f"worst inclusion margin: {where}"
                 + (f"; window M = {window}" if window > 1 else ""))


def _signed_radius_with_witness(H: np.ndarray, h: np.ndarray, witness: np.ndarray) -> float:
    """The signed Chebyshev radius of {H θ <= h} (unit rows), never below −(the witness's largest
    violation): a point that violates every row by at most v puts the rows' common point within v."""
    Hn, hn = polytope.normalize_rows(H, h)
    by_witness = -float(np.max(Hn @ np.asarray(witness, float) - hn))
    radius = signed_chebyshev_radius(H, h)
    return by_witness if np.isnan(radius) else max(radius, by_witness)


# -- Lemma 5 and (11) -----------------------------------------------------------------------------
@second_method("mu_precondition")
def lms_precondition(traj) -> CheckResult:
    """The gain condition used by Lemma 5: μ ‖D(x,u)‖₂² < 1 on Z, eq. (11) (recomputed at the
    vertices of Z, ‖D‖₂ being convex in (x,u)), and μ ‖D_k‖₂² <= 1 at every visited (x_k, u_k)."""
    pr, mu = traj.problem, float(traj.design.mu)
    claim = "(11): 1/μ > sup_Z ‖D(x,u)‖², and μ‖D_k‖² <= 1 along the run"
    H = np.hstack([pr.F, pr.G])
    visited = [float(np.linalg.norm(regressor(pr, x, u), 2) ** 2) for x, u in zip(traj.x, traj.u)]
    margin = 1.0 - mu * max(visited, default=0.0)
    strict = False  # μ‖D_k‖² <= 1 along the run is what (13) needs; (11) itself is strict
    detail = f"μ = {mu:.4g}, max_k ‖D_k‖² = {max(visited, default=0.0):.4g}"
    if polytope.is_bounded(H, np.ones(len(H))):
        verts = polytope.vertices(H, np.ones(len(H)))
        sup = max(float(np.linalg.norm(regressor(pr, vx[:pr.n], vx[pr.n:]), 2) ** 2) for vx in verts)
        if 1.0 - mu * sup <= margin:
            margin, strict = 1.0 - mu * sup, True
        detail += f", sup_Z ‖D‖² = {sup:.4g}"
    return judge("(11)", claim, margin, 0.0, detail, strict=strict)


@second_method("lemma5")
def lms_inequality(traj) -> CheckResult:
    """Lemma 5, the exact inequality proved by (13), for every m:

    (1/μ)‖θ̂_{m+1} − θ*‖² + Σ_{k<=m} ‖x̃_{1|k}‖² <= (1/μ)‖θ̂_0 − θ*‖² + Σ_{k<=m} ‖w_k‖²,

    with x̃_{1|k} = D_k (θ* − θ̂_k) from the recorded θ̂_k and (x_k, u_k), and the applied w_k."""
    pr, mu, ts = traj.problem, float(traj.design.mu), traj.theta_star
    claim = "Lemma 5: (1/μ)‖θ̂_(m+1)−θ*‖² + Σ‖x̃_(1|k)‖² <= (1/μ)‖θ̂_0−θ*‖² + Σ‖w_k‖² for every m"
    hats = [np.asarray(r.theta_hat, float) for r in traj.records]
    steps = min(len(traj.u), len(hats) - 1)
    if steps == 0:
        return judge("Lemma 5", claim, None, LEMMA5_REL_TOL, "fewer than two estimates recorded")
    err = [float(np.sum((regressor(pr, traj.x[k], traj.u[k]) @ (ts - hats[k])) ** 2)) for k in range(steps)]
    wsq = [float(np.sum(traj.w[k] ** 2)) for k in range(steps)]
    start = float(np.sum((hats[0] - ts) ** 2)) / mu
    worst, at = np.inf, -1
    for m in range(steps):
        lhs = float(np.sum((hats[m + 1] - ts) ** 2)) / mu + sum(err[:m + 1])
        rhs = start + sum(wsq[:m + 1])
        margin = (rhs - lhs) / (1.0 + rhs)
        if margin < worst:
            worst, at = margin, m
    return judge("Lemma 5", claim, worst, LEMMA5_REL_TOL, f"relative margin (rhs − lhs)/(1 + rhs), worst at m = {at}")


# -- Proposition 9 --------------------------------------------------------------------------------
@second_method("tube_contains_state", "tube_contains_next_state", "tube_propagation", "tube_constraints")
def prediction_tube(traj) -> CheckResult:
    """Proposition 9 ("⇐": (15) implies (5a)-(5c)) on every solved step k:

    * x_k ∈ X_{0|k} (5a) and the realised x_{k+1} ∈ X_{1|k};
    * X_{l+1|k} ∋ A(θ)x + B(θ)(Kx + v_l) + w for every vertex x of X_{l|k}, every vertex θ of
      Θ_k and every vertex w of W (5b), by enumeration (not through Λ or w̄; when Θ_k has empty
      interior its maxima come from LPs, see :class:`PolytopeMaxima`);
    * (x, Kx + v_l) ∈ Z at every vertex x of X_{l|k} (5c).
    Margins in the units of H_x (α units) and of Z's rows."""
    pr, des = traj.problem, traj.design
    claim = "Proposition 9: x_k ∈ X_0|k, x_(k+1) ∈ X_1|k, A_cl(θ)X_l|k ⊕ B(θ)v_l ⊕ W ⊆ X_(l+1)|k on vert Θ_k, W"
    H_x, K = np.asarray(des.H_x, float), np.asarray(des.K, float)
    Xv, Wv = _x0_vertices(des), _w_vertices(pr)
    worst, where = np.inf, "no solved step"
    for k in _solved(traj):
        r = traj.records[k]
        z, alpha, v = np.asarray(r.z, float), np.asarray(r.alpha, float), np.asarray(r.v, float)
        N = len(v)
        checks = {"x_k ∈ X_0|k": float(alpha[0] - np.max(H_x @ (r.x - z[0])))}
        if k + 1 < len(traj.x):
            checks["realised x_(k+1) ∈ X_1|k"] = float(alpha[1] - np.max(H_x @ (traj.x[k + 1] - z[1])))
        theta_k = maxima(*_theta_k(r))
        tube = z[:N, None, :] + alpha[:N, None, None] * Xv[None, :, :]
        inputs = tube @ K.T + v[:, None, :]
        checks["(5c) tube in Z"] = float(np.min(1.0 - tube @ pr.F.T - inputs @ pr.G.T))
        if theta_k.vertices is not None:
            T = theta_k.vertices
            A_t = pr.A0[None] + np.tensordot(T, pr.A, axes=1)            # (vp, n, n)
            B_t = pr.B0[None] + np.tensordot(T, pr.B, axes=1)            # (vp, n, m)
            images = (np.einsum("tab,ljb->ltja", A_t, tube) + np.einsum("tab,ljb->ltja", B_t, inputs))
            images = images[:, :, :, None, :] + Wv[None, None, None, :, :]   # (N, vp, nv, vw, n)
            rel = (images - z[1:N + 1, None, None, None, :]) @ H_x.T          # (N, vp, nv, vw, u)
            margin = float(np.min(alpha[1:N + 1, None, None, None, None] - rel))
        else:
            margin = tube_constraint_margins(traj, k, Wv)["(5b) tube propagation"]
        checks[f"(5b) images under vert Θ_k ({theta_k.method}), vert W"] = margin
        for name, value in checks.items():
            if value < worst:
                worst, where = value, f"step {k}: {name}"
    return judge("Proposition 9", claim, worst, TUBE_TOL, f"worst margin at {where}")


# -- Assumption 11 --------------------------------------------------------------------------------
@second_method("design.x_f_non_empty", "design.x_f_invariant", "design.x_f_in_z")
def terminal_set_invariance(problem, design) -> CheckResult:
    """Assumption 11 for X_f = {(z, α) | H_T z + h_T α <= 1, α >= 0}, without the design's witness:

    * X_f ≠ ∅ (it has vertices);
    * (x, Kx) ∈ Z for x ∈ {z} ⊕ αX0 at every vertex (z, α) of X_f;
    * for every vertex (z, α) of X_f, an LP finds (z⁺, α⁺) ∈ X_f with
      A_cl(θ)({z} ⊕ αX0) ⊕ W ⊆ {z⁺} ⊕ α⁺X0 for every vertex θ of Θ (hence all θ ∈ Θ, the
      left side being affine in θ), enumerating the vertices of X0 and W.
    Vertex witnesses suffice: a convex combination of witnesses is a witness of the combination."""
    claim = "Assumption 11: X_f ≠ ∅, in Z under u = Kx, and robustly invariant for every vertex of Θ"
    n = problem.n
    H_T, h_T = np.asarray(design.H_T, float), np.asarray(design.h_T, float)
    H = np.vstack([np.column_stack([H_T, h_T]), np.r_[np.zeros(n), -1.0]])
    h = np.r_[np.ones(len(H_T)), 0.0]
    try:
        verts = polytope.vertices(H, h)
    except ValueError as exc:
        return judge("Assumption 11", claim, -np.inf, TUBE_TOL, f"X_f is empty, flat or unbounded: {exc}")
    H_x, K = np.asarray(design.H_x, float), np.asarray(design.K, float)
    Xv, Wv, Tv = _x0_vertices(design), _w_vertices(problem), _prior_vertices(problem)
    A_cl = np.array([problem.A_of(t) + problem.B_of(t) @ K for t in Tv])
    FGK = problem.F + problem.G @ K
    w_part = np.max(H_x @ Wv.T, axis=1)
    worst, where = np.inf, ""
    # LP in (z⁺, α⁺, t): maximise t s.t. c_i − [H_x z⁺]_i − α⁺ + t <= 0, H_T z⁺ + h_T α⁺ + t <= 1, α⁺ >= 0
    A_inv = np.hstack([-H_x, -np.ones((len(H_x), 1)), np.ones((len(H_x), 1))])
    A_term = np.hstack([H_T, h_T[:, None], np.ones((len(H_T), 1))])
    cost = np.zeros(n + 2)
    cost[-1] = -1.0
    bounds = [(None, None)] * n + [(0.0, None), (None, 1.0)]
    for vert in verts:
        z, alpha = vert[:n], vert[n]
        pts = z[None, :] + alpha * Xv                                      # vertices of {z} ⊕ αX0
        in_Z = float(np.min(1.0 - pts @ FGK.T))
        if in_Z < worst:
            worst, where = in_Z, f"(x, Kx) ∈ Z at X_f vertex {np.round(vert, 6).tolist()}"
        c = np.max(np.einsum("in,tnm,jm->tji", H_x, A_cl, pts), axis=(0, 1)) + w_part
        res = linprog(cost, A_ub=np.vstack([A_inv, A_term]), b_ub=np.r_[-c, np.ones(len(H_T))],
                      bounds=bounds, method="highs")
        margin = float(res.x[-1]) if res.status == 0 else -np.inf
        if margin < worst:
            worst, where = margin, f"no successor (z⁺, α⁺) ∈ X_f for X_f vertex {np.round(vert, 6).tolist()}"
    return judge("Assumption 11", claim, worst, TUBE_TOL, f"{len(verts)} vertices of X_f; worst: {where}")


# -- Corollary 16 and (22) ------------------------------------------------------------------------
def state_norms(traj) -> np.ndarray:
    """‖x_k‖ for k = 0..T."""
    return np.linalg.norm(traj.x, axis=1)


def l2_gain_ratios(traj) -> np.ndarray:
    """r_K = Σ_{k<=K} ‖x_k‖² / (‖x_0‖² + ‖θ̂_0 − θ*‖² + Σ_{k<=K} ‖w_k‖²) for K = 0..T−1.

    (22) says r_K <= max(c0, c1, c2) for every K. A finite run can never show that constants
    exist; it can only show that the ratio does not keep growing (see the finite-gain test)."""
    x2 = np.sum(traj.x[:len(traj.w)] ** 2, axis=1)
    w2 = np.sum(traj.w ** 2, axis=1)
    start = float(np.sum(traj.x[0] ** 2) + np.sum((traj.records[0].theta_hat - traj.theta_star) ** 2))
    return np.cumsum(x2) / (start + np.cumsum(w2))


#: Corollary 16 gives no rate. After w stops at step k1, the test expects ‖x_T‖ to fall to a
#: fraction max(1e-6, ρ̄^((T − k1 − N)/2)) of max_{k>=k1} ‖x_k‖, where ρ̄ = max_{θ ∈ vert Θ} ρ(A_cl(θ))
#: is the rate that Assumption 8 gives the feedback K alone: half the exponent of that rate, after
#: N steps for the horizon to empty. Measured on 120 generated runs: the state reaches 1e-6 in
#: (1.0 ± 0.2)·log(1e-6)/log(ρ̄) steps.
CONVERGENCE_TARGET = 1e-6
#: Below this norm the state is at the accuracy of the QP solutions (runs settle at 1e-11..1e-13).
#: The QPs fix the inputs v to an accuracy in input units, which reaches the state through B(θ); so
#: the floor is CONVERGENCE_FLOOR·max(1, max_θ ‖B(θ)‖₂) over the vertices of Θ (a generated
#: problem in state units 100 times smaller, ‖B‖ ≈ 100, settled at ‖x‖ = 2.5e-8, above 1e-8; the same
#: problem in its drawn units settles 100 times lower). Unchanged (1e-8) wherever ‖B(θ)‖ <= 1.
CONVERGENCE_FLOOR = 1e-8


def rate_of_feedback(problem, design) -> float:
    """ρ̄ = max over the vertices θ of Θ of the spectral radius of A(θ) + B(θ)K (Assumption 8)."""
    K = np.asarray(design.K, float)
    return max(float(np.max(np.abs(np.linalg.eigvals(problem.A_of(t) + problem.B_of(t) @ K))))
               for t in _prior_vertices(problem))


def convergence_after_disturbance(traj, zero_from: int) -> CheckResult:
    """Corollary 16 on a run whose disturbance is zero from step ``zero_from`` on (finite energy):
    x_k → 0, checked as ‖x_T‖ <= φ·max_{k>=k1}‖x_k‖ + floor with φ as in CONVERGENCE_TARGET's comment.
    What a finite run cannot show: convergence itself (only decay by the expected factor)."""
    claim = "Corollary 16: w_k = 0 for k >= k1 implies x_k -> 0"
    if traj.stop_reason != "completed":
        return judge("Corollary 16", claim, -np.inf, 0.0, f"run ended early: {traj.stop_reason}")
    if np.any(traj.w[zero_from:] != 0.0):
        return judge("Corollary 16", claim, None, 0.0, "the disturbance is not zero after k1")
    norms = state_norms(traj)
    T, N = len(norms) - 1, traj.problem.N
    rho = rate_of_feedback(traj.problem, traj.design)
    exponent = max(T - zero_from - N, 0) / 2.0
    fraction = max(CONVERGENCE_TARGET, rho ** exponent) if exponent > 0 else 1.0
    ref = float(np.max(norms[zero_from:]))
    input_gain = max(float(np.linalg.norm(traj.problem.B_of(t), 2)) for t in _prior_vertices(traj.problem))
    bound = fraction * ref + CONVERGENCE_FLOOR * max(1.0, input_gain)
    return judge("Corollary 16", claim, 1.0 - norms[-1] / bound, 0.0,
                 f"‖x_T‖ = {norms[-1]:.3e} vs bound {bound:.3e} (fraction {fraction:.2e} of max ‖x_k‖ = {ref:.3e} "
                 f"after k1 = {zero_from}; ρ̄ = {rho:.3f}, {T - zero_from} steps without disturbance)")


#: The finite-gain test compares the ratio of (22) with GAIN_MARGIN times the ℓ2 gain bound of the
#: linear loop x⁺ = A_cl(θ)x + w under the feedback K alone (:func:`linear_gain_yardstick`).
#: Measured on 60 generated 90-step runs: max_K r_K <= 0.40 of the yardstick (margin 25x).
GAIN_MARGIN = 10.0


def linear_gain_yardstick(problem, design) -> float:
    """2 κ(P) / (1 − γ)², γ² = 1 − λ_min(P^{-½}(Q + KᵀRK)P^{-½}): from (16), ‖A_cl(θ)x‖_P <= γ‖x‖_P
    for all θ ∈ Θ, so x_{k+1} = A_cl x_k + w_k has ‖x_k‖_P <= Σ_j γ^(k-j) (‖x_0‖_P δ_j + ‖w_j‖_P),
    and Young's inequality for this convolution bounds Σ‖x‖² by this factor times ‖x0‖² + Σ‖w‖²."""
    P = np.asarray(design.P, float)
    K = np.asarray(design.K, float)
    M = problem.Q + K.T @ problem.R @ K
    vals, vecs = np.linalg.eigh(P)
    P_inv_half = vecs @ np.diag(vals ** -0.5) @ vecs.T
    gamma2 = 1.0 - float(np.min(np.linalg.eigvalsh(P_inv_half @ M @ P_inv_half)))
    gamma = np.sqrt(max(gamma2, 0.0))
    return 2.0 * float(vals.max() / vals.min()) / (1.0 - gamma) ** 2


def finite_gain(traj) -> CheckResult:
    """(22) along a run: r_K = Σ_{k<=K}‖x_k‖² / (‖x_0‖² + ‖θ̂_0 − θ*‖² + Σ_{k<=K}‖w_k‖²) stays below
    GAIN_MARGIN × :func:`linear_gain_yardstick` for every K (see the test for what this shows)."""
    claim = "(22): Σ‖x_k‖² <= c (‖x_0‖² + ‖θ̂_0 − θ*‖² + Σ‖w_k‖²) along the run"
    if traj.stop_reason != "completed":
        return judge("(22) finite gain", claim, -np.inf, 0.0, f"run ended early: {traj.stop_reason}")
    ratios = l2_gain_ratios(traj)
    ceiling = GAIN_MARGIN * linear_gain_yardstick(traj.problem, traj.design)
    K = int(np.argmax(ratios))
    return judge("(22) finite gain", claim, 1.0 - float(ratios[K]) / ceiling, 0.0,
                 f"max_K r_K = {ratios[K]:.3g} at K = {K} of {len(ratios)}; ceiling {ceiling:.3g}; "
                 f"r at the end {ratios[-1]:.3g}")
