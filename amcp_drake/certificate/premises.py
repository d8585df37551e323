"""The premises of the paper's results on one run, kept apart from the results themselves.

Theorem 14 says what happens *if* its premises hold; a run whose premises do not hold is no evidence
against it. Three premises are checked here, each reported as ``met``, ``not_met`` or ``unknown``:

* ``initial_feasibility``: 𝔻(x_0, Θ_0) ≠ ∅, the first QP (20) is feasible (Theorem 14 assumes it).
  When the run applied a checked answer at step 0, that answer is a point of 𝔻(x_0, Θ_0) (the tube
  claims check it) and the premise is met. Otherwise it is decided by the independent LP of
  :class:`~amcp_drake.certificate.feasible_region.TubeLP` at x_0 for the recorded Θ_0: its slack t
  (rows of unit norm) is the margin; the premise is not met when t < −:data:`LP_TOL`, and a start
  within LP_TOL of the region (or inside it) leaves the unsolved step to the claim of Theorem 14 (i).
* ``assumption_8``: A_cl(θ) = A(θ) + B(θ) K Schur stable at every vertex of Θ (the design check of
  the same name, :func:`amcp_drake.offline.checks.verify_design`).
* ``mu_condition_11``: the gain μ of (11) (the design check of the same name).

A design computed by ``amcp design`` meets Assumption 8 and (11) by construction (the design refuses
otherwise); a design given or edited by the user may not. When a premise is not met the certificate's
verdict is ``premise_not_met`` and the claims that did not pass on the run are moved to its
``not_claimed`` list with the premise as the reason (:func:`apply`): they are not claims of the paper for
this run.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amcp_drake.model.check_result import FAIL, PASS, CheckResult

#: The LP slack t below which x_0 is outside the feasible region of (20) (rows of unit norm): the
#: agreement tolerance of ``amcp coverage`` between the QP and this LP (Clarabel's and HiGHS's
#: feasibility tolerances are ~1e-8; QP_TOL 1e-6 leaves room for the QP's scaling).
LP_TOL = 1e-6
MET, NOT_MET, UNKNOWN = "met", "not_met", "unknown"
#: Design claims that are premises of the paper's results (claim id -> premise id).
DESIGN_PREMISES = {"design.assumption_8": "assumption_8", "design.mu_condition_11": "mu_condition_11"}
COVERAGE_HINT = ("choose x_0 inside the feasible region of (20): measure it with `amcp coverage PROBLEM` "
                 "(docs/how-to/own-system.md, section 4)")
DESIGN_HINT = ("let `amcp design` compute K and P (its design meets Assumption 8 and (11) by construction), "
               "or give a gain that stabilises every vertex of Θ (docs/how-to/own-system.md, section 3)")


def premise(pid: str, name: str, statement: str, status: str, margin: float | None, tolerance: float,
            detail: str, hint: str = "") -> dict[str, Any]:
    """One entry of the certificate's ``premises`` section."""
    margin = None if margin is None or not np.isfinite(margin) else float(margin)
    return {"id": pid, "name": name, "premise": statement, "status": status, "margin": margin,
            "tolerance": tolerance, "detail": detail, "hint": hint if status == NOT_MET else ""}


def initial_feasibility(view) -> dict[str, Any]:
    """The premise 𝔻(x_0, Θ_0) ≠ ∅ (module docstring)."""
    name, statement = "initial feasibility", "Theorem 14 premise: 𝔻(x_0, Θ_0) ≠ ∅ (the first QP (20) is feasible)"
    if not view.records:
        return premise("initial_feasibility", name, statement, UNKNOWN, None, LP_TOL, "no step recorded")
    if 0 in set(view.solved):
        return premise("initial_feasibility", name, statement, MET, None, LP_TOL,
                       "the run applied a checked answer of (20) at step 0")
    from amcp_drake.certificate.feasible_region import TubeLP

    r0 = view.records[0]
    try:
        lp = TubeLP.build(view.problem, view.design, np.asarray(r0.H_theta, float), np.asarray(r0.h_theta, float))
        t = lp.margin(np.asarray(view.traj.x[0], float))
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        return premise("initial_feasibility", name, statement, UNKNOWN, None, LP_TOL, f"the LP could not run: {exc}")
    if not np.isfinite(t):
        return premise("initial_feasibility", name, statement, UNKNOWN, None, LP_TOL, "the LP (HiGHS) did not solve")
    x0 = np.array2string(np.asarray(view.traj.x[0], float), precision=6, separator=", ")
    if t < -LP_TOL:
        return premise("initial_feasibility", name, statement, NOT_MET, t, LP_TOL,
                       f"x_0 = {x0} is outside the feasible region of (20) for Θ_0: the independent LP's largest "
                       f"common slack of the tube constraints is {t:.3e} < 0 (rows of unit norm)", COVERAGE_HINT)
    return premise("initial_feasibility", name, statement, MET, t, LP_TOL,
                   f"x_0 = {x0}: the independent LP's slack is {t:.3e} (feasible within {LP_TOL:.0e}); the unsolved "
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
    too (X0, X_f and (16) are built on the same K), is moved. Claims that pass stay: they were checked."""
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
    moved = [c for c in kept if c.status != PASS and (design_broken or c.data.get("group") != "design")]
    out = [c for c in kept if c not in moved]
    return out, premises, [{"id": c.data["id"], "name": c.name, "reason": reason} for c in moved]
