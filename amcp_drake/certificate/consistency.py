"""Model consistency of a run: the data never contradicted the declared Θ and W, and what that implies.

``data_consistency``: Θ_{k−1} ∩ Δ_k ≠ ∅ at every step k = 1..T, with Δ_k the non-falsified set (6)
re-derived from the recorded (x_{k−1}, u_{k−1}, x_k) (:func:`amcp_drake.certificate.claims._delta`)
and Θ_{k−1} the recorded set estimate. Under Assumption 1 θ* lies in both (Lemma 3), so an empty
intersection means the disturbance left W, θ* is not in Θ or the model (A_i, B_i) is wrong. The
claim needs only x, u and the records, so it is the certificate's check of the model on a measured
run (θ* and w unknown); on a simulated run it is checked as well and must pass there.

Margin at step k: the *signed* Chebyshev radius of Θ_{k−1} ∩ Δ_k on unit rows,
r_k = max_{θ, r} r subject to a_iᵀθ + r <= b_i for every unit row (a_i, b_i), solved by HiGHS
(scipy ``linprog``) at tight tolerances: r_k > 0 is the radius of the largest ball inside the
intersection, r_k < 0 the amount by which every row must be relaxed for the intersection to be
non-empty (in θ units). The claim reports the first step at which it fails.

When it fails, the claims whose guarantee rests on data that satisfy the model
(:data:`RESTS_ON_CONSISTENCY`) and that did not pass are reported ``not_run`` with the reason and what
their check found (:func:`apply`): a guarantee whose premise the data contradict is not refuted by the run.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from amcp_drake.certificate.claims import RunView, _delta, row_check
from amcp_drake.model import polytope
from amcp_drake.model.check_result import FAIL, NOT_RUN, PASS, CheckResult
from amcp_drake.model.claim_table import CLAIMS
from amcp_drake.model.claim_table import tolerance as claim_tolerance

#: HiGHS tolerances of the signed Chebyshev LP (its radius is exact to ~1e-10 at these settings).
_HIGHS_OPTIONS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}
#: Claims whose guarantee assumes data that satisfy (1) with θ* ∈ Θ and w_k ∈ W (Assumption 1), with the
#: lag between a claim's step k and the transition it depends on: Theorem 14 (i) and (iii) at step k
#: (x_k arrived by the transition into k), and x_(k+1) ∈ X_(1|k) (the transition out of k; if
#: Θ_k ∩ Δ_(k+1) ≠ ∅ then x_(k+1) lies in the one-step set of Θ_k and W, so in X_(1|k)).
#: Read from the rows' ``rests_on_consistency``.
RESTS_ON_CONSISTENCY = {c.id: c.rests_on_consistency for c in CLAIMS if c.rests_on_consistency is not None}


def signed_chebyshev_radius(H: np.ndarray, h: np.ndarray) -> float:
    """max r s.t. a_iᵀθ + r <= b_i for the rows of {Hθ <= h} scaled to unit norm (a zero row keeps
    coefficient 1 on r: 0 <= b_i − r). Positive: the radius of the largest ball inside the set;
    negative: minus the smallest uniform relaxation of the rows that makes the set non-empty.
    +inf when r is unbounded (an unbounded set), nan when HiGHS gives no answer."""
    H, h = polytope.normalize_rows(H, h)
    p = H.shape[1]
    A = np.hstack([H, np.ones((len(H), 1))])
    c = np.zeros(p + 1)
    c[-1] = -1.0
    res = linprog(c, A_ub=A, b_ub=h, bounds=[(None, None)] * (p + 1), method="highs", options=_HIGHS_OPTIONS)
    if res.status == 3:
        return float("inf")
    if res.status != 0:
        return float("nan")
    return float(res.x[-1])


def data_consistency(view: RunView) -> CheckResult:
    """Θ_{k−1} ∩ Δ_k ≠ ∅ for every recorded transition (module docstring); margin = min_k r_k, the
    first failing step in ``data["first_failing_step"]``."""
    per = {}
    for k in range(1, view.T + 1):
        prev = view.records[k - 1]
        H_d, h_d = _delta(view, k - 1)
        H_p, h_p = polytope.normalize_rows(prev.H_theta, prev.h_theta)
        per[k] = signed_chebyshev_radius(np.vstack([H_p, H_d]), np.concatenate([h_p, h_d]))
    # The tolerance (the row's: θ units, unit rows) is the scale of the set-membership claims. Θ_{k−1} is
    # recorded from the controller's answers of (9), which are gated to ~1e-8 and may lie that far inside the
    # exact set; the LP above is solved to 1e-10. A negative radius larger than it is a contradiction.
    tolerance = claim_tolerance("data_consistency")
    failing = [k for k, r in sorted(per.items()) if r == r and r < -tolerance]
    first = failing[0] if failing else None
    detail = ("margin = signed Chebyshev radius of Θ_(k−1) ∩ Δ_k, unit rows, θ units (HiGHS); Δ_k of (6) from the "
              "recorded x_(k−1), u_(k−1), x_k")
    if first is not None:
        detail += (f"; the data contradict Θ and W first at step {first} (and at {len(failing)} step(s) in all): the "
                   "disturbance left W, θ* is not in Θ, or the model (A_i, B_i) is wrong")
    return row_check("data_consistency", per, detail, "no transition recorded",
                     extra={"first_failing_step": first, "failing_steps": failing})


def apply(claims: list[CheckResult]) -> list[CheckResult]:
    """``claims`` with those of :data:`RESTS_ON_CONSISTENCY` that did not pass reported ``not_run`` when
    ``data_consistency`` failed first at step K (the reason and the outcome of their own check in the
    detail and in ``found_status``/``found_margin``), unless the claim fails at a step whose data were
    still consistent (k + lag < K): that failure is not explained by the data and stays a failure. A claim
    that passed stays: it was checked and holds on the run, although the paper no longer guarantees it
    (as for the premises, :func:`amcp_drake.certificate.premises.apply`). Unchanged when
    ``data_consistency`` holds."""
    consistency = next((c for c in claims if c.data.get("id") == "data_consistency"), None)
    if consistency is None or consistency.status != FAIL:
        return claims
    first = consistency.data["first_failing_step"]
    out = []
    for c in claims:
        lag = RESTS_ON_CONSISTENCY.get(c.data.get("id"))
        if lag is None or c.status == PASS or _fails_before(c, first - lag):
            out.append(c)
            continue
        found = "n/a" if c.margin is None else f"{c.margin:.3e}"
        reason = (f"not run: rests on data_consistency, which fails at step {first} (the data contradict Θ and W, so "
                  f"this guarantee does not apply); its check found {c.status}, margin {found}: {c.detail}")
        out.append(CheckResult(c.name, c.claim, NOT_RUN, None, c.tolerance, reason,
                               {**c.data, "worst_step": None, "rests_on": "data_consistency", "found_status": c.status,
                                "found_margin": c.margin if c.margin is not None and np.isfinite(c.margin) else None}))
    return out


def _fails_before(c: CheckResult, step: int) -> bool:
    """True when claim ``c`` fails at some step k < ``step`` (by its per-step margins, else its worst step;
    a failed claim without step information counts as failing early: it is never excused)."""
    if c.status != FAIL:
        return False
    per_step = c.data.get("per_step")
    if per_step:
        return any(k < step for k, m in per_step if m is None or m < -c.tolerance)
    worst = c.data.get("worst_step")
    return worst is None or worst < step
