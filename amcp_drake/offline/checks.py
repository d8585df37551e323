"""Independent verification of an offline design with numpy/scipy only (no backend).

Each check recomputes its quantity from the problem data and vertex enumeration, never from
the solver that produced the design: (16) by eigenvalues at every vertex of Θ, Assumption 8 by
spectral radii, contractivity and robust invariance of X0 from its vertices, Assumption 11 for
X_f by enumerating the vertices of X_f, Θ, X0 and W, and μ against (11).
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.check_result import CheckResult, judge, not_run
from amcp_drake.model.claim_table import claim as row_of
from amcp_drake.model.errors import DesignError
from amcp_drake.model.problem import Problem
from amcp_drake.offline.result import OfflineDesign, closed_loop_vertices, regressor_sup

# Each check's name, statement, tolerance and strictness are its row ``design.<name>`` of the table of claims
# (model.claim_table; tolerances model.tolerances EIG_TOL_REL, relative to the size of the terms of (16),
# VERTEX_TOL, OFFLINE_CONSTANTS_TOL; Assumption 8 and (11) strict with tolerance 0).
#: Most bytes of one array of the Assumption 11 check (a chunk of the vertices of X_f times the rows of
#: H_x at every vertex of Θ): 16 MiB.
CHECK_CHUNK_BYTES = 16 * 2**20


def verify_design(problem: Problem, design: OfflineDesign, mu_state_bound: float | None = None) -> list[CheckResult]:
    """All design checks, in the order a reader follows the paper."""
    theta_v = polytope.vertices(problem.H_theta, problem.h_theta)
    A_cl = closed_loop_vertices(problem, design.K, theta_v)
    checks = [
        _terminal_cost(problem, design, A_cl),
        _prestabilisation(A_cl),
    ]
    X0_v = polytope.vertices(design.H_x, np.ones(len(design.H_x)))
    W_v = problem.w_vertices()
    w_bar = np.max(design.H_x @ W_v.T, axis=1)
    h_bar = np.array([np.max(design.H_x @ Ak @ X0_v.T, axis=1) for Ak in A_cl])
    checks.append(_judge("design.x0_contractive", 1.0 - float(np.max(h_bar)), f"lambda_bar = {np.max(h_bar):.6f}"))
    checks.append(_judge("design.x0_robustly_invariant", 1.0 - float(np.max(h_bar + w_bar))))
    checks.append(_judge("design.w_bar_f_bar_recomputed",
                         -max(float(np.max(np.abs(w_bar - design.w_bar))),
                              float(np.max(np.abs(np.max((problem.F + problem.G @ design.K) @ X0_v.T, axis=1) - design.f_bar))))))
    checks.extend(_terminal_set(problem, design, A_cl, X0_v, W_v, w_bar, h_bar))
    checks.append(_mu(problem, design, mu_state_bound))
    return checks


def _judge(claim_id: str, margin: float | None, detail: str = "", scale: float = 1.0) -> CheckResult:
    """``margin`` judged as the claim's row says: its tolerance (times ``scale`` for a relative one), strict or not."""
    row = row_of(claim_id)
    return judge(row.name, row.statement, margin, row.tolerance * scale, detail, strict=row.strict)


def _terminal_cost(problem: Problem, design: OfflineDesign, A_cl: np.ndarray) -> CheckResult:
    K, P = design.K, design.P
    stage = problem.Q + K.T @ problem.R @ K
    worst = max(float(np.max(np.linalg.eigvalsh(Ak.T @ P @ Ak + stage - P))) for Ak in A_cl)
    size = max(max(np.linalg.norm(Ak.T @ P @ Ak, 2) for Ak in A_cl), np.linalg.norm(P, 2), np.linalg.norm(stage, 2))
    return _judge("design.terminal_cost_16", -worst, f"largest eigenvalue {worst:.3e} (terms of size {size:.3e})",
                  scale=float(size))


