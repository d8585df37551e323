"""Certificate claim ``qp_optimality``: the recorded (z, α, v) of every solved step is optimal for the
QP (20) rebuilt from the record alone.

Why a claim of its own. The other claims show that the recorded decision is *feasible* for (20)
(tube claims, multipliers) and that the recorded cost is the cost *of* that decision
(``cost_value``). Nothing there shows that it is the *minimiser*: a trajectory whose design P was
edited (the terminal weight enters only the cost), or whose v, tube and cost were replaced by
another feasible decision, passes them all. This claim closes that gap with the KKT conditions.

**The QP, rebuilt with numpy from the record.** Decision y = [z_0..z_N | α_0..α_N | v_0..v_{N−1}]
(the multipliers Λ are eliminated, see below). Constraint rows A y <= b, all linear:

* (15a) (F + GK) z_l + G v_l + α_l f̄ <= 1, l < N (recorded K and f̄);
* (15b) −H_x z_0 − α_0 1 <= −H_x x_k;
* (5b) in **vertex form** (proof of Proposition 9): for every stage l, every vertex θ^s of Θ_k
  (of Θ_{l|k} = {H_θ θ <= h_{θ l|k}} with the predicted sets (26) when d_θ > 0) and every row i,
  [H_x A_cl(θ^s)]_i z_l + α_l c^s_i + [H_x B(θ^s)]_i v_l − [H_x]_i z_{l+1} − α_{l+1} <= −w̄_i with
  c^s_i = max_j [H_x A_cl(θ^s) x^j]_i over the recorded vertices x^j of X0 (the rows of the other
  j are implied because α_l >= 0 is a row too);
* terminal set H_T z_N + h_T α_N <= 1; α_l >= 0;
* when the step enforced the PE constraint (docs/explanation/paper.md §8): lo <= K x_k + v_0 <= hi, the recorded bounds
  of the QP the controller chose (the claim is optimality for *that* QP; that the other branch was
  not cheaper is not checked).

(15c)-(15d) with Λ >= 0 are the LP dual of max_{θ∈Θ_k} [H_x]_i D^j θ; by strong LP duality they
admit a Λ exactly when the vertex rows hold. So the feasible sets of (20) and of this QP have the
same projection on (z, α, v), and since the cost does not involve Λ, the two have the same optimal
(z, α, v). The recorded Λ itself is checked by ``multipliers_*`` (Λ >= 0, (15c), (15d)); together
with this claim that makes the recorded (z, α, v, Λ) a minimiser of (20). The vertices of Θ_k are
the certificate's own (:func:`amcp_drake.certificate.claims.theta_vertices`: Qhull, flat sets in their
affine hull), never the backend's.

**Cost.** Certainty equivalence (17)-(18): f(y) = J_N(v) with the recorded θ̂_k and P; its gradient
by the adjoint recursion of (18). Min–max (19): the epigraph form min Σ_l t_l s.t.
q_lj(y) <= t_l, q_lj = ‖x^j_l‖²_Q + ‖u^j_l‖²_R (l < N), q_Nj = ‖x^j_N‖²_P, x^j_l = z_l + α_l x^j,
evaluated at t_l = max_j q_lj(y) (the backends' Σ s_l² with s_l >= ‖·‖ has the same minimisers).

**The test.** Both problems ((20) with the rows of (15) in vertex form, and its min–max epigraph) are
convex with linear (resp. convex smooth) constraints, so y is optimal iff it is feasible and there are
multipliers ω >= 0 with ∇f(y) + Σ ω_i ∇g_i(y) = 0 and ω_i·slack_i = 0 (KKT; Slater's condition holds for
the epigraph). The rows are scaled to unit norm. The
step's value is the worst residual of the best dual certificate,

    min over ω >= 0 of max(stationarity(ω), complementarity(ω))   (the residuals below),

so the claim fails a step only when *no* ω >= 0 certifies it within the tolerance. It is found in two
stages. First, cheaply, ω is the non-negative least-squares fit (:func:`scipy.optimize.nnls`) of the
stationarity equation over the rows with slack <= τ, for each τ of :data:`ACTIVE_TOLS` (min–max: also the
quadratics within τ' of t_l, relative, for each τ' of :data:`ACTIVE_COST_TOLS`); the best of these is kept
when it is within :data:`LP_ABOVE` (a tenth of the tolerance). Otherwise, **the LP certificate** (:func:`lp_certificate`) takes
every row: for a bound τ on the complementarity (Σ ω_i·slack_i <= τ·s0, s0 the scale below without the ω
terms), the ω minimising the stationarity residual ‖∇f + Σ ω_i ∇g_i‖_∞/s0 is an LP (HiGHS, through
:func:`scipy.optimize.linprog`); its optimum r(τ) does not increase with τ, and the min–max above is the τ*
with r(τ*) = τ*. τ = OPTIMALITY_TOL is tried first (which decides the claim), then τ* is bracketed by
bisection in log τ. HiGHS only proposes ω: every ω, from NNLS or the LP, is made non-negative (and
scaled onto the complementarity bound), its residuals are recomputed here with numpy, and the smallest
worst residual is the step's value. Its margin is therefore a genuine certificate; whenever it exceeds
a tenth of the tolerance it is also at most the LP's minimum (to within the bisection's 0.4 %; the LP holds
s at its value without the ω terms, which can only be smaller). Why not NNLS alone: it minimises the 2-norm of stationarity over a guessed active set, the
claim judges the ∞-norm of stationarity and the complementarity together, and on a degenerate step
(hundreds of nearly parallel vertex rows within 1e-2 of active, the dual not unique) the two differ by
more than the tolerance: on mass_chain4 (n = 8, a Drake plan 1.6e-7 from the optimum) the best NNLS
candidate leaves 3.9e-5, the LP certificate 1.7e-6.

Three residuals are judged, each made dimensionless:

* stationarity ‖∇f + Σ ω_i ∇g_i‖_∞ / s, with s the largest ∞-norm of the terms being summed, floored
  at :data:`SCALE_FLOOR`. For (17) the gradient is split two ways and every part counts: along (18),
  2R(K x̂_l + v_l) and B(θ̂)ᵀ p_{l+1} with the adjoint p (they cancel at an unconstrained minimiser), and
  as H v + q, the curvature part (the gradient at x_k = 0) and the state part (the gradient at v = 0);
  and each ω_i ∇g_i. The curvature part matters when B(θ̂) is large: then H is large, ∇f is a small
  difference of large H v and q, and a plan accurate to a relative 1e-9 in v leaves a residual of that
  order in H v, not in the small B(θ̂)ᵀ p (ji2022_quadrotor: |B| ≈ 86, ‖H v‖ ≈ 6 against parts of 5e-3 along
  (18)). The floor makes the residual absolute (at the solver's own absolute accuracy) once the state, and
  with it every term, is near zero;
* complementarity Σ_i ω_i·slack_i / s: with exact stationarity, Σ_i ω_i·slack_i bounds f(y) − min f (weak
  duality), so this is the duality gap of (y, ω) in the units of the stationarity (a length in y). A sum,
  not a maximum over rows: with thousands of rows, a per-row allowance lets many slightly slack rows absorb
  a genuine stationarity error together (per row, Example 1 with its design P[0][0] raised by 0.1 would
  have a certificate within the tolerance);
* primal infeasibility max_i (A y − b)_i on unit rows (a length in y; states are O(1)).

The step's margin is −max of the three; the claim passes when margin >= −:data:`OPTIMALITY_TOL`.
A step whose Θ_k vertices cannot be enumerated has no margin, which makes the claim ``not_run``,
never ``pass``. Only numpy and scipy are used; no backend, cvxpy or Drake.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.optimize import linprog, nnls

from amcp_drake.certificate.claims import RunView, row_check, theta_vertices
from amcp_drake.model.check_result import CheckResult
from amcp_drake.model.tolerances import OPTIMALITY_TOL

CLAIM_ID = "qp_optimality"

# OPTIMALITY_TOL (model.tolerances, the row of ``qp_optimality`` in the table of claims) is the judged KKT
# residual (dimensionless, see module docstring). The run's QPs are solved by Clarabel to
# its default 1e-8 gap and feasibility tolerances. Measured (docs/certificate.md, qp_optimality):
# honest runs <= 3.7e-6 (446 runs: problems 0-59 of campaign seeds 0, 1, 2 on both backends, 20 of
# them again with min–max, exact update, vertex formulation, PE; Example 1 with every option);
# Example 1 with design P[0][0] raised by 0.1 (still satisfying (16)) 3.0e-5 on the Drake run (the
# terminal weight reaches the gradient only through A_cl(θ̂)^N x_k ~ 1e-3 x_k). 1e-5 sits between them
# with a factor of about 3 on either side. (The honest figures were measured with a per-row
# complementarity and NNLS multipliers only; docs/certificate.md gives those under this definition.)
#: Candidate active sets: the unit rows with slack below each of these (a distance in y = (z, α, v)).
#: Clarabel leaves active rows at slacks of 1e-10..1e-6 (measured; cvxpy's answers are the looser),
#: inactive ones are typically >= 1e-3 away. One fixed threshold misjudges either side: at 1e-6 a
#: cvxpy step whose decisive row sat at 1.03e-6 (random campaign problem 0-22) showed a stationarity
#: residual of 6e-2; at 1e-4 NNLS leaned on rows that are not active and the complementarity
#: residual failed two honest runs. So ω is fitted for each candidate set and the best certificate is
#: kept (every one is a genuine ω >= 0, so the minimum is honest). A row admitted although inactive
#: shows up in the complementarity residual ω·slack.
ACTIVE_TOLS = (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2)
#: Min–max epigraph: vertex j is a candidate at stage l when q_lj >= t_l − τ'·max(t_l, COST_FLOOR)
#: (relative: the epigraph constraints are met to Clarabel's tolerance in s_l = √t_l). A single
#: τ' = 1e-6 left a vertex at relative gap ~1e-5 out on a random problem (residual 2.5e-5).
ACTIVE_COST_TOLS = (1e-7, 1e-6, 1e-5, 1e-4)
#: Absolute floor of the cost scale in the min–max activity test (near the origin t_l → 0).
COST_FLOOR = 1e-12
#: Floor of the stationarity scale s (cost-gradient units; problems are scaled so that Z is
#: {F x + G u <= 1}, where gradients are O(1)). Near the origin every term of the sum shrinks with
#: x_k while the solver's absolute accuracy does not (Clarabel accepts a dual residual of
#: tol_feas·max(1, ...) = 1e-8 absolute in its own scaling). With this floor the allowance is
#: OPTIMALITY_TOL·SCALE_FLOOR = 1e-7 absolute. Measured on the campaign runs above: without a floor,
#: relative residuals up to 1 at scales 1e-11 (absolute <= 3e-10); with 1e-3, worst 5.4e-6
#: (absolute 5.4e-9); with 1e-2, worst 1.7e-6. The tampered-P margins are unchanged (their scales
#: are >= 1e-2).
SCALE_FLOOR = 1e-2
#: The LP certificate: bisections of log τ (each halves the bracket of τ*; 12 over the 7 decades of
#: :data:`LP_TAU_RANGE` below the tolerance leave it within 0.4 %), and the range searched.
LP_BISECTIONS = 12
LP_TAU_RANGE = (1e-12, 1e1)
#: The LP certificate runs when the best NNLS candidate leaves more than this (so that every margin beyond
#: a tenth of the tolerance is the minimum over ω, not an upper bound of it).
LP_ABOVE = OPTIMALITY_TOL / 10
#: HiGHS options of the LP certificate: feasibility tolerances below HiGHS's default 1e-7, since the LP's
#: rows are the stationarity residual divided by the scale, judged at OPTIMALITY_TOL (its answer is
#: re-evaluated in any case; a looser answer only makes the certificate worse, never wrongly better).
#: ``maxiter`` caps each attempt (deterministically, unlike a time limit): dual simplex, the first of
#: :data:`LP_METHODS`, can cycle on these degenerate LPs (measured: 290,000 iterations without an answer on a
#: mass_chain3 step whose LP it otherwise solves in ~300); the interior-point method then answers.
LP_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10, "maxiter": 20_000}
LP_METHODS = ("highs-ds", "highs-ipm")

CE, MINMAX = "certainty_equivalence", "minmax"


# -- the QP (20) of one step, rebuilt ------------------------------------------------------------
class _Layout:
    """Offsets of y = [z (N+1)·n | α (N+1) | v N·m]."""

    def __init__(self, n: int, m: int, N: int) -> None:
        self.n, self.m, self.N = n, m, N
        self.a0 = (N + 1) * n
        self.v0 = self.a0 + N + 1
        self.size = self.v0 + N * m

    def z(self, l: int) -> slice:
        return slice(l * self.n, (l + 1) * self.n)

    def a(self, l: int) -> int:
        return self.a0 + l

    def v(self, l: int) -> slice:
        return slice(self.v0 + l * self.m, self.v0 + (l + 1) * self.m)

    def pack(self, z, alpha, v) -> np.ndarray:
        return np.concatenate([np.asarray(z, float).ravel(), np.asarray(alpha, float).ravel(),
                               np.asarray(v, float).ravel()])


def _vertex_coefficients(problem, design, theta_v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """H_x A_cl(θ^s) (S, u, n), c^s = max_j H_x A_cl(θ^s) x^j (S, u) and H_x B(θ^s) (S, u, m) for the
    vertices θ^s (S, p) of Θ_{l|k}: the coefficients of the vertex rows of (5b)."""
    K = np.asarray(design.K, float)
    H_x = np.asarray(design.H_x, float)
    Xv = np.asarray(design.X0_vertices, float)
    A_t = problem.A0[None] + np.einsum("sp,pab->sab", theta_v, problem.A)       # (S, n, n)
    B_t = problem.B0[None] + np.einsum("sp,pab->sab", theta_v, problem.B)       # (S, n, m)
    HA = np.einsum("ia,sab->sib", H_x, A_t + B_t @ K)                          # (S, u, n)
    HB = np.einsum("ia,sab->sib", H_x, B_t)                                    # (S, u, m)
    c = np.max(np.einsum("sib,jb->sij", HA, Xv), axis=2)                       # (S, u)
    return HA, c, HB


def _vertex_rows(design, lay: _Layout, l: int, coefficients) -> tuple[np.ndarray, np.ndarray]:
    """Rows of (5b) in vertex form for stage l (module docstring), from :func:`_vertex_coefficients`."""
    HA, c, HB = coefficients
    H_x = np.asarray(design.H_x, float)
    S, u = c.shape
    rows = np.zeros((S * u, lay.size))
    rows[:, lay.z(l)] = HA.reshape(S * u, -1)
    rows[:, lay.a(l)] = c.ravel()
    rows[:, lay.v(l)] = HB.reshape(S * u, -1)
    rows[:, lay.z(l + 1)] = np.tile(-H_x, (S, 1))
    rows[:, lay.a(l + 1)] = -1.0
    return rows, np.tile(-np.asarray(design.w_bar, float), S)


def constraint_rows(problem, design, lay: _Layout, x: np.ndarray, stage_vertices: list[np.ndarray],
                    u0_bounds: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) of the QP (20) in (z, α, v) with (5b) in vertex form (module docstring), rows unscaled."""
    N, m = lay.N, lay.m
    K = np.asarray(design.K, float)
    H_x = np.asarray(design.H_x, float)
    F, G = problem.F, problem.G
    blocks, rhs = [], []
    c = len(F)
    a15 = np.zeros((N * c, lay.size))                                          # (15a)
    for l in range(N):
        a15[l * c:(l + 1) * c, lay.z(l)] = F + G @ K
        a15[l * c:(l + 1) * c, lay.v(l)] = G
        a15[l * c:(l + 1) * c, lay.a(l)] = np.asarray(design.f_bar, float)
    blocks.append(a15)
    rhs.append(np.ones(N * c))
    b15 = np.zeros((len(H_x), lay.size))                                        # (15b)
    b15[:, lay.z(0)] = -H_x
    b15[:, lay.a(0)] = -1.0
    blocks.append(b15)
    rhs.append(-H_x @ x)
    coefficients: dict[int, tuple] = {}
    for l in range(N):                                                          # (5b), vertex form
        verts = stage_vertices[l]
        if id(verts) not in coefficients:  # the same set at every stage unless d_θ > 0
            coefficients[id(verts)] = _vertex_coefficients(problem, design, verts)
        rows, b = _vertex_rows(design, lay, l, coefficients[id(verts)])
        blocks.append(rows)
        rhs.append(b)
    H_T, h_T = np.asarray(design.H_T, float), np.asarray(design.h_T, float)
    term = np.zeros((len(H_T), lay.size))                                       # terminal set
    term[:, lay.z(N)] = H_T
    term[:, lay.a(N)] = h_T
    blocks.append(term)
    rhs.append(np.ones(len(H_T)))
    nonneg = np.zeros((N + 1, lay.size))                                        # α >= 0
    nonneg[np.arange(N + 1), lay.a0 + np.arange(N + 1)] = -1.0
    blocks.append(nonneg)
    rhs.append(np.zeros(N + 1))
    if u0_bounds is not None:                                                   # PE: lo <= K x + v_0 <= hi
        lo, hi = (np.broadcast_to(np.asarray(b, float), (m,)) for b in u0_bounds)
        Kx = K @ x
        for i in range(m):
            if np.isfinite(hi[i]):
                row = np.zeros((1, lay.size))
                row[0, lay.v0 + i] = 1.0
                blocks.append(row)
                rhs.append(np.array([hi[i] - Kx[i]]))
            if np.isfinite(lo[i]):
                row = np.zeros((1, lay.size))
                row[0, lay.v0 + i] = -1.0
                blocks.append(row)
                rhs.append(np.array([Kx[i] - lo[i]]))
    return np.vstack(blocks), np.concatenate(rhs)


