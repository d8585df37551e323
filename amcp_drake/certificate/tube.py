"""Certificate checks of the prediction tube (Proposition 9, eqs (5), (14), (15)) at every solved step.

Two independent routes, both from the recorded z_{l|k}, α_{l|k}, v_{l|k}, Λ^j_{l|k} and Θ_k:

* **Vertex enumeration** (the primal claim (5a)-(5c)): the vertices of X_{l|k} = {z_l} ⊕ α_l X0
  (X0's vertices recomputed with Qhull from H_x), of Θ_k and of W are enumerated, and
  A(θ)x + B(θ)(Kx + v_l) + w ∈ X_{l+1|k} is evaluated at every combination. Since the map is
  affine in each of x, θ, w separately and X_{l+1|k} is convex, the vertices suffice.
* **Dual certificates** (15c)-(15d): the recorded multipliers Λ must be non-negative and satisfy
  (15c) and (15d) when the residuals are recomputed from z, α, v, Λ, h_θk, H_θk; then LP duality
  proves max_{θ∈Θ_k} [H_x]_i D^j θ <= [Λ^j h_θk]_i, i.e. the same containment.

The vertex ordering j of Λ^j is that of ``design.X0_vertices`` (the QP's order), which the check
``design.x0_vertices`` compares with the recomputed vertex set.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.certificate.claims import RunView, max_over_set, not_claimed, row_check, tag
from amcp_drake.model import polytope
from amcp_drake.model.check_result import CheckResult, judge
from amcp_drake.model.claim_table import claim as row_of

# The claims' tolerances, names and statements are their rows of the table of claims (model.claim_table):
# model.tolerances.TUBE_TOL for the tube and its multipliers, VERTEX_TOL (relative, floor 1) for the vertex list.

#: Most bytes of one array of the propagation check (5b) (a chunk of the vertices of X_(l|k) times the
#: vertices of Θ_k times the rows of H_x): 16 MiB.
PROPAGATION_CHUNK_BYTES = 16 * 2**20

GROUP_DESIGN = "design"


def x0_vertex_list(view: RunView) -> CheckResult:
    """The QP's vertex list x^1..x^v of X0 (14) equals the vertex set of {H_x x <= 1} (Qhull).

    Margin: −(Hausdorff distance between the two finite sets).
    """
    d = view.design
    recorded = np.asarray(d.X0_vertices, float)
    fresh = polytope.vertices(d.H_x, np.ones(len(d.H_x)))
    hausdorff = max(_directed_distance(recorded, fresh), _directed_distance(fresh, recorded))
    row = row_of("design.x0_vertices")
    tol = row.tolerance * max(1.0, float(np.max(np.abs(fresh))))  # relative to the size of X0, floor 1
    return tag(judge(row.name, row.statement, 0.0 - hausdorff, tol, f"{len(recorded)} recorded, {len(fresh)} recomputed "
                     "vertices; margin = −Hausdorff distance"), row.id, row.family)


def _directed_distance(points: np.ndarray, others: np.ndarray) -> float:
    """max over ``points`` of the Euclidean distance to the nearest of ``others`` (a directed Hausdorff
    distance), with the pairwise distances formed in chunks of at most :data:`PROPAGATION_CHUNK_BYTES`."""
    if len(points) == 0 or len(others) == 0:
        return 0.0 if len(points) == 0 else float("inf")
    step = max(1, PROPAGATION_CHUNK_BYTES // (8 * len(others) * max(1, points.shape[1])))
    worst = 0.0
    for start in range(0, len(points), step):
        dist = np.linalg.norm(points[start:start + step, None, :] - others[None, :, :], axis=2)
        worst = max(worst, float(np.max(np.min(dist, axis=1))))
    return worst


class _TubeStep:
    """Recorded tube of one solved step k, with vertex arrays."""

    def __init__(self, view: RunView, k: int, X0v: np.ndarray) -> None:
        r = view.records[k]
        self.k = k
        self.z = np.asarray(r.z, float)
        self.alpha = np.asarray(r.alpha, float)
        self.v = np.asarray(r.v, float)
        self.Lambda = None if r.Lambda is None else np.asarray(r.Lambda, float)
        self.H_theta = np.asarray(r.H_theta, float)
        self.h_theta = np.asarray(r.h_theta, float)
        self.N = len(self.v)
        self.X0v = X0v

    def vertices(self, l: int, X0v: np.ndarray | None = None) -> np.ndarray:
        """Vertices z_l + α_l x^j of X_{l|k}, shape (v, n)."""
        base = self.X0v if X0v is None else X0v
        return self.z[l] + self.alpha[l] * base


def _propagation_margin(view: RunView, step: _TubeStep, theta_v: np.ndarray | None, W_v: np.ndarray,
                        w_bar: np.ndarray) -> float:
    """min over l, vertices x of X_{l|k}, θ of Θ_k, w of W of α_{l+1} − max_i [H_x]_i (A(θ)x + B(θ)(Kx+v_l) + w − z_{l+1}).

    (5b) by vertex enumeration; when Θ_k's vertices are unavailable (flat or degenerate set) the
    maximum over θ is taken by HiGHS support LPs instead (same value, by LP duality no solver of
    the run is involved).
    """
    pr, d = view.problem, view.design
    H_x, K = d.H_x, d.K
    worst = np.inf
    # the maximum over w of [H_x]_i w separates row by row: max_{x,θ,w} [H_x]_i(A(θ)x + B(θ)u + w − z⁺)
    # = max_{x,θ} [H_x]_i(A(θ)x + B(θ)u − z⁺) + max_w [H_x]_i w, with the latter from W's vertices
    HW_max = np.max(W_v @ H_x.T, axis=0)                                      # (u,)
    for l in range(step.N):
        X = step.vertices(l)                                   # (v, n)
        U = X @ K.T + step.v[l]                                # (v, m)
        base = X @ pr.A0.T + U @ pr.B0.T                       # (v, n)
        Dv = np.einsum("pab,vb->vap", pr.A, X) + np.einsum("pab,vb->vap", pr.B, U)  # (v, n, p) = D(x^j, u^j)
        if theta_v is not None:
            top = -np.inf
            t = max(1, len(theta_v))
            chunk = max(1, PROPAGATION_CHUNK_BYTES // (8 * t * max(len(H_x), len(base[0]))))
            for start in range(0, len(X), chunk):  # vertices of X_(l|k) in chunks: (chunk, t, u) at a time
                images = base[start:start + chunk, None, :] + np.einsum("vap,tp->vta", Dv[start:start + chunk],
                                                                        theta_v)  # (v, t, n)
                rows = (images - step.z[l + 1]) @ H_x.T                            # (v, t, u)
                top = max(top, float(np.max(np.max(rows, axis=(0, 1)) + HW_max)))
        else:
            top = -np.inf
            for j in range(len(X)):
                sup = max_over_set(step.H_theta, step.h_theta, None, H_x @ Dv[j])  # (u,)
                top = max(top, float(np.max(H_x @ (base[j] - step.z[l + 1]) + sup + w_bar)))
        worst = min(worst, float(step.alpha[l + 1]) - top)
    return worst


#: The claims about the multipliers Λ of (15c)-(15d).
MULTIPLIER_CLAIMS = ("multipliers_nonneg", "multipliers_15c", "multipliers_15d")
#: Why the Λ claims are not made for a run solved in the vertex form.
VERTEX_FORM_REASON = ("not applicable (vertex form has no multipliers): (20) was solved in the vertex form, (5b) at "
                      "the vertices of Θ_k (checked by tube_propagation); --formulation plain solves (15) with Λ")


def _not_claimed_multiplier(claim_id: str, reason: str) -> CheckResult:
    """The Λ claim ``claim_id`` (its row of the claim table) listed as not claimed, with ``reason``."""
    row = row_of(claim_id)
    return not_claimed(row.id, row.name, row.statement, row.family, reason)


def tube_checks(view: RunView) -> list[CheckResult]:
    """Every tube check of Proposition 9 / (5) / (14) / terminal set, one CheckResult each."""
    pr, d, tr = view.problem, view.design, view.traj
    H_x, K = d.H_x, d.K
    X0v = polytope.vertices(H_x, np.ones(len(H_x)))
    X0v_qp = np.asarray(d.X0_vertices, float)
    W_v = pr.w_vertices()
    w_bar = np.max(H_x @ W_v.T, axis=1)  # recomputed, not the design's w̄

    contains, contains_next, alpha_ok, constraints, propagation, terminal = {}, {}, {}, {}, {}, {}
    lam_nonneg, lam_c, lam_d = {}, {}, {}
    lp_fallback = []
    for k in view.solved:
        s = _TubeStep(view, k, X0v)
        x = tr.x[k]
        contains[k] = float(np.min(s.alpha[0] - H_x @ (x - s.z[0])))
        if k < view.T:
            contains_next[k] = float(np.min(s.alpha[1] - H_x @ (tr.x[k + 1] - s.z[1])))
        alpha_ok[k] = float(np.min(s.alpha))
        con = np.inf
        for l in range(s.N):
            X = s.vertices(l)
            U = X @ K.T + s.v[l]
            con = min(con, float(np.min(1.0 - X @ pr.F.T - U @ pr.G.T)))
        constraints[k] = con
        theta_v = view.theta_k_vertices[k]
        if theta_v is None:
            lp_fallback.append(k)
        propagation[k] = _propagation_margin(view, s, theta_v, W_v, w_bar)
        terminal[k] = float(np.min(1.0 - d.H_T @ s.z[s.N] - d.h_T * s.alpha[s.N]))
        # dual certificates (15c)-(15d) with the QP's vertex order (the vertex formulation has no Λ)
        if s.Lambda is None:
            continue
        lam_nonneg[k] = float(np.min(s.Lambda))
        c_margin, d_margin = np.inf, np.inf
        for l in range(s.N):
            X = s.vertices(l, X0v_qp)
            U = X @ K.T + s.v[l]
            for j in range(len(X)):
                Lam = s.Lambda[l, j]                                   # (u, q_k)
                dj = pr.A0 @ X[j] + pr.B0 @ U[j] - s.z[l + 1]          # d^j_{l|k}
                lhs = Lam @ s.h_theta + H_x @ dj - s.alpha[l + 1]
                c_margin = min(c_margin, float(np.min(-w_bar - lhs)))
                Dj = pr.regressor(X[j], U[j])                           # D^j_{l|k}
                d_margin = min(d_margin, -float(np.max(np.abs(H_x @ Dj - Lam @ s.H_theta))))
        lam_c[k], lam_d[k] = c_margin, d_margin

    none = "no step has a QP solution (see recursive feasibility)"
    prop_detail = "margin = min α_(l+1) − [H_x]_i(A(θ)x + B(θ)(Kx+v_l) + w − z_(l+1)) over l, vertices of X_(l|k), Θ_k, W"
    if lp_fallback:
        prop_detail += f"; Θ_k vertices not enumerable at steps {lp_fallback}: max over Θ_k by HiGHS LPs"
    checks = [
        row_check("tube_contains_state", contains, "margin = min_i (α_0 − [H_x]_i (x_k − z_0))", none),
        row_check("tube_contains_next_state", contains_next, "margin = min_i (α_1 − [H_x]_i (x_(k+1) − z_1))", none),
        row_check("tube_propagation", propagation, prop_detail, none),
        row_check("tube_constraints", constraints, "margin = min (1 − F x − G(Kx + v_l)) over tube vertices", none),
        row_check("tube_alpha_nonneg", alpha_ok, "margin = min_l α_(l|k)", none),
        row_check("terminal_set", terminal, "margin = min_r (1 − [H_T]_r z_N − [h_T]_r α_N)", none),
    ]
    if view.traj.meta.get("formulation") == "vertex":
        # The vertex formulation enforces (5b) at the vertices of Θ_k without multipliers: there is no Λ
        # to check, and the certificate lists the Λ claims as not applicable, saying why. (5b) itself is
        # still checked above by vertex enumeration (tube_propagation).
        return checks + [_not_claimed_multiplier(cid, VERTEX_FORM_REASON) for cid in MULTIPLIER_CLAIMS]
    if view.solved and not lam_nonneg:
        # every applied answer is the vertex form's (the plain form's answers were rejected and the
        # other formulation answered): no Λ was applied, so no claim about Λ is made for this run
        reason = ("every applied answer of (20) is the vertex form's (no multipliers): the plain form's answers were "
                  "rejected, see solver_answers")
        return checks + [_not_claimed_multiplier(cid, reason) for cid in MULTIPLIER_CLAIMS]
    return checks + [
        row_check("multipliers_nonneg", lam_nonneg, "margin = min entry of Λ", none),
        row_check("multipliers_15c", lam_c, "margin = min (−w̄ − Λ^j h_θk − H_x d^j + α_(l+1)); w̄ recomputed from the vertices of W", none),
        row_check("multipliers_15d", lam_d, "margin = −max |H_x D^j − Λ^j H_θk|", none),
    ]
