"""The premises of the paper's results on one run, kept apart from the results themselves.

Theorem 14 says what happens *if* its premises hold; a run whose premises do not hold is no evidence
against it. Three premises are checked here, each reported as ``met``, ``not_met`` or ``unknown``:

* ``initial_feasibility``: 𝔻(x_0, Θ_0) ≠ ∅, the first QP (20) is feasible (Theorem 14 assumes it).
  First x_0 is evaluated against the rows of (4) that constrain the state alone (G_i = 0): 𝔻(x_0, Θ_0) ≠ ∅
  implies (x_0, K x_0 + v_0) ∈ Z, so an x_0 outside Z by more than the round-off of that evaluation
  (:func:`state_rows_at_x0`) does not meet the premise, whether or not a solver answered step 0 within its own
  tolerance. Otherwise, when the run applied a checked answer at step 0, that answer is a point of
  𝔻(x_0, Θ_0) (the tube claims check it) and the premise is met. Otherwise it is decided by the independent
  LP of :class:`~amcp_drake.certificate.feasible_region.TubeLP` at x_0 for the recorded Θ_0, solved with
  HiGHS' feasibility tolerances at :data:`LP_OPTIONS`: its slack t (rows of unit norm) is the margin; the
  premise is not met when t < −:data:`PREMISE_LP_TOL`, and a start within PREMISE_LP_TOL of the region (or inside it)
  leaves the unsolved step to the claim of Theorem 14 (i).
* ``assumption_8``: A_cl(θ) = A(θ) + B(θ) K Schur stable at every vertex of Θ (the design check of
  the same name, :func:`amcp_drake.offline.checks.verify_design`).
* ``mu_condition_11``: the gain μ of (11) (the design check of the same name).

A design computed by ``amcp design`` meets Assumption 8 and (11) by construction (the design refuses
otherwise); a design given or edited by the user may not. When a premise is not met the certificate's
verdict is ``premise_not_met`` and the claims that did not pass on the run are moved to its
``not_claimed`` list with the premise as the reason (:func:`apply`): they are not claims of the paper for
this run. The claims about the recorded data themselves (:data:`DATA_CLAIMS`: the states follow (1),
w_k ∈ W, θ* ∈ Θ, u_k = K x_k + v_0|k) are never moved when they fail: no premise can excuse a file whose
numbers contradict each other (one with nothing to check, no step applied, is moved like the others).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amcp_drake.model.check_result import FAIL, PASS, CheckResult
from amcp_drake.model.claim_table import CLAIMS
from amcp_drake.model.tolerances import PREMISE_LP_TOL

#: HiGHS options of the premise's LP: primal and dual feasibility 1e-10 (the LP has unit rows, so its
#: slack t is accurate to about that).
LP_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
# PREMISE_LP_TOL (model.tolerances): the LP slack t below which x_0 is outside the feasible region of (20)
# (rows of unit norm), ten times the LP's own feasibility tolerance (:data:`LP_OPTIONS`).
#: Claims about the recorded data alone (claim ids, the rows marked ``data`` in the table of claims): checked
#: and kept whatever the premises say.
DATA_CLAIMS = frozenset(c.id for c in CLAIMS if c.data)
MET, NOT_MET, UNKNOWN = "met", "not_met", "unknown"
#: Design claims that are premises of the paper's results (claim id -> premise id; the rows' ``premise``).
DESIGN_PREMISES = {c.id: c.premise for c in CLAIMS if c.premise}
COVERAGE_HINT = ("choose x_0 inside the feasible region of (20): measure it with `amcp coverage PROBLEM` "
                 "(from n = 3 on, slices through x_0: `--plane I,J --fix NAME=VALUE,...`; docs/how-to/own-system.md, "
                 "section 5)")
DESIGN_HINT = ("let `amcp design` compute K and P (its design meets Assumption 8 and (11) by construction), "
               "or give a gain that stabilises every vertex of Θ (docs/how-to/own-system.md, section 3)")


def premise(pid: str, name: str, statement: str, status: str, margin: float | None, tolerance: float,
            detail: str, hint: str = "") -> dict[str, Any]:
    """One entry of the certificate's ``premises`` section."""
    margin = None if margin is None or not np.isfinite(margin) else float(margin)
    return {"id": pid, "name": name, "premise": statement, "status": status, "margin": margin,
            "tolerance": tolerance, "detail": detail, "hint": hint if status == NOT_MET else ""}


def state_rows_at_x0(F: np.ndarray, G: np.ndarray, x0: np.ndarray) -> tuple[float, float, int] | None:
    """x_0 against the rows of (4) F x + G u <= 1 that constrain the state alone (G_i = 0): (margin, tolerance,
    row) of the row whose margin is worst relative to its tolerance, or None when no row is state-only.

    margin_i = (1 − F_i x_0)/‖F_i‖ (unit rows); tolerance_i bounds the float64 round-off of evaluating it:
    2 (n + 2) ε (1 + Σ_j |F_ij x_0j|)/‖F_i‖ (the dot product's error is at most n u Σ_j |F_ij x_0j|, u = ε/2,
    plus one rounding each for the subtraction and the division; a factor 4 over that bound)."""
    F, G, x0 = np.asarray(F, float), np.asarray(G, float), np.asarray(x0, float)
    rows = np.flatnonzero(np.all(G == 0.0, axis=1) & np.any(F != 0.0, axis=1))
    if rows.size == 0:
        return None
    Fs = F[rows]
    norms = np.linalg.norm(Fs, axis=1)
    margins = (1.0 - Fs @ x0) / norms
    tols = 2.0 * (len(x0) + 2) * np.finfo(float).eps * (1.0 + np.abs(Fs) @ np.abs(x0)) / norms
    worst = int(np.argmin(margins + tols))
    return float(margins[worst]), float(tols[worst]), int(rows[worst])


