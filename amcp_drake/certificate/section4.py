"""Certificate checks of the optional parts of Section 4 and of the recorded cost.

* ``cost_value``: the recorded ``cost`` of every solved step is the objective the run claims to
  minimise, evaluated with numpy from the recorded decision: (17) with the nominal prediction (18)
  and the recorded θ̂_k (certainty equivalence), or (19), the worst case over the tube vertices
  x^j_{l|k} = z_{l|k} + α_{l|k} x^j (min–max, Remark 13; docs/decisions.md "Min–max cost (19)").
* ``pe_level`` (only when the run enforces persistent excitation, docs/explanation/paper.md §8): at every step whose
  record says the PE constraint was enforced, λ_min of the window Gram
  Σ_{j=k−P+1}^{k} ū_j ū_jᵀ, ū_j = [u_j; …; u_{j−d+1}] (d = ``pe_dim``), of the inputs the run
  actually applied reaches the recorded ``pe_level``.
* ``pe_bounds`` (same condition): u_k lies within the recorded first-input bounds of the QP that
  was chosen (docs/explanation/paper.md §8 step 3).

Both PE claims are absent from a run without PE (they are options, not claims of the paper's
Theorem 14). The PE status counts and Definition 21 for the realised regressor D_kᵀ are figures
(``figures["persistent_excitation"]``), not pass/fail claims: the paper does not claim that the
input constraint makes the regressor PE on every run.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.certificate.claims import RunView, row_check, tag
from amcp_drake.model.check_result import CheckResult, not_run
from amcp_drake.model.claim_table import claim as row_of
from amcp_drake.online.excitation import pe_measure

# The claims' tolerances (model.tolerances COST_REL_TOL, PE_LEVEL_TOL, PE_BOUND_TOL, all relative), names and
# statements are their rows of the table of claims (model.claim_table).
#: Recorded cost vs the numpy evaluation, relative to max(|J|, COST_SCALE_FLOOR) (absolute below 1).
#: Certainty equivalence: both sides are the same quadratic of recorded floats (~1e-14 relative).
#: Min–max: the backends record (19) of their plan (amcp_drake.backends.minmax_cost; not
#: the solver's Σ s_l², which can be 1.3e-6 relative off (19) on a problem in badly scaled state units),
#: so both sides are the same formula of recorded floats too.
COST_SCALE_FLOOR = 1.0

#: Record statuses at which the PE constraint was enforced (controller.AdaptiveMPC._solve_qp).
ENFORCED = ("enforced", "enforced_partial", "enforced_necessary")
PE_STATUSES = ("off", "inactive", "satisfied") + ENFORCED + ("fallback",)


def certainty_equivalence_cost(problem, design, x, theta_hat, v) -> float:
    """J_N of (17): Σ_{l<N} ‖x̂_l‖²_Q + ‖K x̂_l + v_l‖²_R + ‖x̂_N‖²_P along (18),
    x̂_{l+1} = A(θ̂) x̂_l + B(θ̂)(K x̂_l + v_l), x̂_0 = x_k."""
    A = problem.A0 + np.tensordot(theta_hat, problem.A, axes=1)
    B = problem.B0 + np.tensordot(theta_hat, problem.B, axes=1)
    K = np.asarray(design.K, float)
    xh = np.asarray(x, float)
    J = 0.0
    for vl in np.asarray(v, float):
        u = K @ xh + vl
        J += float(xh @ problem.Q @ xh + u @ problem.R @ u)
        xh = A @ xh + B @ u
    return J + float(xh @ np.asarray(design.P, float) @ xh)


def minmax_cost(problem, design, z, alpha, v) -> float:
    """(19): Σ_{l<N} max_j (‖x^j_l‖²_Q + ‖u^j_l‖²_R) + max_j ‖x^j_N‖²_P with x^j_l = z_l + α_l x^j
    (x^j the vertices of X0) and u^j_l = K x^j_l + v_l."""
    Xv = np.asarray(design.X0_vertices, float)
    K, P = np.asarray(design.K, float), np.asarray(design.P, float)
    z, alpha, v = np.asarray(z, float), np.asarray(alpha, float), np.asarray(v, float)
    J = 0.0
    for l in range(len(v)):
        X = z[l] + alpha[l] * Xv                    # (nv, n): the vertices of X_{l|k}
        U = X @ K.T + v[l]
        J += float(np.max(np.einsum("jn,nm,jm->j", X, problem.Q, X) + np.einsum("jn,nm,jm->j", U, problem.R, U)))
    X = z[len(v)] + alpha[len(v)] * Xv
    return J + float(np.max(np.einsum("jn,nm,jm->j", X, P, X)))


def cost_value(view: RunView) -> CheckResult:
    """The recorded cost of every solved step equals (17) or (19) evaluated from the recorded data."""
    cost = getattr(view.traj.options, "cost", "certainty_equivalence")
    pr, d = view.problem, view.design
    per: dict[int, float] = {}
    for k in view.solved:
        r = view.records[k]
        if r.cost is None:
            per[k] = float("nan")
            continue
        if cost == "minmax":
            J = minmax_cost(pr, d, r.z, r.alpha, r.v)
        else:
            J = certainty_equivalence_cost(pr, d, r.x, r.theta_hat, r.v)
        per[k] = -abs(float(r.cost) - J) / max(abs(J), COST_SCALE_FLOOR)
    variant = ({"name": "cost (19)", "statement": "Remark 13, (19): the recorded cost is Σ_l max_j (‖x^j_l‖²_Q + "
                "‖u^j_l‖²_R) + max_j ‖x^j_N‖²_P of the recorded tube and inputs"} if cost == "minmax" else {})
    name = variant.get("name", row_of("cost_value").name)
    return row_check("cost_value", per, f"margin = −|recorded cost − numpy {name}| / max(|J|, {COST_SCALE_FLOOR:g})",
                     "no step was solved", extra={"cost": cost}, **variant)


def pe_enabled(view: RunView) -> bool:
    return getattr(view.traj.options, "pe_window", None) is not None


def applied_inputs(view: RunView) -> np.ndarray:
    """u_0 … u_T' (m = 1): the applied inputs, plus the last computed one when it was recorded."""
    return np.array([float(u[0]) for _, _, u in view.inputs])


