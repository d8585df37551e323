"""The preimage template: X0 = {x | D x <= h} with facet directions D taken from the nominal closed loop
and h the least robustly invariant template for every vertex of Θ (``design.x0_template = "preimage"``).

The fixed directions of the ``"mrpi"`` template (±e_i, ±(e_i ± e_j)/√2) do not fit a closed loop that is
far from normal, such as a chain of integrators: the template iteration diverges, because no invariant
polytope has those facet normals. The maximal λ-contractive set of the ``"contractive"`` template has
the right normals but, under the four vertex maps of Θ, thousands of them from n = 4 on (its rows are
preimages under every product of vertex maps). This template takes its normals from the nominal closed
loop only, where they stay few, and lets the template iteration find the robust set:

1. Directions (Blanchini & Miani, "Set-theoretic methods in control", Ch. 5; Gilbert & Tan 1991): the
   maximal λ₀-contractive set of the nominal closed loop x⁺ = A_cl(θ̂0) x (no disturbance) inside
   C = {x | (F + GK) x <= 1}, by the backward iteration Ω_{j+1} = Ω_j ∩ {x | a A_cl(θ̂0) x <= λ₀} over the
   rows a added at step j, redundant rows removed, until no new row is violated (finite determination,
   λ₀ above the nominal spectral radius). A single map adds at most one row per row of C and iteration.
   D = its unit rows and their negatives (so that every template {D x <= h} is bounded).
2. Template iteration (as for ``"mrpi"``, offline/templates.py): the least fixed point of
   h ↦ max_k σ_{X(h)}(A_cl(θ^k)ᵀ d_i) + σ_W(d_i), X(h) = {D x <= h}, started from σ_W(D); the supports
   are maxima over the vertices of X(h) (exact: X(h) is bounded), each enumeration sized against the
   memory budget. Stopped when T(h) − h <= :data:`~amcp_drake.offline.templates.MRPI_RESIDUAL_FRACTION`
   σ_W per row, then inflated by :data:`~amcp_drake.offline.templates.X0_INFLATION`, which makes X0
   exactly robustly invariant (h̄^k + w̄ <= 1) and λ-contractive (λ̄ < 1).
3. Fit: a design with this X0 needs its tube's steady state inside the constraints, α_∞ max f̄ < 1
   (Appendix A.1: the terminal set holds (0, α_∞) only then; :func:`~amcp_drake.offline.terminal.steady_alpha`).
   X0 is the least robustly invariant set with these normals, so when α_∞ max f̄ >= 1 no design with
   them exists for this K: :class:`~amcp_drake.offline.templates.TemplateError` "does not fit Z", with
   the ratio (``fit_ratio``). The iteration stops early when an iterate X(h_j) already reaches
   max (F + GK) x >= :data:`PREIMAGE_STOP_REACH` over its vertices: the iterates increase (h_0 = σ_W <= T(h_0), T monotone), and the
   steady tube α_∞ X0 is a robustly invariant template with the same normals, hence contains the least
   one and every iterate, so α_∞ max f̄ >= that maximum (then reported as a lower bound).

Nothing here is trusted: the design's independent checks (offline/checks.py) re-verify contractivity,
robust invariance and Assumption 11 at the vertices.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.offline.budget import DesignBudget, chunked_row_maxima, unbounded
from amcp_drake.offline.templates import (
    CONTRACTIVE_REDUNDANCY_TOL,
    MRPI_RESIDUAL_FRACTION,
    X0_INFLATION,
    TemplateError,
    _prune,
    _row_maxima,
    _unit_rows,
)
from amcp_drake.offline.terminal import steady_alpha

#: λ₀ of the nominal directions, tried in this order by the automatic design (offline/auto.py): a larger
#: λ₀ gives fewer directions (a smaller X0, a cheaper tube QP), a smaller one more and a tighter tube
#: (and at or below the nominal spectral radius none: the iteration does not terminate). On the
#: 4-state integrator chain (K from 100 R) 0.97 gave 68 facets and 380 vertices, 0.95 90 and 512.
PREIMAGE_LAMBDAS = (0.97, 0.95)
#: The template iteration stops as soon as an iterate reaches this multiple of the constraints (step 3:
#: then α_∞ max f̄ is at least that much, and the candidate cannot fit); below it the iteration runs to
#: its fixed point, so that a tube reaching 1 to 2 times Z is reported with its exact ratio.
PREIMAGE_STOP_REACH = 2.0
#: Iteration cap of the nominal backward iteration (step 1).
PREIMAGE_DIRECTION_ITER = 200


def preimage_max_rows(n: int) -> int:
    """Most directions (rows of D, both signs) at dimension n: 40 per state (90 were needed at n = 4)."""
    return 40 * int(n)


def nominal_directions(FGK: np.ndarray, A_nom: np.ndarray, lam0: float, be, max_rows: int,
                       budget: DesignBudget | None = None) -> np.ndarray:
    """Step 1 of the module docstring: unit rows ±a of the maximal λ₀-contractive set of x⁺ = A_nom x in
    {FGK x <= 1}; TemplateError when it does not terminate or exceeds ``max_rows`` directions."""
    budget = budget or unbounded()
    name = f"preimage (lambda = {lam0:g})"
    rows = _unit_rows(FGK)
    if len(rows) == 0:
        raise TemplateError(name, "no constraint", "F + GK has no non-zero row", "x0_template = 'mrpi'")
    radius = float(np.max(np.abs(np.linalg.eigvals(A_nom))))
    if not radius < lam0:
        raise TemplateError(name, "below the spectral radius", f"lambda = {lam0:g} <= {radius:.4g}, the spectral "
                            "radius of the nominal closed loop: the backward iteration does not terminate",
                            "a larger lambda (design.x0_lambda)")
    rows = _prune(rows, be, budget)
    new = rows
    for iteration in range(1, PREIMAGE_DIRECTION_ITER + 1):
        stage = f"X0 template {name}: directions, iteration {iteration} ({len(rows)} rows)"
        budget.tick(stage)
        cand = _unit_rows(new @ A_nom / lam0)
        values = _row_maxima(rows, cand, be, budget, stage)
        violated = cand[~(values <= 1.0 + CONTRACTIVE_REDUNDANCY_TOL)]
        if len(violated) == 0:
            break
        merged = _prune(np.vstack([rows, violated]), be, budget)
        old = {tuple(np.round(r, 10)) for r in rows}
        new = np.array([r for r in merged if tuple(np.round(r, 10)) not in old]).reshape(-1, rows.shape[1])
        rows = merged
        if len(new) == 0:
            break
        if len(rows) > max_rows:
            raise TemplateError(name, "too complex", f"{len(rows)} directions after {iteration} iterations "
                                f"(cap {max_rows})", "a larger lambda (design.x0_lambda)")
    else:
        raise TemplateError(name, "not converged", f"new nominal directions still appear after "
                            f"{PREIMAGE_DIRECTION_ITER} iterations",
                            "a larger lambda (design.x0_lambda)")
    unit = rows / np.linalg.norm(rows, axis=1)[:, None]
    D = _unit_rows(np.vstack([unit, -unit]))
    if len(D) > max_rows:
        raise TemplateError(name, "too complex", f"{len(D)} directions with their negatives (cap {max_rows})",
                            "a larger lambda (design.x0_lambda)")
    return D


def preimage_template(FGK: np.ndarray, H_w: np.ndarray, A_cl: np.ndarray, A_nom: np.ndarray, be, lam0: float,
                      max_iter: int, max_rows: int, budget: DesignBudget | None = None) -> np.ndarray:
    """H_x of X0 (module docstring, steps 1-3); TemplateError "not converged", "too complex"
    or "does not fit Z" (with ``fit_ratio`` = α_∞ max f̄ of the least invariant template)."""
    budget = budget or unbounded()
    name = f"preimage (lambda = {lam0:g})"
    D = nominal_directions(FGK, A_nom, lam0, be, max_rows, budget)
    n = D.shape[1]
    W_v = polytope.vertices(H_w, np.ones(len(H_w)))
    w_sup = np.max(D @ W_v.T, axis=1)
    if not np.all(w_sup > 0):
        raise TemplateError(name, "flat disturbance", "W has no extent along some template direction",
                            "x0_template = 'mrpi'")
    h = w_sup.copy()
    for iteration in range(1, max_iter + 1):
        stage = f"X0 template {name}, iteration {iteration} ({len(D)} facets)"
        budget.tick(stage)
        budget.require_vertices(stage, len(D), n)
        verts = polytope.vertices(D, h)
        budget.note_vertices(len(D), n, len(verts))
        reach = float(np.max(chunked_row_maxima(FGK, verts, budget, stage)))
        if not reach < PREIMAGE_STOP_REACH:  # step 3: later iterates and the steady tube α_∞ X0 contain this one
            _no_fit(name, len(D), reach, f"at least {reach:.3g} (iteration {iteration} of the template iteration "
                    "already reaches it; every later iterate and the steady tube alpha_inf X0 contain it)", bound=True)
        images = np.max([chunked_row_maxima(D @ Ak, verts, budget, stage) for Ak in A_cl], axis=0)
        h_next = images + w_sup
        residual = float(np.max((h_next - h) / w_sup))
        h = h_next
        if residual <= MRPI_RESIDUAL_FRACTION:
            H_x = D / (X0_INFLATION * h)[:, None]
            _require_fit(H_x, FGK, W_v, A_cl, name, budget)
            return H_x
    raise TemplateError(name, "not converged", f"residual still above {MRPI_RESIDUAL_FRACTION:g} w_bar after "
                        f"{max_iter} iterations", "design.mrpi_max_iter, or another design.x0_lambda")


def fit_ratio(H_x: np.ndarray, FGK: np.ndarray, W_v: np.ndarray, A_cl: np.ndarray) -> float:
    """α_∞ · max f̄ of X0 = {H_x x <= 1} (step 3): below 1 iff the tube's steady state lies in Z."""
    verts = polytope.vertices(H_x, np.ones(len(H_x)))
    h_bar = np.array([np.max(H_x @ Ak @ verts.T, axis=1) for Ak in A_cl])
    w_bar = np.max(H_x @ W_v.T, axis=1)
    f_max = float(np.max(FGK @ verts.T))
    return steady_alpha(w_bar, h_bar) * f_max