def initial_feasibility(view) -> dict[str, Any]:
    """The premise 𝔻(x_0, Θ_0) ≠ ∅ (module docstring)."""
    name, statement = "initial feasibility", "Theorem 14 premise: 𝔻(x_0, Θ_0) ≠ ∅ (the first QP (20) is feasible)"
    if not view.records:
        return premise("initial_feasibility", name, statement, UNKNOWN, None, PREMISE_LP_TOL, "no step recorded")
    x0 = np.asarray(view.traj.x[0], float)
    in_z = state_rows_at_x0(view.problem.F, view.problem.G, x0)
    if in_z is not None and in_z[0] < -in_z[1]:
        margin, tol, row = in_z
        shown = np.array2string(x0, precision=17, separator=", ")
        return premise("initial_feasibility", name, statement, NOT_MET, margin, tol,
                       f"x_0 = {shown} is outside Z: row {row} of (4), which constrains the state alone, has margin "
                       f"(1 − F_i x_0)/‖F_i‖ = {margin:.3e} < −{tol:.1e} (the round-off of evaluating it)", COVERAGE_HINT)
    if 0 in set(view.solved):
        return premise("initial_feasibility", name, statement, MET, None, PREMISE_LP_TOL,
                       "the run applied a checked answer of (20) at step 0")
    from amcp_drake.certificate.feasible_region import TubeLP

    r0 = view.records[0]
    try:
        lp = TubeLP.build(view.problem, view.design, np.asarray(r0.H_theta, float), np.asarray(r0.h_theta, float))
        t = lp.margin(x0, LP_OPTIONS)
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        return premise("initial_feasibility", name, statement, UNKNOWN, None, PREMISE_LP_TOL, f"the LP could not run: {exc}")
    if not np.isfinite(t):
        return premise("initial_feasibility", name, statement, UNKNOWN, None, PREMISE_LP_TOL, "the LP (HiGHS) did not solve")
    shown = np.array2string(x0, precision=6, separator=", ")
    if t < -PREMISE_LP_TOL:
        return premise("initial_feasibility", name, statement, NOT_MET, t, PREMISE_LP_TOL,
                       f"x_0 = {shown} is outside the feasible region of (20) for Θ_0: the independent LP's largest "
                       f"common slack of the tube constraints is {t:.3e} < 0 (rows of unit norm)", COVERAGE_HINT)
    return premise("initial_feasibility", name, statement, MET, t, PREMISE_LP_TOL,
                   f"x_0 = {shown}: the independent LP's slack is {t:.3e} (feasible within {PREMISE_LP_TOL:.0e}); the unsolved "
                   "step 0 is judged by Theorem 14 (i)")


def from_design_claim(claim: CheckResult) -> dict[str, Any]:
    """The premise of a design check of :data:`DESIGN_PREMISES` (its margin and tolerance)."""
    status = {PASS: MET, FAIL: NOT_MET}.get(claim.status, UNKNOWN)
    return premise(DESIGN_PREMISES[claim.data["id"]], claim.name, claim.claim, status, claim.margin, claim.tolerance,
                   claim.detail, DESIGN_HINT)


def apply(claims: list[CheckResult], view) -> tuple[list[CheckResult], list[dict[str, Any]], list[dict[str, Any]]]:
    """(the claims, the ``premises`` section, the claims moved to ``not_claimed``).

    A premise design check that fails leaves the claims (it is a premise, not a claim). When x_0 is outside
    the feasible region, every claim of the run that did not pass is moved out of the claims with the premise
    as its reason; when the design breaks Assumption 8 or (11), every claim that did not pass, of the design
    too (X0, X_f and (16) are built on the same K), is moved. Claims that pass stay: they were checked. The
    claims of :data:`DATA_CLAIMS` that fail always stay: a premise never hides a failure of the recorded data."""
    premises = [initial_feasibility(view)]
    kept: list[CheckResult] = []
    for c in claims:
        if c.data.get("id") in DESIGN_PREMISES:
            p = from_design_claim(c)
            premises.append(p)
            if p["status"] == NOT_MET:
                continue
        kept.append(c)
    broken = [p for p in premises if p["status"] == NOT_MET]
    if not broken:
        return kept, premises, []
    reason = "premise not met: " + ", ".join(p["name"] for p in broken)
    design_broken = any(p["id"] != "initial_feasibility" for p in broken)
    moved = [c for c in kept if c.status != PASS and not (c.status == FAIL and c.data.get("id") in DATA_CLAIMS)
             and (design_broken or c.data.get("group") != "design")]
    out = [c for c in kept if c not in moved]
    return out, premises, [{"id": c.data["id"], "name": c.name, "reason": reason} for c in moved]
