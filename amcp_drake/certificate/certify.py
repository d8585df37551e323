"""Certificates: an independent a-posteriori check of every claim of the paper on one recorded run.

``certify(traj)`` re-checks, from the recorded data only and with numpy/scipy only (never the
backend that ran the loop):

* the offline design (:func:`amcp_drake.offline.checks.verify_design`: (16), Assumptions 8 and 11,
  X0, w̄, f̄, μ of (11)) and the QP's vertex list of X0;
* the premises on this run: θ* ∈ Θ and w_k ∈ W (Assumption 1), the states follow (1), the inputs
  follow (21), and the Lemma 5 precondition μ‖D(x_k,u_k)‖² <= 1;
* Theorem 14 (i)-(iii): recursive feasibility, θ* ∈ Θ_k, θ̂_k ∈ Θ, (x_k, u_k) ∈ Z;
* Lemma 3 / (10): Θ ⊆ Θ_0, Θ_{k+1} ⊆ Θ_k, Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1};
* (12) and Lemma 5: the projected LMS update and the Lemma 5 inequality for every m;
* Proposition 9 at every solved step: tube containment by vertex enumeration, (5c), α >= 0,
  the terminal set, and the multipliers Λ as dual certificates (Λ >= 0, (15c), (15d));
* the recorded cost against (17) or (19) and, when the run enforces persistent excitation, the
  PE window level and input bounds of docs/explanation/paper.md §8 (:mod:`amcp_drake.certificate.section4`);
* the optimality of the recorded (z, α, v) for the QP (20) rebuilt from the record, by KKT
  residuals (:mod:`amcp_drake.certificate.optimality`).

Every run is also checked for model consistency, Θ_{k−1} ∩ Δ_k ≠ ∅ at every step
(:mod:`amcp_drake.certificate.consistency`). A *measured run* (``theta_star`` and ``w`` None: a plant
other than amcp's simulator) has the claims that need θ* or w reported ``not_applicable`` ("θ* and w
unknown", never a pass) and every other claim checked as on a simulated run; its verdict is on the
applicable claims.

The premises of the results (𝔻(x_0, Θ_0) ≠ ∅, Assumption 8, (11)) are reported apart from the claims
(:mod:`amcp_drake.certificate.premises`): a run whose premise is not met has the verdict
``"premise_not_met"``, and the claims that did not pass on it are "not claimed", never failed.

The claims are checked on the answers the controller applied (a checked fallback answer is a solved
step for Theorem 14). Whose answers they were is reported beside the verdict: the section
``solver_answers`` counts, per problem, the backend's first answers, re-solves, fallbacks (with
their kind and the check that rejected the backend's answer) and unsolved steps
(:mod:`amcp_drake.online.answers`), and :attr:`Certificate.conformance` is the backend's own verdict
line: ``"fail"`` when any of its answers was rejected, so that a backend defect reads as one, never as
a failed theorem and never as nothing.

Each claim is a :class:`~amcp_drake.model.check_result.CheckResult` (margin, tolerance, worst step in
``data["worst_step"]``). :attr:`Certificate.passed` is True only when every claim passed: a claim
that could not run (``not_run``) makes the verdict ``"incomplete"``, which is not a pass.
:data:`TOLERANCE_RULE` is how every margin is judged. The JSON
layout is described by ``amcp_drake/data/certificate.schema.json`` and docs/certificate.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import resources
from typing import Any

import numpy as np

from amcp_drake import __version__
from amcp_drake.certificate import consistency
from amcp_drake.certificate import premises as premise_checks
from amcp_drake.certificate.claims import RunView, run_checks, tag
from amcp_drake.certificate.optimality import qp_optimality
from amcp_drake.certificate.section4 import cost_value, excitation_checks, pe_figure
from amcp_drake.certificate.tube import GROUP_DESIGN, tube_checks, x0_vertex_list
from amcp_drake.model.check_result import FAIL, NOT_APPLICABLE, NOT_RUN, PASS, CheckResult, not_run
from amcp_drake.model.claim_table import CLAIMS
from amcp_drake.model.errors import TrajectoryError
from amcp_drake.model.problem import ProblemSpec
from amcp_drake.model.problem_io import jsonable
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answers
from amcp_drake.online.simulate import Trajectory

CERTIFICATE_FORMAT = "amcp-certificate"
#: Version of the certificate JSON layout (bump on any incompatible change; see docs/certificate.md).
CERTIFICATE_VERSION = 1
VERDICT_PASS, VERDICT_FAIL, VERDICT_INCOMPLETE = "pass", "fail", "incomplete"
#: A premise of the paper's results does not hold on this run (premises.py): nothing is claimed.
VERDICT_PREMISE_NOT_MET = "premise_not_met"
#: How every claim is judged, printed once above the claims (terminal and report).
TOLERANCE_RULE = ("a claim passes when its margin >= -tolerance (margin > 0: holds with room; a small negative "
                  "margin within the tolerance is round-off), the strict inequalities of Assumption 8 and (11) "
                  "when margin > 0; tolerances marked 'r' are relative (scaled by the "
                  "size of the quantity, see the statement), the others absolute in the claim's units")
#: Backend conformance (:func:`amcp_drake.online.answers.summarize`): every answer the backend's own;
#: some answer rejected by a check; provenance not recorded.
CONFORMANCE_PASS, CONFORMANCE_FAIL, CONFORMANCE_UNKNOWN = "pass", "fail", "unknown"
#: Claims whose margin and tolerance are relative (scaled by the size of the quantity, named in the claim's
#: detail), marked "r" beside the tolerance; every other tolerance is absolute in the claim's units.
#: Read from the rows' ``relative`` in the table of claims.
RELATIVE_TOLERANCES = {c.id: c.relative for c in CLAIMS if c.relative}
#: Recorded copies of the same number (x_k in the record and in the state array) must agree exactly
#: up to float64 rounding of a JSON round trip (which is exact); anything else is a corrupt file.
DUPLICATE_TOL = 1e-12


@dataclass(frozen=True, eq=False)
class Certificate:
    """The verdict on one run: ``claims`` in reading order, ``figures`` (convergence numbers),
    ``series`` (per-step values for plots), ``run`` (what was run)."""

    claims: list[CheckResult]
    figures: dict[str, Any]
    series: dict[str, Any]
    run: dict[str, Any]
    problem: dict[str, Any]
    created: str = field(default_factory=lambda: datetime.now(timezone.utc).isoformat(timespec="seconds"))
    #: the ``solver_answers`` section (:func:`amcp_drake.online.answers.summarize`)
    solver_answers: dict[str, Any] = field(default_factory=dict)
    #: the ``premises`` section (:mod:`amcp_drake.certificate.premises`)
    premises: list[dict[str, Any]] = field(default_factory=list)
    #: the ``provenance`` section (:mod:`amcp_drake.certificate.provenance`), set when the bundle is written
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def premises_not_met(self) -> list[dict[str, Any]]:
        """The premises of the paper's results that do not hold on this run."""
        return [p for p in self.premises if p["status"] == premise_checks.NOT_MET]

    @property
    def conformance(self) -> str:
        """The backend's verdict line: ``"pass"`` (every answer was its own, first or re-solved),
        ``"fail"`` (an answer was rejected by a check: a backend defect, whatever the claims say) or
        ``"unknown"`` (a trajectory without provenance)."""
        return self.solver_answers.get("conformance", CONFORMANCE_UNKNOWN)

    @property
    def not_claimed(self) -> list[dict[str, str]]:
        """Claims of the paper that this run's configuration does not make (id, name, reason): the
        robust baseline makes no (12)/Lemma 5 claim, time-varying θ* no Lemma 5 claim."""
        return list(self.run.get("not_claimed", []))

    @property
    def measured(self) -> bool:
        """True for a measured run (θ* and w unknown): its θ*/w claims are ``not_applicable``."""
        return bool(self.run.get("measured"))

    @property
    def passed(self) -> bool:
        """True only when every applicable claim passed (``not_run`` is not a pass; ``not_applicable``, a
        θ*/w claim of a measured run, is neither) and every premise is met."""
        applicable = [c for c in self.claims if c.status != NOT_APPLICABLE]
        return bool(applicable) and all(c.status == PASS for c in applicable) and not self.premises_not_met

    @property
    def verdict(self) -> str:
        """``"pass"``, ``"fail"`` (some claim failed), ``"premise_not_met"`` (no claim failed, a premise of the
        paper's results does not hold: nothing is claimed for the run) or ``"incomplete"`` (none failed, every
        premise met, some claim not run)."""
        if any(c.status == FAIL for c in self.claims):
            return VERDICT_FAIL
        if self.premises_not_met:
            return VERDICT_PREMISE_NOT_MET
        return VERDICT_PASS if self.passed else VERDICT_INCOMPLETE

    def claim(self, claim_id: str) -> CheckResult:
        """The claim with this id (KeyError if absent)."""
        for c in self.claims:
            if c.data.get("id") == claim_id:
                return c
        raise KeyError(claim_id)

    def ids(self, status: str | None = None) -> list[str]:
        """Claim ids, optionally only those with ``status``."""
        return [c.data["id"] for c in self.claims if status is None or c.status == status]

    def counts(self) -> dict[str, int]:
        return {s: sum(c.status == s for c in self.claims) for s in (PASS, FAIL, NOT_RUN, NOT_APPLICABLE)}

    def to_dict(self) -> dict[str, Any]:
        """The JSON layout of certificate.json (schema: ``data/certificate.schema.json``)."""
        return jsonable({
            "format": CERTIFICATE_FORMAT, "version": CERTIFICATE_VERSION, "generator": f"amcp-drake {__version__}",
            "created": self.created, "verdict": self.verdict, "passed": self.passed, "counts": self.counts(),
            "problem": self.problem, "run": self.run,
            "premises": self.premises, "claims": [claim_to_dict(c) for c in self.claims],
            "backend_conformance": self.conformance, "solver_answers": self.solver_answers,
            "figures": self.figures, "series": self.series,
            **({"provenance": self.provenance} if self.provenance else {}),
        })