def _require_fit(H_x, FGK, W_v, A_cl, name: str, budget: DesignBudget) -> None:
    budget.require_vertices(f"X0 template {name}: fit", len(H_x), H_x.shape[1])
    ratio = fit_ratio(H_x, FGK, W_v, A_cl)
    if not ratio < 1.0:
        _no_fit(name, len(H_x), ratio, f"{ratio:.3g}")


def _no_fit(name: str, rows: int, ratio: float, value: str, bound: bool = False) -> None:
    """Raise the TemplateError "does not fit Z" with ``fit_ratio`` = ``ratio``, α_∞ max f̄ or (``bound``,
    recorded as ``fit_bound``) a lower bound of it."""
    err = TemplateError(name, "does not fit Z", f"the least robustly invariant X0 with these {rows} directions has "
                        f"alpha_inf * max f_bar = {value} >= 1: its steady tube leaves the constraints under "
                        "u = Kx, so no terminal set exists (Appendix A.1)",
                        "a lower-gain K (design.gain_R_scale), another design.x0_lambda, or relax Z / shrink W")
    err.fit_ratio, err.fit_bound = ratio, bound
    raise err


__all__ = ["PREIMAGE_DIRECTION_ITER", "PREIMAGE_LAMBDAS", "PREIMAGE_STOP_REACH", "fit_ratio", "nominal_directions", "preimage_max_rows",
           "preimage_template"]
