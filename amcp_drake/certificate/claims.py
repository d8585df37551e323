"""Certificate checks on a recorded run: assumptions, Theorem 14, set membership, LMS, Lemma 5.

Every check recomputes its quantity from the recorded data (states, inputs, disturbances, Θ_k,
θ̂_k) with numpy and scipy (``amcp_drake.model.polytope``: HiGHS LPs and Qhull vertex enumeration),
never with the backend that produced the run. The tube and multiplier checks of Proposition 9
are in :mod:`amcp_drake.certificate.tube`.

Conventions: a check's ``margin`` is positive when the claim holds (in the units stated in its
``detail``), it passes when ``margin >= -tolerance``, and ``data`` holds ``id``, ``group``,
``worst_step`` (the step k of the worst margin) and ``per_step`` (``[k, margin]`` pairs).
A check with nothing to check (e.g. no transition recorded) is ``not_run``, never ``pass``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.check_result import NOT_APPLICABLE, CheckResult, judge, not_run
from amcp_drake.model.claim_table import claim as row_of
from amcp_drake.model.polytope import theta_vertices
from amcp_drake.online import answers
from amcp_drake.online.simulate import Trajectory

# Every claim's tolerance, name and statement are its row of the table of claims (model.claim_table), whose
# tolerances are named in model.tolerances.

#: Online update mode of the robust, non-adaptive baseline (Θ_k ≡ Θ_0, θ̂_k ≡ θ̂0): it makes the
#: claims of Theorem 14 and Proposition 9, but not (12) or Lemma 5, which are then not run.
NO_UPDATE = "none"



# -- helpers -----------------------------------------------------------------------------------
def step_check(check_id: str, group: str, name: str, claim: str, per_step: dict[int, float], tolerance: float,
               detail: str = "", empty_reason: str = "nothing to check in this run",
               extra: dict | None = None) -> CheckResult:
    """A CheckResult whose margin is the worst (smallest) of ``per_step`` margins.

    ``per_step`` maps step k to its margin; a NaN margin (a step whose quantity could not be
    computed) makes the whole check ``not_run``, as does an empty dict.
    """
    data = {"id": check_id, "group": group, "worst_step": None,
            "per_step": [[int(k), _finite_or_none(v)] for k, v in sorted(per_step.items())]}
    data.update(extra or {})
    if not per_step:
        result = not_run(name, claim, empty_reason, tolerance)
        return CheckResult(result.name, result.claim, result.status, None, tolerance, result.detail, data)
    bad = [k for k, v in per_step.items() if v != v]  # NaN: not computable (±inf are real margins)
    if bad:
        return CheckResult(name, claim, "not_run", None, tolerance,
                           f"could not be computed at steps {bad[:10]}; {detail}".strip("; "), data)
    worst = min(per_step, key=lambda k: per_step[k])
    data["worst_step"] = int(worst)
    return judge(name, claim, float(per_step[worst]) + 0.0, tolerance, detail, data)  # + 0.0: no "-0" margins


def tag(result: CheckResult, check_id: str, group: str, worst_step: int | None = None) -> CheckResult:
    """A copy of ``result`` with ``id``, ``group`` and ``worst_step`` in its data."""
    data = {**result.data, "id": check_id, "group": group, "worst_step": worst_step}
    return CheckResult(result.name, result.claim, result.status, result.margin, result.tolerance, result.detail, data)


def row_check(check_id: str, per_step: dict[int, float], detail: str = "",
              empty_reason: str = "nothing to check in this run", extra: dict | None = None, *,
              name: str | None = None, statement: str | None = None) -> CheckResult:
    """:func:`step_check` with the family, name, statement and tolerance of the claim's row in the table of
    claims (:mod:`amcp_drake.model.claim_table`); ``name``/``statement`` word a run variant of the claim."""
    row = row_of(check_id)
    return step_check(check_id, row.family, name or row.name, statement or row.statement, per_step, row.tolerance,
                      detail, empty_reason, extra)


def row_judge(check_id: str, margin: float | None, detail: str = "", worst_step: int | None = None) -> CheckResult:
    """One margin judged as the claim's row says (tolerance, strict), tagged with its id and family."""
    row = row_of(check_id)
    return tag(judge(row.name, row.statement, margin, row.tolerance, detail, strict=row.strict), check_id, row.family,
               worst_step)