def claim_to_dict(c: CheckResult) -> dict[str, Any]:
    """One claim as in certificate.json: id, group, name, claim, status, margin, tolerance, tolerance_relative
    (:data:`RELATIVE_TOLERANCES`), worst_step, detail, per_step (``[k, margin]`` pairs or null)."""
    margin = c.margin if c.margin is not None and np.isfinite(c.margin) else None
    extra = {k: v for k, v in c.data.items() if k not in ("id", "group", "worst_step", "per_step")}
    return {"id": c.data["id"], "group": c.data["group"], "name": c.name, "claim": c.claim, "status": c.status,
            "margin": margin, "tolerance": c.tolerance, "tolerance_relative": c.data["id"] in RELATIVE_TOLERANCES,
            "worst_step": c.data.get("worst_step"), "detail": c.detail,
            "per_step": c.data.get("per_step"), "extra": extra}


def schema() -> dict[str, Any]:
    """The JSON Schema of certificate.json."""
    import json

    return json.loads((resources.files("amcp_drake") / "data" / "certificate.schema.json").read_text())


def certify(traj: Trajectory, problem_spec: ProblemSpec | None = None) -> Certificate:
    """Check every claim on ``traj`` independently (see module docstring).

    ``problem_spec`` (optional) supplies the box |x_i| <= bound on which μ was computed when Z is
    unbounded in x and the trajectory does not record it; its problem must be the trajectory's.
    Raises TrajectoryError when the trajectory is structurally malformed (wrong shapes, non-finite
    numbers, copies of the same quantity that disagree); wrong *values* are failed claims instead.
    """
    validate_trajectory(traj)
    state_bound = traj.mu_state_bound if traj.mu_state_bound is not None else traj.design.mu_state_bound
    if problem_spec is not None:
        _require_same_problem(traj, problem_spec)
        if state_bound is None:
            state_bound = problem_spec.design.mu_state_bound
    claims = _design_claims(traj, state_bound)
    view = RunView(traj)
    run, lemma = run_checks(view, state_bound)
    at = next(i for i, c in enumerate(run) if c.data["id"] == "model_consistent") + 1
    run.insert(at, consistency.data_consistency(view))
    claims += run + tube_checks(view) + [cost_value(view), qp_optimality(view)] + excitation_checks(view)
    claims = consistency.apply(claims)
    figures, series = _figures(view, lemma)
    info = _run_info(traj, state_bound)
    info["not_claimed"] = [{"id": c.data["id"], "name": c.name, "reason": c.detail}
                           for c in claims if c.data.get("not_claimed")]
    claims = [c for c in claims if not c.data.get("not_claimed")]
    claims, premises, unclaimed = premise_checks.apply(claims, view)
    info["not_claimed"] += unclaimed
    return Certificate(claims=claims, figures=figures, series=series, run=info, premises=premises,
                       problem=_problem_summary(traj.problem),
                       solver_answers=answers.summarize(traj.records, traj.backend))


