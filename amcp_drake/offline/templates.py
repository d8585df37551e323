"""Cross-section templates X0 = {x | H_x x <= 1} of the homothetic tube (14) (docs/explanation/paper.md §4, "Choice of X0").

The paper needs X0 to be λ-contractive for every A_cl(θ^k) (λ̄ < 1, Appendix A.1) and, for the
design checks of this project, robustly invariant: A_cl(θ)X0 ⊕ W ⊆ X0 (h̄^k + w̄ <= 1). Three
templates, all n-dimensional:

* ``"mrpi"``: a fixed set of facet normals (:func:`template_directions`) and the least fixed point
  of the template map h ↦ max_k σ_{X(h)}(A_cl(θ^k)ᵀ d_i) + σ_W(d_i), started from σ_W: an outer
  approximation of the minimal robust positively invariant set (the paper's suggestion). Divergence
  of the iteration is detected (:data:`MRPI_DIVERGENCE_FACTOR`) and reported as such.
* ``"contractive"``: the maximal robust λ-contractive set inside the state/input constraints
  under u = Kx: the largest Ω ⊆ C = {(F+GK)x <= 1} with A_cl(θ^k)Ω ⊕ W ⊆ λΩ for every vertex θ^k
  of Θ, by the backward iteration Ω_0 = C, Ω_{j+1} = Ω_j ∩ ⋂_k {a A_cl(θ^k) x <= λ − σ_W(a)}
  (Blanchini & Miani, "Set-theoretic methods in control", Ch. 5), rows normalised to right-hand
  side 1. Stopping rule: Ω_{j+1} = Ω_j (no new non-redundant row); then h̄^k + w̄ <= λ is verified
  at the vertices. Failure after :data:`CONTRACTIVE_MAX_ITER` iterations or
  :data:`CONTRACTIVE_MAX_ROWS` rows, or when the set is empty or collapses.
* ``"given"``: a user-given H_x (rows with right-hand side 1), checked for boundedness,
  contractivity and robust invariance like the others.

Every function returns H_x or raises :class:`TemplateError` with a reason a person can act on.
Linear programs go through the design backend (``be.support``); vertex enumeration uses Qhull
(``polytope.vertices``), as the rest of the design does.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.offline.budget import DesignBudget, chunked_tight_counts, unbounded
from amcp_drake.offline.support import bounded_vertices, row_maxima

#: The minimal-RPI iteration stops when T(h) - h is below this fraction of w̄ per row; inflating
#: h by X0_INFLATION then makes the template exactly invariant: T(ch) = c T(h) - (c-1) w̄ <= c h.
MRPI_RESIDUAL_FRACTION = 1e-3
X0_INFLATION = 1.01
#: The minimal-RPI iteration is declared divergent when h exceeds this multiple of max σ_W where Z
#: does not bound the state: a converging iteration stays of the order of w̄/(1 - λ); values near
#: 1e8 (seen on the SLS-MPC family at ε_A = 0.25 before the iteration stopped at this factor) are far
#: past any useful tube.
MRPI_DIVERGENCE_FACTOR = 1e6
#: ... or when h_i exceeds this multiple of the state extent of Z in direction d_i (Z bounded in x):
#: a cross-section 10 times larger than the constraint set can never give a non-empty terminal set.
MRPI_Z_FACTOR = 10.0
#: Iteration and complexity caps of the λ-contractive backward iteration (2-D sets of the
#: literature need 5-30 iterations and 10-40 rows; more rows make the tube QP large: N·v·u·q Λ's).
#: The row cap is CONTRACTIVE_MAX_ROWS up to n = 3 and grows with n above
#: (:func:`contractive_max_rows`); the vertex enumerations it implies are sized against the memory
#: limit (offline/budget.py) whatever the cap.
CONTRACTIVE_MAX_ITER = 200
CONTRACTIVE_MAX_ROWS = 200
#: A candidate row is redundant when the current set keeps it below 1 + this (Qhull vertex
#: accuracy ~1e-12, LP accuracy ~1e-8: below it, rounding would keep duplicates forever).
CONTRACTIVE_REDUNDANCY_TOL = 1e-9
#: Round-off allowed when λ-contractivity of the finished set is verified at its vertices (the
#: iteration stops at CONTRACTIVE_REDUNDANCY_TOL; Qhull adds ~1e-12).
CONTRACTIVE_CHECK_TOL = 1e-8
#: The contractive set has collapsed (λ is below what K can achieve) when its Chebyshev radius
#: falls below this fraction of the radius of the constraint set.
COLLAPSE_FRACTION = 1e-6

TEMPLATE_KINDS = ("auto", "mrpi", "contractive", "given", "parallelotope", "preimage")


class TemplateError(DesignError):
    """A template could not be built; ``reason`` is a short label (``"diverged"``, ``"not converged"``,
    ``"collapsed"``, ``"not contractive"``, ...) and ``hint`` the next thing to try."""

    # The shape of model.errors.ProblemError.__init__ (fields kept, one message composed), with other
    # fields: a template failure names the template and why, not a file field, expected and received.
    def __init__(self, template: str, reason: str, detail: str, hint: str = "") -> None:
        self.template = template
        self.reason = reason
        self.detail = detail
        self.hint = hint
        message = f"X0 template {template}: {reason}: {detail}"
        if hint:
            message += f". Next: {hint}"
        super().__init__(message)


def template_directions(n: int, count: int) -> np.ndarray:
    """Facet normals of X0: 2-D equally spaced angles; n-D ±e_i then ±(e_i ± e_j)/√2 (unit rows)."""
    if count < 2 * n:
        raise ProblemError("design.x0_facets", f"at least 2n = {2 * n} directions", str(count))
    if n == 1:
        return np.array([[1.0], [-1.0]])[:count]
    if n == 2:
        angles = 2 * np.pi * np.arange(count) / count
        return np.column_stack([np.cos(angles), np.sin(angles)])
    rows = [s * e for e in np.eye(n) for s in (1.0, -1.0)]
    for i in range(n):
        for j in range(i + 1, n):
            for si in (1.0, -1.0):
                for sj in (1.0, -1.0):
                    d = np.zeros(n)
                    d[i], d[j] = si, sj
                    rows.append(d / np.sqrt(2))
    if count > len(rows):
        raise ProblemError("design.x0_facets", f"at most {len(rows)} directions for n = {n}", str(count))
    return np.array(rows[:count])


def contractive_max_rows(n: int) -> int:
    """Row cap of the contractive template at dimension n: :data:`CONTRACTIVE_MAX_ROWS` up to n = 3,
    then 50 more per state (a λ-contractive set in n dimensions needs rows in proportion to its
    2n axis directions times the few images of each that the iteration adds)."""
    return CONTRACTIVE_MAX_ROWS + 50 * max(0, int(n) - 3)


def max_template_facets(n: int) -> int:
    """Largest ``count`` :func:`template_directions` accepts for dimension n (None-like 10**9 in 2-D)."""
    if n == 1:
        return 2
    if n == 2:
        return 10 ** 9
    return 2 * n + 4 * n * (n - 1) // 2


# -- (a) minimal-RPI outer approximation -----------------------------------------------------------

def mrpi_template(H_w: np.ndarray, A_cl: np.ndarray, be, facets: int, max_iter: int,
                  Z_rows: np.ndarray | None = None, budget: DesignBudget | None = None) -> np.ndarray:
    """Template outer approximation of the minimal RPI set of x⁺ = A_cl(θ)x + w, θ ∈ Θ, w ∈ W.

    Least fixed point of h ↦ max_k σ_{X(h)}(A_cl(θ^k)ᵀ d_i) + σ_W(d_i), X(h) = {D x <= h},
    started from h = σ_W(D) (monotone increasing). Stopped when T(h) - h <= 1e-3 w̄ per row,
    then inflated by 1.01 (see :data:`X0_INFLATION`).

    Divergence: the iterates increase monotonically; they are called divergent when some h_i
    exceeds :data:`MRPI_Z_FACTOR` times the support of the state projection of Z in direction d_i
    (``Z_rows`` = [F G]; such a tube cannot fit in Z, so no design can follow), or, when Z does not
    bound the state in every template direction, 1e6 max σ_W (:data:`MRPI_DIVERGENCE_FACTOR`).
    """
    budget = budget or unbounded()
    n = A_cl.shape[1]
    name = f"mrpi ({facets} facets)"
    D = template_directions(n, facets)
    w_sup = be.support(H_w, np.ones(len(H_w)), D)
    if not np.all(np.isfinite(w_sup)):
        raise TemplateError(name, "LP failed", f"sigma_W = {w_sup.tolist()}")
    limit = np.full(len(D), MRPI_DIVERGENCE_FACTOR * float(np.max(w_sup)))
    if Z_rows is not None:
        z_sup = be.support(Z_rows, np.ones(len(Z_rows)), np.hstack([D, np.zeros((len(D), Z_rows.shape[1] - n))]))
        if np.all(np.isfinite(z_sup)):
            limit = MRPI_Z_FACTOR * z_sup
    h = w_sup.copy()
    for iteration in range(1, max_iter + 1):
        budget.tick(f"X0 template {name}, iteration {iteration}")
        images = np.array([be.support(D, h, D @ Ak) for Ak in A_cl])
        if not np.all(np.isfinite(images)) or np.any(np.max(images, axis=0) > limit):
            raise TemplateError(name, "diverged",
                                f"the template iteration grew past {MRPI_Z_FACTOR:g} x the state constraints "
                                f"(or 1e6 sigma_W where Z is unbounded) at iteration {iteration}; these "
                                f"{facets} facet directions admit no invariant template for A_cl(Theta)",
                                "more facets (design.x0_facets), or x0_template = 'contractive'")
        h_next = np.max(images, axis=0) + w_sup
        residual = float(np.max((h_next - h) / w_sup))
        h = h_next
        if residual <= MRPI_RESIDUAL_FRACTION:
            return D / (X0_INFLATION * h)[:, None]
    raise TemplateError(name, "not converged",
                        f"residual still above {MRPI_RESIDUAL_FRACTION:g} w_bar after {max_iter} iterations",
                        "more facets (design.x0_facets), design.mrpi_max_iter, or x0_template = 'contractive'")


# -- (b) maximal λ-contractive set under u = Kx ----------------------------------------------------

def contractive_template(FGK: np.ndarray, H_w: np.ndarray, A_cl: np.ndarray, be, lam: float,
                         max_iter: int = CONTRACTIVE_MAX_ITER, max_rows: int = CONTRACTIVE_MAX_ROWS,
                         budget: DesignBudget | None = None) -> np.ndarray:
    """The maximal robust λ-contractive set of x⁺ = A_cl(θ)x + w inside C = {x | (F+GK) x <= 1}:
    the largest Ω ⊆ C with A_cl(θ^k) Ω ⊕ W ⊆ λ Ω for every vertex θ^k of Θ; returned as H_x
    with right-hand side 1.

    Backward iteration Ω_0 = C, Ω_{j+1} = Ω_j ∩ {x | a A_cl(θ^k) x <= λ − σ_W(a) for every row a
    added at step j and every k} (the pre-image distributes over intersections, so only new rows
    are propagated; each row is divided by λ − σ_W(a) to keep right-hand side 1; λ − σ_W(a) <= 0
    means Ω is empty). Stopping rule: no candidate row is violated by more than
    :data:`CONTRACTIVE_REDUNDANCY_TOL` on Ω_j, i.e. Ω_{j+1} = Ω_j (Gilbert & Tan finite
    determination). Ω then satisfies h̄^k + w̄ <= λ: it is λ-contractive (λ̄ <= λ) and robustly
    invariant at once, and Ω ⊆ C gives f̄ <= 1 and α_∞ f̄ < 1 (a non-empty terminal set,
    Appendix A.1). Both properties are verified at the vertices before returning.

    Complexity: at most ``max_rows`` rows (:func:`contractive_max_rows`), checked after each
    iteration, and every vertex enumeration sized against ``budget`` before Qhull runs.
    """
    budget = budget or unbounded()
    name = f"contractive (lambda = {lam:g})"
    if not 0.0 < lam < 1.0:
        raise ProblemError("design.x0_lambda", "a number in (0, 1)", repr(lam))
    rows = _unit_rows(FGK)
    if len(rows) == 0:
        raise TemplateError(name, "no constraint", "F + GK has no non-zero row", "x0_template = 'mrpi'")
    ones_w = np.ones(len(H_w))
    rows = _prune(rows, be, budget)
    base_radius = None
    new = rows
    for iteration in range(1, max_iter + 1):
        stage = f"X0 template {name}, iteration {iteration} ({len(rows)} rows)"
        budget.tick(stage)
        sigma = be.support(H_w, ones_w, new)
        if not np.all(np.isfinite(sigma)):
            raise TemplateError(name, "LP failed", f"sigma_W failed at iteration {iteration}")
        room = lam - sigma
        if np.any(room <= 0.0):
            raise TemplateError(name, "empty", f"the disturbance alone leaves no room in a constraint row "
                                f"(sigma_W = {np.max(sigma):.4g} >= lambda, iteration {iteration})",
                                "a larger lambda (design.x0_lambda) or a lower-gain K (design.gain_R_scale)")
        cand = _unit_rows(np.vstack([(new @ Ak) / room[:, None] for Ak in A_cl]))
        values = _row_maxima(rows, cand, be, budget, stage)
        if np.any(np.isnan(values)):
            raise TemplateError(name, "LP failed", f"a support LP failed at iteration {iteration}")
        violated = cand[~(values <= 1.0 + CONTRACTIVE_REDUNDANCY_TOL)]
        if len(violated) == 0:
            return _verified(rows, H_w, A_cl, name, lam, budget)
        if len(rows) + len(violated) > 10 * max_rows:  # far past the cap before pruning: stop here
            raise TemplateError(name, "too complex", f"{len(rows)} rows and {len(violated)} violated candidate rows "
                                f"at iteration {iteration} (cap {max_rows})",
                                "a larger lambda (design.x0_lambda) or a lower-gain K (design.gain_R_scale)")
        merged = _prune(np.vstack([rows, violated]), be, budget)
        old = {tuple(np.round(r, 10)) for r in rows}
        new = np.array([r for r in merged if tuple(np.round(r, 10)) not in old]).reshape(-1, rows.shape[1])
        rows = merged
        if len(new) == 0:
            return _verified(rows, H_w, A_cl, name, lam, budget)
        if len(rows) > max_rows:
            raise TemplateError(name, "too complex", f"{len(rows)} rows after {iteration} iterations (cap {max_rows})",
                                "a larger lambda (design.x0_lambda) or a lower-gain K (design.gain_R_scale)")
        _, radius = polytope.chebyshev_center(rows, np.ones(len(rows)))
        if radius == float("-inf"):
            raise TemplateError(name, "empty", f"no state is left after {iteration} iterations",
                                "a larger lambda (design.x0_lambda) or a lower-gain K (design.gain_R_scale)")
        if base_radius is None:
            base_radius = radius
        if np.isfinite(radius) and np.isfinite(base_radius) and radius < COLLAPSE_FRACTION * base_radius:
            raise TemplateError(name, "collapsed", f"the set shrank to a point (iteration {iteration})",
                                "a larger lambda (design.x0_lambda) or a lower-gain K (design.gain_R_scale)")
    raise TemplateError(name, "not converged", f"new rows still appear after {max_iter} iterations",
                        "a larger lambda (design.x0_lambda) or a lower-gain K (design.gain_R_scale)")


def _verified(rows: np.ndarray, H_w: np.ndarray, A_cl: np.ndarray, name: str, lam: float,
              budget: DesignBudget | None = None) -> np.ndarray:
    """Check h̄^k + w̄ <= λ at the vertices of {rows x <= 1} (bounded, with interior) and return rows."""
    (budget or unbounded()).require_vertices(f"X0 template {name}: vertices", len(rows), rows.shape[1])
    try:
        verts = polytope.vertices(rows, np.ones(len(rows)))
    except ValueError as exc:
        raise TemplateError(name, "unbounded", f"the contractive set is unbounded or flat ({exc}): the "
                            "constraints under u = Kx do not bound the state", "x0_template = 'mrpi'") from None
    h_bar = np.array([np.max(rows @ Ak @ verts.T, axis=1) for Ak in A_cl])
    w_bar = np.max(rows @ polytope.vertices(H_w, np.ones(len(H_w))).T, axis=1)
    worst = float(np.max(h_bar + w_bar))
    if worst > lam + CONTRACTIVE_CHECK_TOL:
        raise TemplateError(name, "not contractive", f"max h_bar + w_bar = {worst:.6f} > lambda at the vertices",
                            "x0_template = 'mrpi'")
    return rows


def scale_to_robust_invariance(H: np.ndarray, verts: np.ndarray, H_w: np.ndarray, A_cl: np.ndarray,
                               name: str, lam_limit: float = 1.0) -> np.ndarray:
    """Scale {H x <= 1} (vertices ``verts``) by s so that h̄^k + w̄/s <= 1 with a 1 % margin.

    h̄^k_i = max_{x∈X} [H]_i A_cl(θ^k) x does not change with s; w̄_i = max_{w∈W} [H]_i w scales as 1/s.
    Raises TemplateError when λ̄ >= ``lam_limit`` (or >= 1).
    """
    h_bar = np.array([np.max(H @ Ak @ verts.T, axis=1) for Ak in A_cl])  # (v_p, u)
    lam_bar = float(np.max(h_bar))
    limit = min(lam_limit * (1.0 + 1e-9), 1.0)
    if not lam_bar < limit:
        raise TemplateError(name, "not contractive", f"lambda_bar = {lam_bar:.6f} (needs < {limit:g})",
                            "x0_template = 'contractive' with a larger lambda, or 'mrpi'")
    W_v = polytope.vertices(H_w, np.ones(len(H_w)))
    w_bar = np.max(H @ W_v.T, axis=1)
    s = X0_INFLATION * float(np.max(w_bar / (1.0 - np.max(h_bar, axis=0))))
    return H / s


# -- (c) user-given H_x ----------------------------------------------------------------------------

def given_template(H_x: np.ndarray, H_w: np.ndarray, A_cl: np.ndarray, scale: bool = False) -> np.ndarray:
    """A user-given X0 = {H_x x <= 1}: checked bounded with 0 inside; when ``scale`` it is scaled like
    the contractive template, otherwise it is used as given (the design checks then judge it)."""
    H = np.asarray(H_x, float)
    try:
        verts = polytope.vertices(H, np.ones(len(H)))
    except ValueError as exc:
        raise ProblemError("design.x0_H", "rows of a bounded X0 = {x | H x <= 1} with interior", str(exc)) from None
    if scale:
        return scale_to_robust_invariance(H, verts, H_w, A_cl, "given")
    return H


# -- row bookkeeping (as in the terminal-set recursion of design.py) -------------------------------

def _unit_rows(M: np.ndarray) -> np.ndarray:
    """Rows a with a·x <= 1 kept as they are; all-zero rows (vacuous) dropped; duplicates merged."""
    M = np.asarray(M, float)
    M = M[np.linalg.norm(M, axis=1) > 0.0]
    if len(M) == 0:
        return M
    _, idx = np.unique(np.round(M, 10), axis=0, return_index=True)
    return M[np.sort(idx)]


def _bounded_vertices(rows: np.ndarray, be, budget: DesignBudget | None = None,
                      stage: str = "X0 template: vertices") -> np.ndarray | None:
    """Vertices of {rows · x <= 1} when it is bounded, else None."""
    return bounded_vertices(rows, np.ones(len(rows)), be, budget, stage)


def _row_maxima(rows: np.ndarray, directions: np.ndarray, be, budget: DesignBudget | None = None,
                stage: str = "X0 template") -> np.ndarray:
    """max of each direction over {rows · x <= 1}: by vertices when bounded, else by LPs."""
    return row_maxima(rows, np.ones(len(rows)), directions, be, budget, stage)


def _prune(rows: np.ndarray, be, budget: DesignBudget | None = None) -> np.ndarray:
    """Drop rows of {rows · x <= 1} implied by the others: by facet test at the vertices when the set
    is bounded (rows × vertices in chunks), else one support LP per row."""
    budget = budget or unbounded()
    dim = rows.shape[1]
    stage = f"X0 template: redundant rows of {len(rows)}"
    verts = _bounded_vertices(rows, be, budget, stage)
    if verts is not None:
        tight = chunked_tight_counts(rows, verts, CONTRACTIVE_REDUNDANCY_TOL * 1e3, budget, stage)
        facet = np.array([len(t) >= dim and np.linalg.matrix_rank(verts[t] - verts[t][0], tol=1e-9) >= dim - 1
                          for t in tight], dtype=bool)
        return _unit_rows(rows[facet])
    keep = np.ones(len(rows), dtype=bool)
    for i in range(len(rows)):
        budget.tick(stage)
        keep[i] = False
        value = be.support(rows[keep], np.ones(int(keep.sum())), rows[i:i + 1])[0]
        if not (value <= 1.0 + CONTRACTIVE_REDUNDANCY_TOL):
            keep[i] = True
    return rows[keep]