def _finite_or_none(value: float) -> float | None:
    return float(value) if np.isfinite(value) else None


def max_over_set(H: np.ndarray, h: np.ndarray, verts: np.ndarray | None, directions: np.ndarray) -> np.ndarray:
    """max_{θ ∈ {Hθ <= h}} d·θ for each row d of ``directions``: by vertices when available, else
    by HiGHS support LPs (+inf unbounded, nan infeasible)."""
    directions = np.atleast_2d(directions)
    if verts is not None:
        return np.max(directions @ verts.T, axis=1)
    return np.array([polytope.support(H, h, d).value for d in directions])


def not_claimed(check_id: str, name: str, claim: str, group: str, reason: str) -> CheckResult:
    """A claim the paper does not make for this run's configuration: ``certify`` lists it under
    ``run["not_claimed"]`` with ``reason`` instead of among the claims (it is neither checked nor
    counted, so it cannot make a verdict "pass" or "incomplete")."""
    result = tag(not_run(name, claim, reason), check_id, group)
    return CheckResult(result.name, result.claim, result.status, None, 0.0, reason, {**result.data, "not_claimed": True})


#: Why a claim that needs θ* or the disturbances is not applicable to a measured run.
UNKNOWN_THETA_STAR_AND_W = "θ* and w unknown"


def not_applicable(check_id: str, statement: str | None = None) -> CheckResult:
    """A claim that needs θ* or w_k on a measured run (θ* and w unknown): status ``not_applicable``,
    never a pass; the detail names what it would need (its row's ``needs``)."""
    row = row_of(check_id)
    return CheckResult(row.name, statement or row.statement, NOT_APPLICABLE, None, 0.0,
                       f"{UNKNOWN_THETA_STAR_AND_W} (a measured run): this claim needs {row.needs}",
                       {"id": check_id, "group": row.family, "worst_step": None, "per_step": None})


def _not_adaptive(check_id: str, name: str, claim: str) -> CheckResult:
    return not_claimed(check_id, name, claim, row_of(check_id).family, "update mode 'none' is the robust baseline (θ̂_k ≡ θ̂0, no LMS "
                                                     "update (12))")