def _problem_summary(pr) -> dict:
    """Dimensions of the problem, and the names, units and sample time when the problem gives them
    (descriptive: ``states``/``inputs`` as ``name [unit]``, ``dt`` in seconds)."""
    out = {"name": pr.name, "n": pr.n, "m": pr.m, "p": pr.p, "N": pr.N}
    if pr.states:
        out["states"] = [pr.state_label(i) for i in range(pr.n)]
    if pr.inputs:
        out["inputs"] = [pr.input_label(j) for j in range(pr.m)]
    if pr.dt is not None:
        out["dt"] = pr.dt
    return out


# -- design ------------------------------------------------------------------------------------------
def _slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def _design_claims(traj: Trajectory, state_bound: float | None) -> list[CheckResult]:
    from amcp_drake.offline.checks import verify_design

    try:
        checks = [tag(c, f"design.{_slug(c.name)}", GROUP_DESIGN) for c in verify_design(traj.problem, traj.design,
                                                                                            state_bound)]
    except (ValueError, RuntimeError, np.linalg.LinAlgError) as exc:
        checks = [tag(not_run("design checks", "the offline design satisfies (16), Assumptions 8 and 11, (11)",
                              f"could not run: {exc}"), "design.checks", GROUP_DESIGN)]
    try:
        checks.append(x0_vertex_list(RunView(traj)))
    except (ValueError, RuntimeError) as exc:
        checks.append(tag(not_run("X0 vertex list", "(14): the QP's vertices of X0", f"could not run: {exc}"),
                          "design.x0_vertices", GROUP_DESIGN))
    return checks