def window_gram(u: np.ndarray, k: int, dim: int, window: int) -> np.ndarray | None:
    """Σ_{j=k−P+1}^{k} ū_j ū_jᵀ, ū_j = [u_j; u_{j−1}; …; u_{j−d+1}] (None when the history is short).

    Written again on purpose, not :func:`amcp_drake.online.excitation.stacked_gram`: that one is part of
    the controller's PE rule whose output this claim checks, so sharing it would let one indexing
    bug pass its own check."""
    first = k - window - dim + 2
    if first < 0 or k >= len(u):
        return None
    G = np.zeros((dim, dim))
    for j in range(k - window + 1, k + 1):
        ub = np.array([u[j - i] for i in range(dim)])
        G += np.outer(ub, ub)
    return G


def pe_level(view: RunView) -> CheckResult:
    """At every enforced step: λ_min(window Gram of dimension pe_dim) >= recorded pe_level."""
    P = int(view.traj.options.pe_window)
    u = applied_inputs(view)
    per: dict[int, float] = {}
    for k, _, _ in view.inputs:
        r = view.records[k]
        if r.pe_status not in ENFORCED:
            continue
        G = None if r.pe_dim is None or r.pe_level is None else window_gram(u, k, int(r.pe_dim), P)
        if G is None:  # an enforced step without its level, or before the window it needs: inconsistent
            per[k] = -np.inf
            continue
        per[k] = (float(np.linalg.eigvalsh(G)[0]) - float(r.pe_level)) / max(1.0, abs(float(r.pe_level)))
    return row_check("pe_level", per, f"margin = (λ_min − pe_level) / max(1, pe_level), window P = {P}; "
                      "−inf at an enforced step that records no level or precedes its window",
                      "no step enforced the PE constraint in this run")


def pe_bounds(view: RunView) -> CheckResult:
    """At every step with recorded PE bounds (lo, hi): lo <= u_k <= hi."""
    per: dict[int, float] = {}
    for k, _, u in view.inputs:
        r = view.records[k]
        if r.pe_status in ENFORCED and r.pe_bounds is None:  # enforced, yet no bounds recorded
            per[k] = -np.inf
            continue
        if r.pe_bounds is None:
            continue
        lo, hi = (float(b) for b in r.pe_bounds)
        uk = float(u[0])
        per[k] = min((uk - lo) / max(1.0, abs(lo)) if np.isfinite(lo) else np.inf,
                     (hi - uk) / max(1.0, abs(hi)) if np.isfinite(hi) else np.inf)
    return row_check("pe_bounds", per, "margin = distance of u_k inside [lo, hi], relative to max(1, |bound|); "
                      "−inf at an enforced step that records no bounds",
                      "no step recorded PE bounds")


def option_checks(view: RunView) -> list[CheckResult]:
    """The claims of this module that apply to the run's options, in reading order."""
    return [cost_value(view)] + excitation_checks(view)


def excitation_checks(view: RunView) -> list[CheckResult]:
    """``pe_level`` and ``pe_bounds`` when the run enforces persistent excitation, else nothing."""
    checks: list[CheckResult] = []
    if pe_enabled(view):
        if view.problem.m != 1:
            checks.append(tag(not_run("PE window level", "Section 4.2: the PE constraint", "PE needs m = 1"), "pe_level",
                              row_of("pe_level").family))
        else:
            checks += [pe_level(view), pe_bounds(view)]
    return checks


def pe_figure(view: RunView) -> dict | None:
    """PE status counts and Definition 21 of the realised regressor Φ_k = D_kᵀ over windows of P steps
    (None when the run does not enforce PE)."""
    if not pe_enabled(view):
        return None
    P = int(view.traj.options.pe_window)
    statuses = [r.pe_status for r in view.records]
    counts = {s: statuses.count(s) for s in PE_STATUSES if statuses.count(s)}
    u = applied_inputs(view)
    input_lmin = [float(np.linalg.eigvalsh(G)[0]) for k in range(len(u))
                  if (G := window_gram(u, k, view.problem.n + 1, P)) is not None]
    D = np.array([view.regressor(k) for k in view.transitions])
    reg_lmin = pe_measure(D, P)[0].tolist() if len(D) >= P else []
    return {"window": P, "level": float(view.traj.options.pe_level), "status_counts": counts,
            "input_gram_lambda_min": {"min": min(input_lmin, default=None),
                                      "median": float(np.median(input_lmin)) if input_lmin else None},
            "regressor_gram_lambda_min": {"min": min(reg_lmin, default=None),
                                          "median": float(np.median(reg_lmin)) if reg_lmin else None}}