# -- cost gradients ----------------------------------------------------------------------------------
def ce_gradient_terms(problem, design, x: np.ndarray, theta_hat: np.ndarray,
                      v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The two parts of ∇_v J_N of (17) along (18), each of shape (N, m): 2R(K x̂_l + v_l) (the stage's
    own input term) and B(θ̂)ᵀ p_{l+1} (its effect on the later stages), by the adjoint of
    x̂_{l+1} = A_cl(θ̂) x̂_l + B(θ̂) v_l: p_N = 2P x̂_N, p_l = 2Q x̂_l + 2Kᵀ R (K x̂_l + v_l) + A_cl(θ̂)ᵀ p_{l+1}.
    At an unconstrained minimiser they cancel; their sizes are the scale of the stationarity residual."""
    A = problem.A0 + np.tensordot(theta_hat, problem.A, axes=1)
    B = problem.B0 + np.tensordot(theta_hat, problem.B, axes=1)
    K, P = np.asarray(design.K, float), np.asarray(design.P, float)
    Q, R = problem.Q, problem.R
    Acl = A + B @ K
    v = np.asarray(v, float)
    N = len(v)
    xs = [np.asarray(x, float)]
    for l in range(N):
        xs.append(Acl @ xs[-1] + B @ v[l])
    own = np.zeros_like(v)
    later = np.zeros_like(v)
    lam = 2.0 * P @ xs[N]
    for l in range(N - 1, -1, -1):
        ul = K @ xs[l] + v[l]
        own[l] = 2.0 * R @ ul
        later[l] = B.T @ lam
        lam = 2.0 * Q @ xs[l] + 2.0 * K.T @ R @ ul + Acl.T @ lam
    return own, later


def ce_gradient(problem, design, x: np.ndarray, theta_hat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """∇_v J_N of (17) along (18), shape (N, m) (the sum of :func:`ce_gradient_terms`)."""
    own, later = ce_gradient_terms(problem, design, x, theta_hat, v)
    return own + later


def _minmax_terms(problem, design, lay: _Layout, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """q_lj(y) (N+1, v) and ∇_y q_lj (N+1, v, ny) of the min–max stage terms of (19)."""
    Xv = np.asarray(design.X0_vertices, float)
    K, P = np.asarray(design.K, float), np.asarray(design.P, float)
    Q, R = problem.Q, problem.R
    N, nv = lay.N, len(Xv)
    z = y[:lay.a0].reshape(N + 1, lay.n)
    alpha = y[lay.a0:lay.v0]
    v = y[lay.v0:].reshape(N, lay.m)
    q = np.zeros((N + 1, nv))
    grad = np.zeros((N + 1, nv, lay.size))
    for l in range(N + 1):
        X = z[l] + alpha[l] * Xv                                                # (v, n)
        if l < N:
            U = X @ K.T + v[l]
            q[l] = np.einsum("jn,nm,jm->j", X, Q, X) + np.einsum("jn,nm,jm->j", U, R, U)
            gx = 2.0 * X @ Q + 2.0 * (U @ R) @ K                                # ∂q/∂x^j (v, n)
            grad[l, :, lay.v(l)] = 2.0 * U @ R
        else:
            q[l] = np.einsum("jn,nm,jm->j", X, P, X)
            gx = 2.0 * X @ P
        grad[l, :, lay.z(l)] = gx
        grad[l, :, lay.a(l)] = np.sum(gx * Xv, axis=1)
    return q, grad, np.max(q, axis=1)


# -- KKT residuals -------------------------------------------------------------------------------
def _certificate(cols: np.ndarray, slacks: np.ndarray, omega: np.ndarray, grad: np.ndarray,
                 gradient_scale: float) -> dict[str, float]:
    """Stationarity and complementarity of the multipliers ``omega`` (>= 0) on the columns ``cols``
    (ny, a) with slacks ``slacks`` (module docstring), recomputed here whatever produced ``omega``."""
    contrib = cols * omega[None, :]
    residual = grad + contrib.sum(axis=1)
    term_scale = float(np.max(np.abs(contrib))) if contrib.size else 0.0
    scale = max(gradient_scale, term_scale, SCALE_FLOOR)
    comp = float(np.sum(omega * slacks)) if len(omega) else 0.0
    return {"stationarity": float(np.max(np.abs(residual))) / scale, "complementarity": comp / scale,
            "scale": scale}


def _lp_multipliers(cols: np.ndarray, slacks: np.ndarray, target: np.ndarray, tau: float) -> np.ndarray | None:
    """ω' >= 0 minimising ‖target + cols ω'‖_∞ subject to Σ ω'_i·slack_i <= tau (an LP solved by HiGHS
    through :func:`scipy.optimize.linprog`; ω' is scaled back onto the bound if HiGHS overshoots it). None
    when HiGHS returns no point."""
    ny, a = cols.shape
    G = sparse.csr_matrix(cols)
    one = sparse.csr_matrix(np.ones((ny, 1)))
    gap = sparse.csr_matrix(np.append(slacks, 0.0)[None, :])
    A_ub = sparse.vstack([sparse.hstack([G, -one]), sparse.hstack([-G, -one]), gap]).tocsc()
    b_ub = np.concatenate([-target, target, [tau]])
    c = np.zeros(a + 1)
    c[-1] = 1.0
    for method in LP_METHODS:  # dual simplex can cycle on these degenerate LPs: capped, then interior point
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, bounds=(0, None), method=method, options=LP_OPTIONS)
        if res.status == 0 and res.x is not None:
            break
    else:
        return None
    omega = np.maximum(res.x[:a], 0.0)
    total = float(omega @ slacks)
    return omega * (tau / total) if total > tau else omega


def lp_certificate(cols: np.ndarray, slacks: np.ndarray, grad: np.ndarray,
                   gradient_scale: float) -> dict[str, float] | None:
    """The multipliers minimising the worst of stationarity and complementarity over every row (module
    docstring, "The LP certificate"): for a bound τ on the complementarity, :func:`_lp_multipliers` gives the
    least stationarity residual r(τ), non-increasing in τ; the claim's value min_ω max(stationarity,
    complementarity) is the τ* with r(τ*) = τ*. τ = :data:`OPTIMALITY_TOL` is tried first (it decides the
    claim), then τ* is bracketed by :data:`LP_BISECTIONS` bisections in log τ. Every ω tried is evaluated by
    :func:`_certificate` and the best kept, so the result is a genuine certificate whatever HiGHS's accuracy."""
    s0 = max(gradient_scale, SCALE_FLOOR)
    best: dict[str, float] | None = None

    def attempt(tau: float) -> dict[str, float] | None:
        nonlocal best
        omega = _lp_multipliers(cols, slacks, grad / s0, tau)
        if omega is None:
            return None
        result = _certificate(cols, slacks, omega * s0, grad, gradient_scale)
        if best is None or _pair(result) < _pair(best):
            best = result
        return result

    first = attempt(OPTIMALITY_TOL)
    if first is None:
        return None
    lo, hi = ((np.log10(LP_TAU_RANGE[0]), np.log10(OPTIMALITY_TOL)) if first["stationarity"] <= OPTIMALITY_TOL
              else (np.log10(OPTIMALITY_TOL), np.log10(LP_TAU_RANGE[1])))
    for _ in range(LP_BISECTIONS):
        mid = 0.5 * (lo + hi)
        result = attempt(10.0 ** mid)
        if result is not None and result["stationarity"] <= 10.0 ** mid:
            hi = mid
        else:
            lo = mid
    return best