# -- structural validation ---------------------------------------------------------------------------
def validate_trajectory(traj: Trajectory) -> None:
    """Raise TrajectoryError naming the first structural problem (shape, finiteness, duplicates)."""
    pr, d = traj.problem, traj.design
    n, m, p, N = pr.n, pr.m, pr.p, pr.N
    T = len(traj.u)

    def arr(name: str, value: Any, shape: tuple[int, ...] | None) -> np.ndarray:
        a = np.asarray(value, float) if value is not None else None
        if a is None:
            raise TrajectoryError(f"trajectory: {name} is missing")
        if shape is not None and a.shape != shape:
            raise TrajectoryError(f"trajectory: {name} has shape {a.shape}; expected {shape}")
        if not np.all(np.isfinite(a)):
            raise TrajectoryError(f"trajectory: {name} has NaN or infinite entries")
        return a

    arr("x", traj.x, (T + 1, n))
    arr("u", traj.u, (T, m))
    if (traj.theta_star is None) != (traj.w is None):
        missing = "theta_star" if traj.theta_star is None else "w"
        raise TrajectoryError(f"trajectory: {missing} is missing; expected theta_star and w both recorded (a simulated "
                              "run) or both null (a measured run)")
    if not traj.measured:
        arr("w", traj.w, (T, n))
        star = arr("theta_star", traj.theta_star, None)
        if star.shape not in ((p,), (T + 1, p)):
            raise TrajectoryError(f"trajectory: theta_star has shape {star.shape}; expected ({p},) or ({T + 1}, {p})")
    arr("design.K", d.K, (m, n))
    H_x = arr("design.H_x", d.H_x, None)
    if H_x.ndim != 2 or H_x.shape[1] != n:
        raise TrajectoryError(f"trajectory: design.H_x has shape {H_x.shape}; expected (u, {n})")
    X0v = arr("design.X0_vertices", d.X0_vertices, None)
    if X0v.ndim != 2 or X0v.shape[1] != n:
        raise TrajectoryError(f"trajectory: design.X0_vertices has shape {X0v.shape}; expected (v, {n})")
    H_T = arr("design.H_T", d.H_T, None)
    if H_T.ndim != 2 or H_T.shape[1] != n:
        raise TrajectoryError(f"trajectory: design.H_T has shape {H_T.shape}; expected (r, {n})")
    arr("design.h_T", d.h_T, (len(H_T),))
    if not (isinstance(d.mu, (int, float)) and np.isfinite(d.mu) and d.mu > 0):
        raise TrajectoryError(f"trajectory: design.mu must be a positive number, got {d.mu!r}")
    if len(traj.records) not in (T, T + 1) or len(traj.records) == 0:
        raise TrajectoryError(f"trajectory: {len(traj.records)} step records for {T} applied inputs; expected {T} or {T + 1}")
    u_rows, v_count = len(H_x), len(X0v)
    for i, r in enumerate(traj.records):
        where = f"records[{i}]"
        if r.k != i:
            raise TrajectoryError(f"trajectory: {where}.k = {r.k}; expected {i}")
        x = arr(f"{where}.x", r.x, (n,))
        if np.max(np.abs(x - traj.x[i])) > DUPLICATE_TOL * max(1.0, float(np.max(np.abs(x)))):
            raise TrajectoryError(f"trajectory: {where}.x differs from x[{i}] (corrupt or edited file)")
        H = arr(f"{where}.H_theta", r.H_theta, None)
        if H.ndim != 2 or H.shape[1] != p:
            raise TrajectoryError(f"trajectory: {where}.H_theta has shape {H.shape}; expected (q, {p})")
        arr(f"{where}.h_theta", r.h_theta, (len(H),))
        arr(f"{where}.theta_hat", r.theta_hat, (p,))
        if i < T:
            if r.u is None:
                raise TrajectoryError(f"trajectory: {where}.u is missing although u[{i}] was applied")
            u = arr(f"{where}.u", r.u, (m,))
            if np.max(np.abs(u - traj.u[i])) > DUPLICATE_TOL * max(1.0, float(np.max(np.abs(u)))):
                raise TrajectoryError(f"trajectory: {where}.u differs from u[{i}] (corrupt or edited file)")
        # the QP solution: required when the status says optimal, shape-checked whenever present
        # (a non-optimal status is a failed claim, recursive feasibility, not a malformed file)
        solution = {"v": (N, m), "z": (N + 1, n), "alpha": (N + 1,)}
        if not has_no_multipliers(traj):
            solution["Lambda"] = (N, v_count, u_rows, len(H))
        for name, shape in solution.items():
            if getattr(r, name) is not None or r.status is SolveStatus.OPTIMAL:
                arr(f"{where}.{name}", getattr(r, name), shape)
        if r.u is not None:
            arr(f"{where}.u", r.u, (m,))