# -- the recorded run, viewed step by step -------------------------------------------------------
@dataclass
class RunView:
    """Per-step quantities of a trajectory, computed once and shared by the checks.

    ``T`` applied inputs u_0..u_{T-1}; ``records`` has T or T+1 entries (the last one is the step at
    x_T, whose input was computed but not applied). ``inputs`` lists every step k with a computed
    input: (k, x_k, u_k).
    """

    traj: Trajectory

    @property
    def problem(self):
        return self.traj.problem

    @property
    def design(self):
        return self.traj.design

    @property
    def T(self) -> int:
        return len(self.traj.u)

    @property
    def records(self):
        return self.traj.records

    @cached_property
    def inputs(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        out = [(k, self.traj.x[k], self.traj.u[k]) for k in range(self.T)]
        if len(self.records) == self.T + 1 and self.records[-1].u is not None \
                and answers.qp_applied(self.records[-1]):
            out.append((self.T, self.traj.x[self.T], np.asarray(self.records[-1].u, float)))
        return out

    @cached_property
    def solved(self) -> list[int]:
        """Steps that applied a checked answer of the tube QP (20) (z, α, v recorded): the backend's own,
        or a checked answer of the other formulation after the backend's was rejected
        (:func:`amcp_drake.online.answers.qp_applied`; a record without provenance: status "optimal").
        The claims are checked on the answers the controller applied; whose answers they were is the
        certificate's ``solver_answers`` section."""
        return [r.k for r in self.records if answers.qp_applied(r)]

    @cached_property
    def theta_k_vertices(self) -> list[np.ndarray | None]:
        """Vertices of each record's Θ_k (None when enumeration failed)."""
        return [theta_vertices(r.H_theta, r.h_theta) for r in self.records]

    def regressor(self, k: int) -> np.ndarray:
        """D_k = D(x_k, u_k) for an applied step (docs/explanation/paper.md §2)."""
        return self.problem.regressor(self.traj.x[k], self.traj.u[k])

    @cached_property
    def transitions(self) -> list[int]:
        """Steps k with x_k, u_k, w_k, x_{k+1} recorded."""
        return list(range(self.T))


# -- Assumption 1 and the control law (the premises of Theorem 14 on this run) -----------------
def theta_star_in_theta(view: RunView) -> CheckResult:
    """Assumption 1, eq. (3): θ* ∈ Θ. Margin: min_i (h_θ − H_θ θ*)_i / ‖[H_θ]_i‖."""
    if view.traj.measured:
        return not_applicable("theta_star_in_Theta")
    pr = view.problem
    H, h = polytope.normalize_rows(pr.H_theta, pr.h_theta)
    # time-varying θ*_k (Section 4.1, Assumption 17): every θ*_k must lie in Θ
    stars = np.atleast_2d(view.traj.theta_star)
    margin = float(np.min(h[None, :] - stars @ H.T))
    return row_judge("theta_star_in_Theta", margin, "margin = min_i (h_θ − H_θ θ*)_i, unit rows")


def disturbances_in_w(view: RunView) -> CheckResult:
    """Assumption 1: every recorded w_k ∈ W = {H_w w <= 1}. Margin: min_i (1 − H_w w_k)_i."""
    if view.traj.measured:
        return not_applicable("w_in_W")
    H_w = view.problem.H_w
    per = {k: float(np.min(1.0 - H_w @ view.traj.w[k])) for k in view.transitions}
    return row_check("w_in_W", per, "margin = min_i (1 − H_w w_k)_i", "no step was applied")


def model_consistency(view: RunView) -> CheckResult:
    """System (1): x_{k+1} = A(θ*) x_k + B(θ*) u_k + w_k. Margin: −‖residual‖_∞."""
    if view.traj.measured:
        return not_applicable("model_consistent")
    pr, tr = view.problem, view.traj
    per = {k: -float(np.max(np.abs(tr.x[k + 1] - pr.step(tr.x[k], tr.u[k], tr.theta_star_at(k), tr.w[k]))))
           for k in view.transitions}
    return row_check("model_consistent", per, "margin = −‖x_{k+1} − A(θ*)x_k − B(θ*)u_k − w_k‖_∞",
                     "no step was applied")


def control_law(view: RunView) -> CheckResult:
    """Control law (21): u_k = K x_k + v*_{0|k} for every step with a computed input."""
    K = view.design.K
    per = {}
    for k, x, u in view.inputs:
        r = view.records[k]
        if r.v is None:
            per[k] = float("nan")
            continue
        per[k] = -float(np.max(np.abs(u - (K @ x + r.v[0]))))
    return row_check("control_law", per, "margin = −‖u_k − K x_k − v*_{0|k}‖_∞", "no input was computed")


def mu_precondition(view: RunView, state_bound: float | None) -> CheckResult:
    """Lemma 5 precondition: μ‖D(x_k, u_k)‖₂² <= 1 at every visited (x_k, u_k) (docs/explanation/paper.md §3, (11)).

    When Z is unbounded in x (Example 1), μ was computed on a box |x_i| <= bound; the detail
    reports the largest |x_i| visited against that bound.
    """
    if view.traj.options.update == NO_UPDATE:
        return _not_adaptive("mu_precondition", "μ‖D(x_k,u_k)‖² <= 1", "Lemma 5 precondition: μ‖D(x_k, u_k)‖₂² <= 1")
    mu = view.design.mu
    per = {k: 1.0 - mu * float(np.linalg.norm(view.problem.regressor(x, u), 2) ** 2) for k, x, u in view.inputs}
    xmax = max((float(np.max(np.abs(x))) for _, x, _ in view.inputs), default=float("nan"))
    box = f"; μ was computed over {view.design.mu_region}"
    if state_bound is not None:
        box += f"; max |x_i| visited = {xmax:.4g} ({'inside' if xmax <= state_bound else 'OUTSIDE'} the box " \
               f"|x_i| <= {state_bound:g})"
    return row_check("mu_precondition", per, f"margin = 1 − μ‖D(x_k,u_k)‖₂², μ = {mu:.6g}{box}", "no input was computed",
                      extra={"max_abs_state": _finite_or_none(xmax), "state_bound": state_bound})


# -- Theorem 14 -------------------------------------------------------------------------------------
def recursive_feasibility(view: RunView) -> CheckResult:
    """Theorem 14 (i): the QP (20) (and the updates (9), (12) before it) solved at every step.

    A step counts as solved when the controller applied a checked answer of (20) (:attr:`RunView.solved`),
    whichever method gave it: a backend defect is the ``solver_answers`` section's, not Theorem 14's.
    Margin: −(number of steps k = 0..T without an applied answer, missing records included).
    """
    expected = view.T + 1
    solved = set(view.solved)
    failed = [r.k for r in view.records if r.k not in solved]
    missing = list(range(len(view.records), expected))
    bad = sorted(failed + missing)
    statuses = {r.k: r.status.value for r in view.records if r.k not in solved}
    detail = (f"{expected - len(bad)} of {expected} steps solved; stop reason: {view.traj.stop_reason}"
              + (f"; failed: {statuses}" if statuses else "") + (f"; missing records: {missing}" if missing else ""))
    return row_judge("recursive_feasibility", float(-len(bad)), detail, bad[0] if bad else None)


def theta_star_in_theta_k(view: RunView) -> CheckResult:
    """Theorem 14 (ii), Lemma 3: θ* ∈ Θ_k for every recorded Θ_k. Margin: min_i (h_k − H_k θ*)_i, unit rows."""
    if view.traj.measured:
        return not_applicable("theta_star_in_Theta_k")
    per = {}
    for r in view.records:
        H, h = polytope.normalize_rows(r.H_theta, r.h_theta)
        per[r.k] = float(np.min(h - H @ view.traj.theta_star_at(r.k)))
    variant = ({"name": "θ*_k ∈ Θ_k",
                "statement": "Proposition 19 (Section 4.1): the time-varying parameter θ*_k lies in Θ_k at every k"}
               if view.traj.time_varying else {})
    return row_check("theta_star_in_Theta_k", per, "margin = min_i (h_θk − H_θk θ*)_i with unit rows", **variant)


def theta_hat_in_theta(view: RunView) -> CheckResult:
    """Theorem 14 (ii), Lemma 5: θ̂_k ∈ Θ. Margin: min_i (h_θ − H_θ θ̂_k)_i, unit rows."""
    pr = view.problem
    H, h = polytope.normalize_rows(pr.H_theta, pr.h_theta)
    per = {r.k: float(np.min(h - H @ r.theta_hat)) for r in view.records}
    return row_check("theta_hat_in_Theta", per, "margin = min_i (h_θ − H_θ θ̂_k)_i with unit rows")


def state_input_constraints(view: RunView) -> CheckResult:
    """Theorem 14 (iii): (x_k, u_k) ∈ Z, F x_k + G u_k <= 1 (4), at every step with a computed input."""
    pr = view.problem
    per = {k: float(np.min(1.0 - pr.F @ x - pr.G @ u)) for k, x, u in view.inputs}
    return row_check("state_input_constraints", per, "margin = min_i (1 − F x_k − G u_k)_i", "no input was computed")


# -- set membership: Lemma 3, (9), (10) -----------------------------------------------------------
#: A row of Δ_k shorter than this is treated as the zero row (its direction carries no information).
DELTA_ZERO_ROW = 1e-12


def _delta(view: RunView, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Δ_{k+1} of (6) from (x_k, u_k, x_{k+1}): {θ | −H_w D_k θ <= 1 + H_w d_{k+1}},
    d_{k+1} = A0 x_k + B0 u_k − x_{k+1}."""
    pr, tr = view.problem, view.traj
    D = pr.regressor(tr.x[k], tr.u[k])
    d = pr.A0 @ tr.x[k] + pr.B0 @ tr.u[k] - tr.x[k + 1]
    H, h = -pr.H_w @ D, 1.0 + pr.H_w @ d
    # Unit rows: the same set, but HiGHS' absolute tolerance (1e-7) on a row of norm 1e-3 would allow
    # θ errors of 1e-4 (the 200-problem campaign found false failures of up to 2.7e-6 this way).
    # A zero row 0·θ <= h is dropped when h >= 0 (it holds for every θ) and kept otherwise (empty set).
    norms = np.linalg.norm(H, axis=1)
    zero = norms <= DELTA_ZERO_ROW
    keep = ~zero | (h < 0)
    scale = np.where(zero, 1.0, norms)
    return (H / scale[:, None])[keep], (h / scale)[keep]


def prior_contains_theta(view: RunView) -> CheckResult:
    """Lemma 3 premise: Θ ⊆ Θ_0 = {H_θ θ <= h_θ0}. Margin: min_i (h_0 − max_{θ∈Θ} [H_0]_i θ) (vertices of Θ)."""
    if not view.records:
        return tag(not_run("Θ ⊆ Θ_0", "Lemma 3 premise: Θ ⊆ Θ_0", "no step recorded"), "Theta0_contains_Theta",
                   row_of("Theta0_contains_Theta").family)
    r0 = view.records[0]
    H, h = polytope.normalize_rows(r0.H_theta, r0.h_theta)
    verts = view.problem.theta_vertices()
    margin = float(np.min(h - np.max(H @ verts.T, axis=1)))
    return row_judge("Theta0_contains_Theta", margin, "margin = min_i (h_0 − max_{θ ∈ vert Θ} [H_0]_i θ)_i, unit rows", 0)


def nested_sets(view: RunView) -> CheckResult:
    """(10), right inclusion: Θ_{k+1} ⊆ Θ_k.

    Same shape H (fixed complexity (9)): h_{k+1} <= h_k componentwise. Otherwise: for every row
    i of Θ_k, max_{θ∈Θ_{k+1}} [H_k]_i θ <= [h_k]_i by vertices (or HiGHS LPs). Unit rows.
    """
    d_theta = float(getattr(view.traj.options, "d_theta", 0.0))
    if d_theta > 0:
        return _dilated_nesting(view, d_theta)
    per = {}
    modes = set()
    for k in range(len(view.records) - 1):
        a, b = view.records[k], view.records[k + 1]
        Ha, ha = polytope.normalize_rows(a.H_theta, a.h_theta)
        if a.H_theta.shape == b.H_theta.shape and np.array_equal(a.H_theta, b.H_theta):
            _, hb = polytope.normalize_rows(b.H_theta, b.h_theta)
            per[k + 1] = float(np.min(ha - hb))
            modes.add("componentwise h")
        else:
            support = max_over_set(b.H_theta, b.h_theta, view.theta_k_vertices[k + 1], Ha)
            per[k + 1] = float(np.min(ha - support))
            modes.add("support of Θ_{k+1}")
    return row_check("Theta_k_nested", per, f"margin = min_i ([h_k]_i − max_{{Θ_(k+1)}} [H_k]_i θ), unit rows ({', '.join(sorted(modes))});"
                      " worst step = k+1", "fewer than two set estimates recorded")


def _dilated_nesting(view: RunView, d_theta: float) -> CheckResult:
    """Section 4.1 replacement of (10) right: with (25), Θ_{k+1} = D_1(Θ_k ∩ Δ_{k+1}) ∩ Θ ⊆ D_1(Θ_k) ∩ Θ_0,
    i.e. on unit rows of the fixed shape h_{k+1} <= min(h_k + d_θ, h_0) componentwise (Θ_k are not nested)."""
    per = {}
    r0 = view.records[0]
    _, h0 = polytope.normalize_rows(r0.H_theta, r0.h_theta)
    for k in range(len(view.records) - 1):
        a, b = view.records[k], view.records[k + 1]
        if not (a.H_theta.shape == b.H_theta.shape and np.array_equal(a.H_theta, b.H_theta)):
            per[k + 1] = float("nan")  # time-varying θ* is supported only with a fixed shape
            continue
        _, ha = polytope.normalize_rows(a.H_theta, a.h_theta)
        _, hb = polytope.normalize_rows(b.H_theta, b.h_theta)
        per[k + 1] = float(np.min(np.minimum(ha + d_theta, h0) - hb))
    return row_check("Theta_k_nested", per,
                     "margin = min_i (min([h_k]_i + d_θ, [h_0]_i) − [h_(k+1)]_i), unit rows; worst step = k+1",
                     "fewer than two set estimates recorded", name="Θ_{k+1} ⊆ D_1(Θ_k) ∩ Θ_0",
                     statement=f"Section 4.1, (25): the set estimates grow by at most d_θ = {d_theta:g} per step "
                               "(they are not nested when θ* varies)")


def lower_inclusion(view: RunView) -> CheckResult:
    """(10), left inclusion: Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1} (Lemma 3; its constraints are those of (9)).

    For the moving window of Remark 4 the update intersects the last M data sets, so the claim
    checked is Θ_k ∩ Δ_{k+1} ∩ ... ∩ Δ_{k+2-M} ⊆ Θ_{k+1}. Support LPs (HiGHS) over the left side
    in the directions of H_{θ,k+1}; margin min_i ([h_{k+1}]_i − support_i), unit rows. An empty
    left side makes the inclusion vacuous (it contradicts θ* ∈ Θ_k ∩ Δ_{k+1}, which the
    Assumption 1 checks catch); such steps are listed in the detail.
    """
    opts = view.traj.options
    window = opts.window if opts.update == "window" else 1
    per, empty = {}, []
    for k in view.transitions:
        if k + 1 >= len(view.records):
            continue
        a, b = view.records[k], view.records[k + 1]
        rows_H, rows_h = list(polytope.normalize_rows(a.H_theta, a.h_theta))[:1], [polytope.normalize_rows(a.H_theta, a.h_theta)[1]]
        for j in range(k, max(k - window, -1), -1):
            Hd, hd = _delta(view, j)
            rows_H.append(Hd)
            rows_h.append(hd)
        H, h = np.vstack(rows_H), np.concatenate(rows_h)
        Hb, hb = polytope.normalize_rows(b.H_theta, b.h_theta)
        margins = []
        for d, limit in zip(Hb, hb):
            res = polytope.support(H, h, d)
            if res.status == "infeasible":
                margins = None
                break
            margins.append(limit - res.value if res.status == "optimal" else -np.inf if res.status == "unbounded"
                           else float("nan"))
        if margins is None:
            empty.append(k + 1)
            per[k + 1] = float("inf")
            continue
        per[k + 1] = float(min(margins))
    detail = ("margin = min_i ([h_(k+1)]_i − max_{Θ_k ∩ Δ_(k+1)} [H_(k+1)]_i θ), unit rows (HiGHS LPs); worst step = k+1"
              + (f"; window M = {window}" if window > 1 else ""))
    if empty:
        detail += f"; vacuous (Θ_k ∩ Δ_(k+1) empty, the data contradict the model) at steps {empty}"
    result = row_check("Theta_k_lower_inclusion", per, detail, "no update recorded", extra={"empty_steps": empty})
    return result


# -- point estimate: (12) and Lemma 5 --------------------------------------------------------------
def lms_update(view: RunView) -> CheckResult:
    """Projected LMS (12): θ̂_0 is the problem's θ̂0, and θ̂_{k+1} = Π_S(θ̃_{k+1}) with
    θ̃_{k+1} = θ̂_k + μ D_kᵀ (x_{k+1} − A(θ̂_k)x_k − B(θ̂_k)u_k), S = Θ (or Θ_{k+1}, Remark 7).

    θ̂ = Π_S(θ̃) iff θ̂ ∈ S and (θ̃ − θ̂)ᵀ(θ − θ̂) <= 0 for all θ ∈ S; the latter is linear in θ, so it is
    checked at the vertices of S. Margin: −max(variational-inequality residual, distance outside S).
    """
    pr, tr = view.problem, view.traj
    if tr.options.update == NO_UPDATE:
        return _not_adaptive("lms_update", "θ̂ follows (12)", "(12): the projected LMS update")
    per = {}
    if view.records:
        per[0] = -float(np.max(np.abs(view.records[0].theta_hat - pr.theta_hat0)))
    prior_verts = pr.theta_vertices()
    to_theta_k = tr.options.projection == "Theta_k"
    for k in view.transitions:
        if k + 1 >= len(view.records):
            continue
        nxt = view.records[k + 1]
        if not answers.projection_is_projection(nxt):  # a kept θ̂_k or a centre: no projection claimed
            continue
        th = view.records[k].theta_hat
        D = view.regressor(k)
        x_pred = pr.A_of(th) @ tr.x[k] + pr.B_of(th) @ tr.u[k]
        tilde = th + view.design.mu * D.T @ (tr.x[k + 1] - x_pred)
        if to_theta_k:
            H, h, verts = nxt.H_theta, nxt.h_theta, view.theta_k_vertices[k + 1]
        else:
            H, h, verts = pr.H_theta, pr.h_theta, prior_verts
        Hn, hn = polytope.normalize_rows(H, h)
        outside = float(np.max(Hn @ nxt.theta_hat - hn))
        gap = tilde - nxt.theta_hat
        vi = float(max_over_set(H, h, verts, gap[None, :])[0] - gap @ nxt.theta_hat)
        per[k + 1] = -max(vi, outside)
    variant = ({"statement": "(12): θ̂_(k+1) is the projection onto Θ_k (Remark 7) of the LMS step from the recorded "
                             "data"} if to_theta_k else {})
    return row_check("lms_update", per, "margin = −max(max_{θ ∈ vert S} (θ̃ − θ̂)ᵀ(θ − θ̂), max_i ([H]_i θ̂ − h_i)); "
                     "step 0: −‖θ̂_0 − θ̂0‖_∞", **variant)


@dataclass(frozen=True)
class Lemma5Series:
    """Running sums of Lemma 5 for m = 0..M−1: lhs[m] = (1/μ)‖θ̂_{m+1} − θ*‖² + Σ_{k<=m} ‖x̃_{1|k}‖²,
    rhs[m] = (1/μ)‖θ̂_0 − θ*‖² + Σ_{k<=m} ‖w_k‖², with x̃_{1|k} = D(x_k, u_k)(θ* − θ̂_k)."""

    lhs: np.ndarray
    rhs: np.ndarray
    x_tilde_sq: np.ndarray
    w_sq: np.ndarray


def lemma5_series(view: RunView) -> Lemma5Series:
    """The two sides of the Lemma 5 inequality from recorded data (docs/explanation/paper.md §3)."""
    tr = view.traj
    mu = view.design.mu
    M = min(view.T, len(view.records) - 1)
    if M <= 0 or tr.measured:  # a measured run: θ* and w unknown, no series
        empty = np.zeros(0)
        return Lemma5Series(empty, empty, empty, empty)
    star = tr.theta_star_at  # θ*_k (constant unless time-varying, Section 4.1)
    x_tilde_sq = np.array([float(np.sum((view.regressor(k) @ (star(k) - view.records[k].theta_hat)) ** 2))
                           for k in range(M)])
    w_sq = np.array([float(np.sum(tr.w[k] ** 2)) for k in range(M)])
    est = np.array([float(np.sum((view.records[m + 1].theta_hat - star(m + 1)) ** 2)) for m in range(M)]) / mu
    start = float(np.sum((view.records[0].theta_hat - star(0)) ** 2)) / mu
    return Lemma5Series(est + np.cumsum(x_tilde_sq), start + np.cumsum(w_sq), x_tilde_sq, w_sq)


def lemma5(view: RunView, series: Lemma5Series) -> CheckResult:
    """Lemma 5: (1/μ)‖θ̂_{m+1} − θ*‖² + Σ_{k<=m}‖x̃_{1|k}‖² <= (1/μ)‖θ̂_0 − θ*‖² + Σ_{k<=m}‖w_k‖² for every m."""
    if view.traj.options.update == NO_UPDATE:
        return _not_adaptive("lemma5", "Lemma 5 inequality", "Lemma 5: the ℓ2 bound of the point estimate")
    if view.traj.time_varying:
        return not_claimed("lemma5", "Lemma 5 inequality", "Lemma 5: the ℓ2 bound of the point estimate",
                           row_of("lemma5").family, "θ* varies with k: Section 4.1 claims no ℓ2 bound for the LMS")
    if view.traj.measured:
        return not_applicable("lemma5", "Lemma 5: the ℓ2 bound of the point estimate")
    per = {m: float(series.rhs[m] - series.lhs[m]) for m in range(len(series.lhs))}
    return row_check("lemma5", per, "margin = right side − left side; worst step = m", "no transition recorded")


def run_checks(view: RunView, state_bound: float | None) -> tuple[list[CheckResult], Lemma5Series]:
    """Every run-level check of this module, in reading order, and the Lemma 5 series."""
    series = lemma5_series(view)
    checks = [
        theta_star_in_theta(view), disturbances_in_w(view), model_consistency(view), control_law(view),
        mu_precondition(view, state_bound),
        recursive_feasibility(view), theta_star_in_theta_k(view), theta_hat_in_theta(view),
        state_input_constraints(view),
        prior_contains_theta(view), nested_sets(view), lower_inclusion(view),
        lms_update(view), lemma5(view, series),
    ]
    return checks, series