def _pair(result: dict[str, float]) -> float:
    return max(result["stationarity"], result["complementarity"])


def kkt_residuals(A: np.ndarray, b: np.ndarray, y: np.ndarray, objective_terms: list[np.ndarray],
                  extra_columns: np.ndarray | None = None, extra_slack: np.ndarray | None = None,
                  rhs_extra: np.ndarray | None = None,
                  scale_terms: list[np.ndarray] | tuple = ()) -> dict[str, float]:
    """Stationarity, complementarity and primal infeasibility of y for min f s.t. A y <= b.

    ``objective_terms`` are the parts of ∇f(y) (their sum is the gradient; their sizes set the scale);
    ``scale_terms``, another split of ∇f(y) into parts (the curvature and state parts of (17)), only enter
    the scale.
    For the min–max epigraph the caller passes, in a space extended by t, the columns of the active
    quadratic constraints (``extra_columns``, (n_ext, c)) with their slacks, and the objective's t-part
    (``rhs_extra``); the linear rows are then padded with zeros in the t-coordinates.

    The multipliers are fitted by NNLS once per candidate active set of :data:`ACTIVE_TOLS`; when none of
    these certifies within :data:`LP_ABOVE`, :func:`lp_certificate` minimises the judged residual over
    every row. The best certificate (smallest worst residual) is kept: every candidate is a genuine ω >= 0
    (zero on the rows left out) whose residuals are recomputed here, so the minimum is a valid certificate.
    """
    norms = np.linalg.norm(A, axis=1)
    keep = norms > 0
    A, b = A[keep] / norms[keep, None], b[keep] / norms[keep]
    slack = b - A @ y
    infeasibility = max(0.0, float(-np.min(slack))) if len(slack) else 0.0
    grad = np.sum(objective_terms, axis=0)
    terms = list(objective_terms)
    if extra_columns is not None:
        grad = np.concatenate([grad, rhs_extra])
        terms = [np.concatenate([t, np.zeros(len(rhs_extra))]) for t in terms] + [
            np.concatenate([np.zeros(len(y)), rhs_extra])]
    gradient_scale = max(float(np.max(np.abs(t))) for t in list(terms) + [np.asarray(t) for t in scale_terms])

    def columns(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cols, slacks = A[rows].T, np.maximum(slack[rows], 0.0)
        if extra_columns is not None:
            pad = np.zeros((extra_columns.shape[0] - cols.shape[0], cols.shape[1]))
            cols = np.hstack([np.vstack([cols, pad]), extra_columns])
            slacks = np.concatenate([slacks, extra_slack])
        return cols, slacks

    best: dict[str, float] | None = None
    for tol in ACTIVE_TOLS:
        cols, slacks = columns(slack <= tol)
        omega = nnls(cols, -grad, maxiter=50 * cols.shape[1])[0] if cols.shape[1] else np.zeros(0)
        result = {**_certificate(cols, slacks, omega, grad, gradient_scale), "method": "nnls",
                  "active": int(cols.shape[1]), "active_tol": tol}
        if best is None or _pair(result) < _pair(best):
            best = result
    if _pair(best) > LP_ABOVE:
        cols, slacks = columns(np.ones(len(slack), dtype=bool))
        result = lp_certificate(cols, slacks, grad, gradient_scale) if cols.shape[1] else None
        if result is not None and _pair(result) < _pair(best):
            best = {**result, "method": "lp", "active": int(cols.shape[1]), "active_tol": float("inf")}
    return {**best, "infeasibility": infeasibility}


def _worst(result: dict[str, float]) -> float:
    return max(result["stationarity"], result["complementarity"], result["infeasibility"])


def _stage_vertices(view: RunView, k: int) -> list[np.ndarray] | None:
    """Vertices of Θ_{l|k} for l < N: Θ_k (shared with the other claims) or, with the predicted
    sets (26) of Section 4.1, of {H_θ θ <= h_{θ l|k}} per stage (None when any is not enumerable)."""
    r = view.records[k]
    N = view.problem.N
    if r.h_theta_stages is None:
        verts = view.theta_k_vertices[k]
        return None if verts is None else [verts] * N
    cache: dict[bytes, np.ndarray | None] = {}
    out = []
    for h_l in np.asarray(r.h_theta_stages, float):
        key = h_l.tobytes()
        if key not in cache:
            cache[key] = theta_vertices(r.H_theta, h_l)
        if cache[key] is None:
            return None
        out.append(cache[key])
    return out


def step_residuals(view: RunView, k: int, cost: str) -> dict[str, float] | None:
    """The KKT residuals of step k (None when Θ_k's vertices are not available)."""
    pr, d = view.problem, view.design
    r = view.records[k]
    lay = _Layout(pr.n, pr.m, pr.N)
    verts = _stage_vertices(view, k)
    if verts is None:
        return None
    bounds = tuple(r.pe_bounds) if r.pe_bounds is not None else None
    x = np.asarray(r.x, float)
    A, b = constraint_rows(pr, d, lay, x, verts, bounds)
    v = np.asarray(r.v, float)
    y = lay.pack(r.z, r.alpha, v)
    if cost == MINMAX:
        q, grad, t = _minmax_terms(pr, d, lay, y)
        T = pr.N + 1
        best = None
        for tol in ACTIVE_COST_TOLS:
            ls, js = np.nonzero(q >= (t - tol * np.maximum(t, COST_FLOOR))[:, None])
            columns = np.zeros((lay.size + T, len(ls)))
            columns[:lay.size] = grad[ls, js].T                                # ∇_y (q_lj − t_l)
            columns[lay.size + ls, np.arange(len(ls))] = -1.0                   # ∂/∂t_l
            result = kkt_residuals(A, b, y, [np.zeros(lay.size)], columns, np.maximum(t[ls] - q[ls, js], 0.0),
                                   np.ones(T))
            if best is None or _worst(result) < _worst(best):
                best = result
        return best
    own, later = ce_gradient_terms(pr, d, x, np.asarray(r.theta_hat, float), v)
    pad = np.zeros(lay.v0)
    theta_hat = np.asarray(r.theta_hat, float)
    curvature = ce_gradient(pr, d, np.zeros_like(x), theta_hat, v)                  # H v
    state = ce_gradient(pr, d, x, theta_hat, np.zeros_like(v))                      # q
    return kkt_residuals(A, b, y, [np.concatenate([pad, own.ravel()]), np.concatenate([pad, later.ravel()])],
                         scale_terms=[np.concatenate([pad, curvature.ravel()]), np.concatenate([pad, state.ravel()])])


def qp_optimality(view: RunView) -> CheckResult:
    """Claim ``qp_optimality`` (module docstring): KKT of (20) at the recorded (z, α, v), every solved step."""
    cost = getattr(view.traj.options, "cost", CE)
    per: dict[int, float] = {}
    worst = {"stationarity": 0.0, "complementarity": 0.0, "infeasibility": 0.0}
    unavailable = []
    for k in view.solved:
        res = step_residuals(view, k, cost) if cost in (CE, MINMAX) else None
        if res is None:
            per[k] = float("nan")
            unavailable.append(k)
            continue
        per[k] = -max(res["stationarity"], res["complementarity"], res["infeasibility"])
        worst = {key: max(value, res[key]) for key, value in worst.items()}
    detail = ("margin = −max(stationarity ‖∇f + Σω∇g‖_∞/s, complementarity Σ ω·slack/s, primal infeasibility) "
              "of (20) rebuilt from the record with (5b) in vertex form, for the best ω >= 0 found: NNLS on the rows "
              f"with slack <= one of {ACTIVE_TOLS}, else the LP over every row minimising the worst of the two "
              f"residuals; s = largest term of the sum; cost {cost}")
    if cost not in (CE, MINMAX):
        detail = f"cost {cost!r} has no optimality check"
    elif unavailable:
        detail = f"vertices of Θ_k not enumerable at steps {unavailable[:10]}; " + detail
    return row_check(CLAIM_ID, per, detail,
                     "no step was solved", extra={"cost": cost, **{f"worst_{k}": v for k, v in worst.items()}})