def has_no_multipliers(traj: Trajectory) -> bool:
    """True for runs of the vertex formulation, whose QP has no Λ (records hold None)."""
    return traj.meta.get("formulation") == "vertex"


def _require_same_problem(traj: Trajectory, spec: ProblemSpec) -> None:
    a, b = traj.problem, spec.problem
    for name in a.__dataclass_fields__:
        if name == "name":
            continue
        va, vb = getattr(a, name), getattr(b, name)
        same = (np.shape(va) == np.shape(vb) and np.array_equal(va, vb)) if isinstance(va, np.ndarray) else va == vb
        if not same:
            raise TrajectoryError(f"the trajectory was recorded for a different problem than {b.name!r}: field {name} "
                                  "differs. Give only --trajectory, or the problem it was recorded for.")


# -- figures and series ------------------------------------------------------------------------------
def _theta_box(view: RunView, k: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Interval hull [lo, hi] of Θ_k per parameter and its diameter max ‖θ1 − θ2‖ (vertices, else LPs)."""
    from amcp_drake.model import polytope

    r = view.records[k]
    verts = view.theta_k_vertices[k]
    if verts is not None:
        diff = verts[:, None, :] - verts[None, :, :]
        return verts.min(axis=0), verts.max(axis=0), float(np.max(np.linalg.norm(diff, axis=2)))
    p = view.problem.p
    hi = np.array([polytope.support(r.H_theta, r.h_theta, e).value for e in np.eye(p)])
    lo = -np.array([polytope.support(r.H_theta, r.h_theta, -e).value for e in np.eye(p)])
    return lo, hi, float(np.linalg.norm(hi - lo))  # an upper bound when vertices are unavailable


def _figures(view: RunView, lemma) -> tuple[dict[str, Any], dict[str, Any]]:
    tr = view.traj
    boxes = [_theta_box(view, r.k) for r in view.records]
    lo = np.array([b[0] for b in boxes])
    hi = np.array([b[1] for b in boxes])
    widths = hi - lo
    diam = [b[2] for b in boxes]
    # a measured run: θ* and w unknown, so the estimation error and the disturbance figures are null
    err = (None if tr.measured else
           [float(np.linalg.norm(r.theta_hat - tr.theta_star_at(r.k))) for r in view.records])
    mu = view.design.mu
    mu_d2 = [float(mu * np.linalg.norm(view.problem.regressor(x, u), 2) ** 2) for _, x, u in view.inputs]
    figures = {
        "final_state_norm": float(np.linalg.norm(tr.x[-1])),
        "initial_state_norm": float(np.linalg.norm(tr.x[0])),
        "theta_width_initial": widths[0].tolist(),
        "theta_width_final": widths[-1].tolist(),
        "theta_diameter_initial": diam[0],
        "theta_diameter_final": diam[-1],
        "theta_hat_error_initial": None if err is None else err[0],
        "theta_hat_error_final": None if err is None else err[-1],
        "sum_state_norm_sq": float(np.sum(tr.x ** 2)),
        "sum_disturbance_norm_sq": None if tr.measured else float(np.sum(tr.w ** 2)),
        "max_mu_D_sq": max(mu_d2) if mu_d2 else None,
        "median_solver_time_s": _median([r.times.get("solver") for r in view.records]),
        "max_solver_time_s": _max([r.times.get("solver") for r in view.records]),
    }
    pe = pe_figure(view)
    if pe is not None:
        figures["persistent_excitation"] = pe
    series = {
        "k": [r.k for r in view.records],
        "x": tr.x.tolist(), "u": tr.u.tolist(), "w": None if tr.measured else tr.w.tolist(),
        "theta_lower": lo.tolist(), "theta_upper": hi.tolist(), "theta_width": widths.tolist(),
        "theta_diameter": diam,
        "theta_hat": [r.theta_hat.tolist() for r in view.records], "theta_hat_error": err,
        "lemma5_lhs": lemma.lhs.tolist(), "lemma5_rhs": lemma.rhs.tolist(),
        "mu_D_sq": mu_d2,
        "solver_time_s": [r.times.get("solver") for r in view.records],
        "step_time_s": [r.times.get("total") for r in view.records],
        "status": [r.status.value for r in view.records],
        "cost": [r.cost for r in view.records],
        "pe_status": [r.pe_status for r in view.records],
    }
    return figures, series


def _median(values) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.median(vals)) if vals else None


def _max(values) -> float | None:
    vals = [v for v in values if v is not None]
    return float(np.max(vals)) if vals else None


def _run_info(traj: Trajectory, state_bound: float | None) -> dict[str, Any]:
    opts = traj.options
    extra: dict[str, Any] = {"d_theta": getattr(opts, "d_theta", 0.0), "pe_window": getattr(opts, "pe_window", None),
                             "pe_level": getattr(opts, "pe_level", None),
                             "cost": getattr(opts, "cost", "certainty_equivalence")}
    if np.ndim(traj.theta_star) == 2:  # time-varying θ*_k (Section 4.1): "theta_star" is θ*_0
        extra["theta_star_sequence"] = np.asarray(traj.theta_star).tolist()
    return extra | {
        "backend": traj.backend, "steps": len(traj.u), "records": len(traj.records), "stop_reason": traj.stop_reason,
        "x0": traj.x[0].tolist(), "theta_star": None if traj.measured else traj.theta_star_at(0).tolist(),
        "measured": traj.measured,
        "simulator": traj.meta.get("simulator") or ("not recorded" if traj.measured else "amcp"),
        "theta_hat0": traj.problem.theta_hat0.tolist(),
        "update": traj.options.update, "window": traj.options.window, "projection": traj.options.projection,
        "disturbance": traj.meta.get("disturbance"), "seed": traj.meta.get("seed"),
        "mu": traj.design.mu, "mu_region": traj.design.mu_region, "mu_method": traj.design.mu_method,
        "mu_state_bound": state_bound,
        "design_backend": traj.design.backend,
        "formulation": traj.meta.get("formulation", "plain"),
        "formulation_reason": traj.meta.get("formulation_reason"),
    }