def _prestabilisation(A_cl: np.ndarray) -> CheckResult:
    radius = max(float(np.max(np.abs(np.linalg.eigvals(Ak)))) for Ak in A_cl)
    return _judge("design.assumption_8", 1.0 - radius, f"max spectral radius {radius!r} (must be < 1)")


def _terminal_set(problem, design, A_cl, X0_v, W_v, w_bar, h_bar) -> list[CheckResult]:
    """Assumption 11 at every vertex (z, α) of X_f, evaluated exactly and in bounded memory.

    Inclusion: the worst case of row i of H_x over (A_k, x_j, w) of A_k (z + α x_j) + w − z⁺ separates:
    max_w [H_x]_i w plus max_k ([H_x A_k z]_i − [H_x z⁺]_i + α s^k_i), where s^k_i = max_j [H_x A_k x_j]_i
    for α >= 0 and min_j for α < 0 (recomputed here from the vertices of X0). The constraint rows
    separate the same way over x_j. The vertices of X_f are taken in chunks of at most
    :data:`CHECK_CHUNK_BYTES` per array, so the work is (vertices of X_f) × (vertices of Θ) × rows
    and never (vertices of X_f) × (vertices of X0) × (vertices of Θ) × rows."""
    inv, con = row_of("design.x_f_invariant"), row_of("design.x_f_in_z")
    non_empty = _steady_tube_in_terminal_set(design, w_bar, h_bar)
    H = np.vstack([np.column_stack([design.H_T, design.h_T]), np.r_[np.zeros(problem.n), -1.0]])
    h = np.r_[np.ones(len(design.H_T)), 0.0]
    try:
        verts = polytope.vertices(H, h)
    except ValueError as exc:
        return [non_empty,
                not_run(inv.name, inv.statement, f"X_f is unbounded or flat, vertices not enumerable: {exc}"),
                not_run(con.name, con.statement, "X_f vertices not enumerable")]
    n = problem.n
    A_cl = np.asarray(A_cl, float)
    X0_v, W_v = np.asarray(X0_v, float), np.asarray(W_v, float)
    H_x = np.asarray(design.H_x, float)
    HA = np.array([H_x @ Ak for Ak in A_cl])                     # (a, rows, n): rows of H_x A_k
    HAz = H_x @ design.A_z                                        # (rows, n)
    # s^k_i over the vertices x_j of X0, for α >= 0 (max) and α < 0 (min)
    s_hi, s_lo = _row_extremes(HA.reshape(-1, n), X0_v)
    s_hi, s_lo = s_hi.reshape(len(A_cl), -1), s_lo.reshape(len(A_cl), -1)  # (a, rows)
    HW_max = np.max(W_v @ H_x.T, axis=0)                          # (rows,)
    FGK = problem.F + problem.G @ design.K
    f_hi, f_lo = _row_extremes(FGK, X0_v)                        # (constraint rows,)
    inclusion_margin = member_margin = con_margin = np.inf
    step = max(1, CHECK_CHUNK_BYTES // (8 * max(1, len(A_cl) * len(H_x), len(design.H_T), len(FGK))))
    for start in range(0, len(verts), step):
        Z, alpha = verts[start:start + step, :n], verts[start:start + step, n]
        up = (alpha >= 0)[None, :, None]
        a_col = alpha[None, :, None]
        Zk = np.einsum("kin,cn->kci", HA, Z)                     # (a, c, rows): H_x A_k z
        Zz = Z @ HAz.T                                            # (c, rows): H_x A_z z = H_x z⁺
        alpha_next = np.max(Zk - Zz[None] + h_bar[:, None, :] * a_col + w_bar[None, None, :], axis=(0, 2))  # φ(z, α)
        z_next = Z @ design.A_z.T
        member = np.minimum(1.0 - np.max(z_next @ design.H_T.T + alpha_next[:, None] * design.h_T[None, :], axis=1),
                            alpha_next)
        worst = np.max(np.max(Zk + a_col * np.where(up, s_hi[:, None, :], s_lo[:, None, :]), axis=0) - Zz
                       + HW_max[None, :], axis=1)
        cons = np.max(Z @ FGK.T + alpha[:, None] * np.where(alpha[:, None] >= 0, f_hi[None, :], f_lo[None, :]), axis=1)
        member_margin = min(member_margin, float(np.min(member)))
        inclusion_margin = min(inclusion_margin, float(np.min(alpha_next - worst)))
        con_margin = min(con_margin, 1.0 - float(np.max(cons)))
    detail = f"{len(verts)} vertices of X_f, {len(design.H_T)} rows"
    return [
        non_empty,
        _judge(inv.id, min(inclusion_margin, member_margin), detail),
        _judge(con.id, con_margin, detail),
    ]


def _row_extremes(rows: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(max_j rows_i · points_j, min_j rows_i · points_j) for every row i, in chunks of rows of at most
    :data:`CHECK_CHUNK_BYTES` (the full product is never formed)."""
    rows, points = np.asarray(rows, float), np.asarray(points, float)
    hi, lo = np.empty(len(rows)), np.empty(len(rows))
    step = max(1, CHECK_CHUNK_BYTES // (8 * max(1, len(points))))
    for start in range(0, len(rows), step):
        product = rows[start:start + step] @ points.T
        hi[start:start + step], lo[start:start + step] = np.max(product, axis=1), np.min(product, axis=1)
    return hi, lo


def _steady_tube_in_terminal_set(design: OfflineDesign, w_bar: np.ndarray, h_bar: np.ndarray) -> CheckResult:
    """X_f ≠ ∅ in the sense that matters (Appendix A.1): X_f = {H_T z + h_T α <= 1, α >= 0} always holds
    (0, 0), so emptiness as a set is never the question; a terminal set is of use only if it holds the
    steady state of the tube dynamics at z = 0, (0, α_∞), where α_∞ = max_{k,i} w̄_i / (1 − h̄^k_i) is
    the least fixed point of α ↦ φ(0, α) = max_{k,i} h̄^k_i α + w̄_i (finite when λ̄ < 1). Margin:
    1 − max_i [h_T]_i α_∞ (−inf when λ̄ >= 1). Invariance of X_f implies it (φ iterated from (0, 0)
    stays in X_f and tends to α_∞), so it fails together with "X_f invariant"; it says why."""
    row = row_of("design.x_f_non_empty")
    if float(np.max(h_bar)) >= 1.0:
        return judge(row.name, row.statement, float("-inf"), 0.0, "λ̄ >= 1: the tube has no steady state")
    alpha_inf = float(np.max(w_bar[None, :] / (1.0 - h_bar)))
    worst = float(np.max(design.h_T)) * alpha_inf if len(design.h_T) else 0.0
    return _judge(row.id, 1.0 - worst, f"α_∞ = {alpha_inf:.6g}, max h_T α_∞ = {worst:.6g}")


def _mu(problem: Problem, design: OfflineDesign, state_bound: float | None) -> CheckResult:
    """(11) recomputed from the problem, not from the design's ``mu_sup``: S = sup ‖D(x,u)‖₂² over the
    region, exact from its vertices when their estimated count allows, else the upper bound of
    :func:`~amcp_drake.offline.result.regressor_upper_bound` (S >= the supremum, so μ S < 1 implies
    μ ‖D(x,u)‖₂² < 1 on the whole region: (11))."""
    row = row_of("design.mu_condition_11")
    try:
        found = regressor_sup(problem, state_bound)
    except (ValueError, DesignError) as exc:
        return not_run(row.name, row.statement, str(exc))
    return _judge(row.id, 1.0 - design.mu * found.value,
                  f"μ = {design.mu:.6g}, sup ‖D‖² <= {found.value:.6g} over {found.region} ({found.detail}; "
                  "μ·sup ‖D‖² must be < 1)")
