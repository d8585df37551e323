"""Offline design (docs/explanation/paper.md §4-§6, Appendix A.1): K, P, X0, w̄, f̄, h̄^k, X_f, μ, and the shape H_θ of (9).

Every optimisation problem is formulated by the chosen backend (gain LMI, support LPs); this
module only orchestrates. Choices where the paper is silent ([REC] in the spec) are documented
on :class:`~amcp_drake.model.problem.DesignOptions` and in docs/decisions.md.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.backends import get_backend
from amcp_drake.model import polytope
from amcp_drake.model.errors import DesignError, ProblemError, TerminalSetError
from amcp_drake.model.problem import DEFAULT_X0_LAMBDA, DesignOptions, Problem
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline import parallelotope, preimage, units
from amcp_drake.offline import templates as x0_templates
from amcp_drake.offline.auto import design_auto, template_label
from amcp_drake.offline.budget import DesignBudget, chunked_row_maxima, chunked_tight_counts, unbounded
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.result import OfflineDesign, closed_loop_vertices, regressor_bound, regressor_sup
from amcp_drake.offline.support import bounded_vertices, row_maxima
from amcp_drake.offline.terminal import scaled_terminal_set, terminal_set_kind

__all__ = ["OfflineDesign", "closed_loop_vertices", "regressor_bound", "design", "design_fixed", "robust_gain",
           "template_label", "terminal_set", "template_directions"]

#: A candidate row of the terminal-set recursion is redundant if the current set keeps it below
#: 1 + this (LP accuracy of Clarabel is ~1e-8; looser than that would keep duplicates).
TERMINAL_REDUNDANCY_TOL = 1e-7
#: Most rows of X_f in the (z, α) recursion per dimension of (z, α): the recursion stops with a
#: TerminalSetError ("too complex") once X^i has more than this times n + 1 rows. Every design of the
#: shipped examples and the size table has at most 102 rows; a generated one-state problem grew to a
#: million rows (6 GB) without converging, each iteration slower than the last.
TERMINAL_MAX_ROWS_PER_DIM = 2000
#: Kept importable from here (moved to offline/templates.py with the template code).
template_directions = x0_templates.template_directions
MRPI_RESIDUAL_FRACTION = x0_templates.MRPI_RESIDUAL_FRACTION
X0_INFLATION = x0_templates.X0_INFLATION


def design(problem: Problem, options: DesignOptions | None = None, backend="drake",
           budget: DesignBudget | None = None) -> OfflineDesign:
    """Compute the offline design of the algorithm (the offline part of the paper's algorithm).

    With ``options.x0_template == "auto"`` (the default) the templates of
    :mod:`amcp_drake.offline.auto` are tried in their documented order and the first design that
    passes every check of :func:`~amcp_drake.offline.checks.verify_design` in the user's units is
    returned (the attempts are in ``design.info["attempts"]``). Otherwise the named template is used
    (:func:`design_fixed`). Either way the design is computed in the state units normalised by W
    and mapped back (:mod:`amcp_drake.offline.units`), so the same system in other diagonal state
    units gets the same design; with W's extents equal these units are the user's, bit for bit.

    ``budget`` (:class:`~amcp_drake.offline.budget.DesignBudget`): the memory limit every stage is
    sized against, the time budget of one candidate and the progress callback; None: the default
    memory limit, no time budget, no progress lines.

    Raises DesignError (or TerminalSetError, TemplateError, DesignSizeError, CandidateTimeout) naming
    the step and the condition that failed; in auto mode a
    :class:`~amcp_drake.offline.auto.AutoDesignError` listing every attempt.
    """
    options = (options or DesignOptions()).validate_for(problem)
    budget = budget or unbounded()
    if options.x0_template != "auto":
        return design_fixed(problem, options, backend=backend, budget=budget)
    s = units.normalising_scales(problem, options)
    if units.is_identity(s):
        return design_auto(problem, options, backend=backend, design_fixed=_design_as_written, robust_gain=robust_gain,
                           verify=verify_design, budget=budget)
    normalised, normalised_options = units.to_normalised(problem, options, s)

    def verify_in_users_units(_normalised: Problem, found: OfflineDesign, _bound) -> list:
        return verify_design(problem, units.from_normalised(found, s, problem, options), options.mu_state_bound)

    found = design_auto(normalised, normalised_options, backend=backend, design_fixed=_design_as_written,
                        robust_gain=robust_gain, verify=verify_in_users_units, budget=budget)
    return units.from_normalised(found, s, problem, options)


def robust_gain(problem: Problem, options: DesignOptions, be) -> tuple[np.ndarray, np.ndarray, str]:
    """K and P of Assumption 8 and (16): given, or from the robust LMI with R scaled by
    ``options.gain_R_scale`` (>= 1). A larger R gives a lower-gain K; the P of that LMI satisfies
    A_clᵀPA_cl + Q + c KᵀRK ⪯ P, hence (16) with the true R as well (c KᵀRK ⪰ KᵀRK for c >= 1).
    Returns (K, P, source) with source "given", "lmi" or "lmi (R x c)"."""
    if options.K is not None and options.P is not None:
        return np.asarray(options.K), np.asarray(options.P), "given"
    if options.K is not None or options.P is not None:
        raise ProblemError("design.K, design.P", "both K and P, or neither", "only one of them")
    theta_vertices = problem.theta_vertices()
    A_v = np.array([problem.A_of(t) for t in theta_vertices])
    B_v = np.array([problem.B_of(t) for t in theta_vertices])
    scale = float(options.gain_R_scale)
    gain = be.robust_gain(A_v, B_v, problem.Q, scale * problem.R, options.lmi_margin)
    if gain.status is not SolveStatus.OPTIMAL:
        raise DesignError(f"gain LMI (16) for K, P: solver status {gain.status.value}; no robustly "
                          "stabilising state feedback with a common quadratic Lyapunov function was found "
                          "for the vertices of Theta (Assumption 8)")
    return gain.K, gain.P, "lmi" if scale == 1.0 else f"lmi (R x {scale:g})"


def design_fixed(problem: Problem, options: DesignOptions, backend="drake", gain=None,
                 budget: DesignBudget | None = None) -> OfflineDesign:
    """The offline design with the template named by ``options.x0_template`` (not "auto"), computed
    in the state units normalised by W and mapped back (:mod:`amcp_drake.offline.units`; with W's
    extents equal, the design as written, bit for bit).

    ``gain``: an already computed (K, P, source) of :func:`robust_gain` for these options, in the
    user's units; None computes it. The design is not checked here (the certificate does), except
    that a check passing in the normalised units must pass on the mapped design in the user's units:
    :class:`~amcp_drake.offline.units.UnitsMappingError` otherwise.
    """
    options = options.validate_for(problem)
    s = units.normalising_scales(problem, options)
    if units.is_identity(s):
        return _design_as_written(problem, options, backend=backend, gain=gain, budget=budget)
    normalised, normalised_options = units.to_normalised(problem, options, s)
    found = _design_as_written(normalised, normalised_options, backend=backend, gain=units.gain_to_normalised(gain, s),
                               budget=budget)
    mapped = units.from_normalised(found, s, problem, options, gain)
    failed = [c.name for c in verify_design(problem, mapped, options.mu_state_bound) if not c.passed]
    if failed:
        passed_in_xi = {c.name for c in verify_design(normalised, found, normalised_options.mu_state_bound) if c.passed}
        lost = [name for name in failed if name in passed_in_xi]
        if lost:
            raise units.UnitsMappingError(lost)
    return mapped


def _design_as_written(problem: Problem, options: DesignOptions, backend="drake", gain=None,
                       budget: DesignBudget | None = None) -> OfflineDesign:
    """The design of :func:`design_fixed` in the units ``problem`` is written in (no normalisation):
    the template design of docs/explanation/paper.md §4-§6; the automatic mode runs it on the normalised problem. Every
    stage is sized against ``budget`` before it allocates (module offline/budget.py)."""
    options = options.validate_for(problem)
    budget = budget or unbounded()
    be = get_backend(backend)
    # μ, eq. (11), first: it needs no solver and fails fast on a missing state box
    # (exact over the vertices of the (x, u) region when their estimated count allows, else an upper bound)
    mu_found = regressor_sup(problem, options.mu_state_bound, budget)
    mu_sup, region = mu_found.value, mu_found.region
    mu = options.mu_fraction / mu_sup
    theta_vertices = problem.theta_vertices()

    # K and P: Assumption 8 and (16)
    K, P, source = gain if gain is not None else robust_gain(problem, options, be)
    T_par = None
    if options.x0_template == "parallelotope":  # K from the LP of offline/parallelotope.py, P from (16) for it
        K, P, source, T_par = _parallelotope_gain(problem, options, K, P, source, be, budget)
    A_cl = closed_loop_vertices(problem, K, theta_vertices)
    _require_stable(A_cl)
    if source != "given":
        _require_terminal_cost(problem, K, P, A_cl)

    # X0: the cross-section template (offline/templates.py)
    FGK = problem.F + problem.G @ K
    budget.tick("X0 template")
    H_x = _x0(problem, A_cl, FGK, be, options, budget, K) if T_par is None else _parallelotope_x0(problem, A_cl, T_par, budget)
    budget.require_vertices("X0 vertices", len(H_x), problem.n)
    X0_vertices = polytope.vertices(H_x, np.ones(len(H_x)))
    budget.tick("w_bar, f_bar, h_bar")
    w_lp = be.support(problem.H_w, np.ones(len(problem.H_w)), H_x)
    f_lp = be.support(H_x, np.ones(len(H_x)), FGK)
    h_lp = np.array([be.support(H_x, np.ones(len(H_x)), H_x @ Ak) for Ak in A_cl])
    # The LP values are upper bounds only up to the solver's tolerance; the maxima over the vertices
    # of W and X0 are exact, so the larger of the two is a valid bound for either backend (found on
    # parsi2020_siso: the cvxpy backend's f̄ was 1.5e-9 too small and X_f left Z by 2e-8). An LP that
    # fails (NaN) leaves the exact vertex maximum; the count is recorded in info["support_lp_failures"].
    # W and X0 are bounded here (their vertices were enumerated, which refuses an unbounded set), so an
    # LP that reports "unbounded" (inf) contradicts the set it was given: a solver failure on badly
    # scaled rows, counted with the failures and replaced by the exact vertex maximum as well.
    budget.require_vertices("w_bar: the vertices of W", len(problem.H_w), problem.n)
    w_vx = chunked_row_maxima(H_x, problem.w_vertices(), budget, "w_bar")
    f_vx = chunked_row_maxima(FGK, X0_vertices, budget, "f_bar")
    h_vx = np.array([chunked_row_maxima(H_x @ Ak, X0_vertices, budget, "h_bar") for Ak in A_cl])
    w_lp, f_lp, h_lp = (_failed_if_unbounded(v) for v in (w_lp, f_lp, h_lp))
    lp_failures = int(sum(np.count_nonzero(np.isnan(v)) for v in (w_lp, f_lp, h_lp)))
    w_bar, f_bar, h_bar = np.fmax(w_lp, w_vx), np.fmax(f_lp, f_vx), np.fmax(h_lp, h_vx)
    _require_finite_support("w_bar", w_bar)
    _require_finite_support("f_bar", f_bar)
    _require_finite_support("h_bar", h_bar)
    lambda_bar = float(np.max(h_bar))
    if lambda_bar >= 1.0:
        raise DesignError(f"X0 is not contractive: lambda_bar = {lambda_bar:.4f} >= 1 (Appendix A.1 conditions); "
                          "try more facets (design.x0_facets) or x0_template = 'contractive'")

    # terminal set X_f, Appendix A.1 (the recursion) or the scaled copy of X0 (offline/terminal.py)
    terminal_kind = terminal_set_kind(options, problem.n)
    if terminal_kind == "scaled":
        A_z = np.zeros((problem.n, problem.n))  # the witness of the scaled copy is z⁺ = 0
        H_T, h_T = scaled_terminal_set(H_x, f_bar, w_bar, h_bar)
        iterations = 0
    else:
        if options.centre_dynamics == "nominal":
            A_z = problem.A_of(problem.theta_hat0) + problem.B_of(problem.theta_hat0) @ K
        else:
            A_z = np.zeros((problem.n, problem.n))
        H_T, h_T, iterations = terminal_set(FGK, f_bar, H_x, A_cl, A_z, w_bar, h_bar, be, options.terminal_max_iter,
                                            budget=budget)

    # fixed-complexity shape of (9)
    H_theta = problem.H_theta
    if options.theta_extra_directions is not None:
        H_theta = np.vstack([H_theta, options.theta_extra_directions])
    H_theta_n, _ = polytope.normalize_rows(H_theta, np.zeros(len(H_theta)))
    h_theta0 = be.support(problem.H_theta, problem.h_theta, H_theta_n)
    _require_finite_support("h_theta0", h_theta0)

    info = {"x0_template": template_label(options, len(H_x), dimension=problem.n), "terminal_set": terminal_kind}
    if lp_failures:
        info["support_lp_failures"] = lp_failures
    return OfflineDesign(K=K, P=P, H_x=H_x, X0_vertices=X0_vertices, w_bar=w_bar, f_bar=f_bar, h_bar=h_bar,
                         lambda_bar=lambda_bar, A_z=A_z, H_T=H_T, h_T=h_T, mu=float(mu), mu_sup=float(mu_sup),
                         mu_region=region, H_theta=H_theta_n, h_theta0=h_theta0, theta_vertices=theta_vertices,
                         terminal_iterations=iterations, backend=be.name, gain_source=source, info=info,
                         mu_state_bound=options.mu_state_bound, mu_method=mu_found.detail)


def _parallelotope_gain(problem: Problem, options: DesignOptions, K, P, source: str, be, budget: DesignBudget):
    """(K, P, source, T) of the parallelotope template (offline/parallelotope.py): a given K is kept
    (only the basis T is computed for it); otherwise K from the LP started at the LMI gain and P from
    the LMI (16) for that K."""
    if source == "given":
        A0, B0 = problem.A_of(problem.theta_hat0), problem.B_of(problem.theta_hat0)
        T = np.linalg.inv(parallelotope.real_eigenbasis(A0 + B0 @ K))
        return K, P, source, parallelotope.perron_scaled(T, closed_loop_vertices(problem, K, problem.theta_vertices()))
    K_lp, T, _ = parallelotope.parallelotope_gain(problem, K, budget)
    P_lp = parallelotope.fixed_gain_terminal_weight(problem, K_lp, be, options.lmi_margin)
    return K_lp, P_lp, "lp (parallelotope)" if source == "lmi" else f"lp (parallelotope, from {source})", T


def _parallelotope_x0(problem: Problem, A_cl: np.ndarray, T: np.ndarray, budget: DesignBudget) -> np.ndarray:
    """H_x of {‖T x‖∞ <= 1} scaled to robust invariance (offline/parallelotope.py, step 3)."""
    n = problem.n
    budget.require("X0 template parallelotope: vertices", 8.0 * (2 ** n) * n * 4, f"2^{n} vertices")
    signs = np.array(np.meshgrid(*[[-1.0, 1.0]] * n, indexing="ij")).reshape(n, -1).T
    verts = signs @ np.linalg.inv(T).T
    H = np.vstack([T, -T])
    return x0_templates.scale_to_robust_invariance(H, verts, problem.H_w, A_cl, "parallelotope")


def _require_stable(A_cl: np.ndarray) -> None:
    radius = max(float(np.max(np.abs(np.linalg.eigvals(Ak)))) for Ak in A_cl)
    if radius >= 1.0:
        raise DesignError(f"Assumption 8 fails: spectral radius of A_cl at a vertex of Theta is {radius:.4f} >= 1")


def _require_terminal_cost(problem: Problem, K: np.ndarray, P: np.ndarray, A_cl: np.ndarray) -> None:
    """Re-check (16) by eigenvalues: an SDP solver may call a solution of tolerance size optimal."""
    worst = max(float(np.max(np.linalg.eigvalsh(Ak.T @ P @ Ak + problem.Q + K.T @ problem.R @ K - P))) for Ak in A_cl)
    if worst > 0.0:
        raise DesignError(f"gain LMI (16): the solver's K, P violate (16) by {worst:.3e} (largest eigenvalue); "
                          "the robust LMI is (nearly) infeasible for the vertices of Theta (Assumption 8)")


def _failed_if_unbounded(values: np.ndarray) -> np.ndarray:
    """Support-LP values over a set known to be bounded, with +inf ("unbounded") marked as failed (NaN)."""
    values = np.array(values, float)
    values[np.isposinf(values)] = np.nan
    return values


def _require_finite_support(name: str, values: np.ndarray) -> None:
    if not np.all(np.isfinite(values)):
        raise DesignError(f"{name}: a support-function LP was unbounded or failed ({values.tolist()})")


def _x0(problem: Problem, A_cl: np.ndarray, FGK: np.ndarray, be, options: DesignOptions,
        budget: DesignBudget | None = None, K: np.ndarray | None = None) -> np.ndarray:
    """Tube shape X0 = {H_x x <= 1} by the template of ``options.x0_template`` (offline/templates.py)."""
    kind = options.x0_template
    if kind == "mrpi":
        return x0_templates.mrpi_template(problem.H_w, A_cl, be, options.facets_for(problem.n), options.mrpi_max_iter,
                                          Z_rows=np.hstack([problem.F, problem.G]), budget=budget)
    if kind == "contractive":
        lam = options.x0_lambda if options.x0_lambda is not None else DEFAULT_X0_LAMBDA
        return x0_templates.contractive_template(FGK, problem.H_w, A_cl, be, lam,
                                                 max_rows=_row_cap(x0_templates.contractive_max_rows(problem.n), options),
                                                 budget=budget)
    if kind == "given":
        return x0_templates.given_template(options.x0_H, problem.H_w, A_cl)
    if kind == "preimage":
        lam = options.x0_lambda if options.x0_lambda is not None else preimage.PREIMAGE_LAMBDAS[0]
        A_nom = problem.A_of(problem.theta_hat0) + problem.B_of(problem.theta_hat0) @ K
        return preimage.preimage_template(FGK, problem.H_w, A_cl, A_nom, be, lam, options.mrpi_max_iter,
                                          _row_cap(preimage.preimage_max_rows(problem.n), options), budget=budget)
    raise ProblemError("design.x0_template", f"one of {list(x0_templates.TEMPLATE_KINDS)}", repr(kind))


def _row_cap(own: int, options: DesignOptions) -> int:
    """The row cap of a template: its own (``own``), lowered to ``design.x0_max_facets`` when that is given."""
    return own if options.x0_max_facets is None else min(own, int(options.x0_max_facets))


def terminal_max_rows(n: int) -> int:
    """The row cap of the terminal-set recursion for n states (:data:`TERMINAL_MAX_ROWS_PER_DIM` × (n + 1))."""
    return TERMINAL_MAX_ROWS_PER_DIM * (int(n) + 1)


def terminal_set(FGK, f_bar, H_x, A_cl, A_z, w_bar, h_bar, be, max_iter: int, budget: DesignBudget | None = None):
    """X_f by the (z, α) recursion of Appendix A.1 (Assumption 11).

    X^0 = {(F+GK) z + f̄ α <= 1, α >= 0};  X^{i+1} = X^i ∩ Pre(X^i) with the map
    (z, α) ↦ (A_z z, φ(z, α)), φ = max_{k,i'} [E^k]_{i'} z + [h̄^k]_{i'} α + [w̄]_{i'},
    E^k = H_x (A_cl(θ^k) - A_z). Since Pre distributes over intersections, only the rows added in
    the previous iteration are propagated. Rows are kept as [a, b] with a z + b α <= 1, b >= 0.

    Redundancy: while X^i is unbounded, each candidate row is tested by a support LP of the
    backend; once it is bounded, exactly by its vertices (a linear function attains its maximum
    over a polytope at a vertex), which is far faster and needs no solver tolerance.

    Size: the candidate rows of an iteration (new rows × v_p × u) and every vertex enumeration are
    sized against ``budget`` before they are formed (DesignSizeError naming the stage otherwise), and
    the rows × vertices products are computed in chunks (offline/budget.py); X^i with more rows than
    :func:`terminal_max_rows` ends the recursion with TerminalSetError ("too complex").
    Returns (H_T, h_T, iterations).
    """
    budget = budget or unbounded()
    n = FGK.shape[1]
    current = _prune(_dedupe(np.column_stack([FGK, f_bar])), be, budget)
    new = current
    E = np.array([H_x @ (Ak - A_z) for Ak in A_cl])  # (v_p, u, n)
    for iteration in range(1, max_iter + 1):
        stage = f"terminal set X_f, iteration {iteration} ({len(current)} rows)"
        budget.tick(stage)
        budget.require(stage, 8.0 * len(new) * len(A_cl) * len(H_x) * (n + 1) * 3,
                       f"{len(new)} new rows x {len(A_cl)} vertices of Theta x {len(H_x)} rows of X0 candidate rows")
        candidates = []
        for a_b in new:
            a, b = a_b[:n], a_b[n]
            rhs = 1.0 - b * w_bar  # (u,)
            if np.any(rhs <= 0.0):
                raise TerminalSetError(
                    f"terminal set X_f is empty (iteration {iteration}): a constraint row needs alpha <= "
                    f"{1.0 / max(b, 1e-300):.4g} but the disturbance alone forces alpha >= {np.max(w_bar):.4g} "
                    "(Appendix A.1: alpha_inf f_bar < 1 fails). Choose a smaller X0 (more facets) or relax Z.")
            for k in range(len(A_cl)):
                lhs_z = a @ A_z + b * E[k]          # (u, n)
                lhs_a = b * h_bar[k]                 # (u,)
                candidates.append(np.column_stack([lhs_z, lhs_a]) / rhs[:, None])
        cand = _dedupe(np.vstack(candidates))
        values = _row_maxima(current, cand, be, budget, stage)
        if np.any(np.isnan(values)):
            raise TerminalSetError(f"terminal set recursion: an LP failed at iteration {iteration}")
        keep = ~(values <= 1.0 + TERMINAL_REDUNDANCY_TOL)
        if not np.any(keep):
            return current[:, :n], current[:, n], iteration
        merged = _prune(np.vstack([current, cand[keep]]), be, budget)
        cap = terminal_max_rows(n)
        if len(merged) > cap:
            raise TerminalSetError(
                f"terminal set X_f too complex: {len(merged)} rows after {iteration} iterations (cap {cap} = "
                f"{TERMINAL_MAX_ROWS_PER_DIM} x (n + 1)); the recursion of Appendix A.1 does not settle for this X0 "
                "and K. Next: design.terminal_set = 'scaled', or another X0 template (design.x0_template).")
        old = {tuple(np.round(r, 10)) for r in current}
        new = np.array([r for r in merged if tuple(np.round(r, 10)) not in old])
        current = merged
        if len(new) == 0:
            return current[:, :n], current[:, n], iteration
    raise TerminalSetError(
        f"terminal set recursion did not converge in {max_iter} iterations; finite termination needs "
        "A_z Schur, lambda_bar < 1, X_f^0 bounded and the fixed point (0, alpha_inf) strictly inside X_f^0 "
        "(Appendix A.1). Check that Z bounds the state in every direction reachable by (F+GK).")


def _with_alpha_nonneg(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    dim = rows.shape[1]
    alpha_row = np.zeros(dim)
    alpha_row[-1] = -1.0
    return np.vstack([rows, alpha_row]), np.concatenate([np.ones(len(rows)), [0.0]])


def _dedupe(rows: np.ndarray) -> np.ndarray:
    rounded = np.round(rows, 10)
    _, idx = np.unique(rounded, axis=0, return_index=True)
    return rows[np.sort(idx)]


def _bounded_vertices(rows: np.ndarray, be, budget: DesignBudget | None = None,
                      stage: str = "terminal set X_f: vertices") -> np.ndarray | None:
    """Vertices of {rows · y <= 1, α >= 0} when it is bounded (checked by backend LPs), else None."""
    return bounded_vertices(*_with_alpha_nonneg(rows), be, budget, stage)


def _row_maxima(rows: np.ndarray, directions: np.ndarray, be, budget: DesignBudget | None = None,
                stage: str = "terminal set X_f") -> np.ndarray:
    """max of each direction over {rows · y <= 1, α >= 0}: by vertices when bounded, else by LPs."""
    return row_maxima(*_with_alpha_nonneg(rows), directions, be, budget, stage)


def _prune(rows: np.ndarray, be, budget: DesignBudget | None = None) -> np.ndarray:
    """Remove rows of {rows · (z, α) <= 1, α >= 0} implied by the others.

    Bounded case: a row is kept iff it is tight (within TERMINAL_REDUNDANCY_TOL) at >= dim
    vertices of the set, i.e. it supports a facet (rows × vertices in chunks). Unbounded case: one
    support LP per row.
    """
    budget = budget or unbounded()
    dim = rows.shape[1]
    stage = f"terminal set X_f: redundant rows of {len(rows)}"
    verts = _bounded_vertices(rows, be, budget, stage)
    if verts is not None:
        tight = chunked_tight_counts(rows, verts, TERMINAL_REDUNDANCY_TOL * 10, budget, stage)
        facet = np.array([np.linalg.matrix_rank(np.column_stack([verts[t], np.ones(len(t))]), tol=1e-9) >= dim
                          if len(t) >= dim else False for t in tight], dtype=bool)
        return _dedupe(rows[facet])
    keep = np.ones(len(rows), dtype=bool)
    for i in range(len(rows)):
        budget.tick(stage)
        keep[i] = False
        H, h = _with_alpha_nonneg(rows[keep])
        value = be.support(H, h, rows[i:i + 1])[0]
        if not (value <= 1.0 + TERMINAL_REDUNDANCY_TOL):
            keep[i] = True
    return rows[keep]
