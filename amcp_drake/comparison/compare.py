"""Cross-backend comparison: the same algorithm, two formulations, step by step.

* **lockstep** (default): one closed loop driven by backend A; at every step backend B receives the
  same x_k, Θ_{k-1}, θ̂_{k-1} and previous (x_{k-1}, u_{k-1}), so any difference in the updated h_θk,
  θ̂_k, the QP solution or the status comes from the formulation or the solver, never from drift.
  Both use the *same* offline design (backend A's), compared separately by :func:`compare_designs`.
* **independent**: two closed loops, each with its own design, on the same disturbance sequence;
  the report says where and how far the states drift apart.

Quantities compared and their tolerances are in :data:`TOLERANCES`. ``z``, ``α`` and ``Λ`` of (20) are
not unique (the cost (17) depends on v only), so they are reported but never count as disagreement;
v is unique because the cost is strictly convex in v (R ≻ 0). Under the min–max cost (19) the
objective is not strictly convex in v in general, so v and u agree only to the QP's accuracy
(measured on Example 2, 30 steps: 2e-6 in v, 1.6e-8 in the cost; the same tolerances apply).
With persistent excitation (Section 4.2 of the paper) the PE status and dimension must match exactly and the
enforced level to ``pe_level``'s tolerance.

How each answer was obtained counts too (``StepRecord.answers``, :mod:`amcp_drake.online.answers`):
where one backend needed a re-solve or a fallback (or solved nothing after a failed check) on a step
where the other answered first, :attr:`Comparison.answer_mismatches` names the step, the backend and
the failed check, and the backends do not agree unless ``allow_fallbacks`` says such help is
acceptable: a fallback makes the applied answers equal while the backend that needed it is wrong.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import ProblemSpec, check_theta_rate
from amcp_drake.offline.design import OfflineDesign, design
from amcp_drake.online import answers
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import disturbance_sequence

#: Clarabel options of both backends for ``amcp compare --accurate`` and the property suite's
#: lockstep comparison ("cross-backend comparisons use the same accurate solver"): at Clarabel's
#: defaults v is determined only to ~1e-5 on flat optima (the thorough profile found a step-0 v
#: 1.14e-5 apart, tests/data/lockstep-flat-optimum-problem.json; 3.6e-9 with these).
ACCURATE_CLARABEL = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}

#: quantity -> (absolute, relative) tolerance; a difference d passes when d <= abs + rel * scale.
#: Both backends default to Clarabel with feasibility/gap tolerances 1e-8 (QP) and 1e-10 (LPs);
#: measured worst differences on 50 steps of Example 1 are ~1e-7 in v and ~1e-9 in h_θ, so these
#: tolerances leave about two orders of magnitude; a loose solver (OSQP defaults, ~5e-2 in v) fails.
#: (`duplicates` pairs rows of this table with each other: alike in shape only, one row per quantity.)
TOLERANCES: dict[str, tuple[float, float]] = {
    "u": (1e-5, 1e-5),
    "v": (1e-5, 1e-5),
    "cost": (1e-5, 1e-6),
    "h_theta": (1e-6, 1e-6),
    "theta_hat": (1e-6, 1e-6),
    # PE level enforced (Section 4.2 of the paper): computed from the applied inputs, which agree to the u tolerance
    "pe_level": (1e-5, 1e-5),
    # the PE status and dimension of a step are discrete: they must match exactly
    "pe_status": (0.0, 0.0),
    # K, P solve an SDP whose objective trace(P⁻¹) is flat near the optimum: Clarabel at its default
    # tolerances fixes K to ~2e-5 in either stack (measured: 1.6e-5 between Drake and cvxpy on Example 1;
    # tighter Clarabel tolerances end in AlmostSolved). The rest of the design is compared with the
    # *same* K, P given to both backends, at LP accuracy.
    "K": (1e-4, 1e-4),
    "P": (1e-4, 1e-4),
    "H_x": (1e-6, 1e-6),
    "mu": (1e-8, 1e-6),
    "w_bar": (1e-6, 1e-6),
    "f_bar": (1e-6, 1e-6),
    "X_f support": (1e-5, 1e-5),
}
#: reported for information only: not unique optimisers of (20)
INFORMATIONAL = ("z", "alpha")


@dataclass
class Difference:
    """One compared quantity at one step (step None: the offline design)."""

    quantity: str
    step: int | None
    difference: float
    scale: float
    tolerance: float
    agree: bool

    def to_dict(self) -> dict[str, Any]:
        """As in compare.json; a quantity of :data:`INFORMATIONAL` has no tolerance and no verdict (null)."""
        if self.quantity in INFORMATIONAL:
            return {"quantity": self.quantity, "step": self.step, "difference": self.difference, "scale": self.scale,
                    "tolerance": None, "agree": None, "information_only": True}
        return {"quantity": self.quantity, "step": self.step, "difference": self.difference,
                "scale": self.scale, "tolerance": self.tolerance, "agree": self.agree}


@dataclass
class Comparison:
    """Every difference, the statuses per step, and the verdict."""

    mode: str
    backends: tuple[str, str]
    differences: list[Difference] = field(default_factory=list)
    informational: list[Difference] = field(default_factory=list)
    statuses: list[tuple[int, str, str]] = field(default_factory=list)
    drift: list[float] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    #: where one backend needed a re-solve or fallback and the other did not (answers.mismatches)
    answer_mismatches: list[dict[str, Any]] = field(default_factory=list)
    #: per backend, the count of its answers per (problem, outcome) over the run
    answer_counts: dict[str, dict[str, dict[str, int]]] = field(default_factory=dict)
    #: re-solves and fallbacks of one backend alone are acceptable (they then do not decide ``agree``)
    allow_fallbacks: bool = False

    @property
    def agree(self) -> bool:
        return (all(d.agree for d in self.differences) and not self.status_differences()
                and (self.allow_fallbacks or not self.answer_mismatches))

    def status_differences(self) -> list[tuple[int, str, str]]:
        """Steps whose statuses differ; with ``allow_fallbacks``, not those where one backend's status
        is "optimal_inaccurate" because its answer was rejected and a checked fallback answered (an
        answer mismatch at that step says so)."""
        helped = {m["step"] for m in self.answer_mismatches if m["outcome"] in ("resolved", "fallback")}
        return [(k, a, b) for k, a, b in self.statuses
                if a != b and not (self.allow_fallbacks and k in helped and "optimal" in (a, b)
                                   and {a, b} <= {"optimal", "optimal_inaccurate"})]

    def count_answers(self, backend: str, record) -> None:
        """Add ``record.answers`` to ``answer_counts[backend]``."""
        counts = self.answer_counts.setdefault(backend, {})
        for e in record.answers or ():
            per = counts.setdefault(e["problem"], {o: 0 for o in answers.OUTCOMES})
            per[e["outcome"]] += 1

    def worst(self) -> dict[str, Difference]:
        """The largest difference per quantity (relative to its tolerance; the informational quantities,
        which have none, by the difference itself)."""
        out: dict[str, Difference] = {}
        for d in self.differences + self.informational:
            cur = out.get(d.quantity)
            if cur is None or _ratio(d) > _ratio(cur):
                out[d.quantity] = d
        return out

    def disagreements(self) -> list[Difference]:
        return [d for d in self.differences if not d.agree]

    def flat_optimum_steps(self) -> list[int]:
        """Steps where v disagrees while the cost agrees: the signature of a flat optimum, where the
        solvers' duality gap fixes the cost but not the minimiser (the thorough profile's
        tests/data/lockstep-flat-optimum-problem.json: v 1.1e-5 apart at Clarabel's defaults, 3.6e-9
        at 1e-10). Only a hint for the reader: the verdict is unchanged."""
        cost_agrees = {d.step for d in self.differences if d.quantity == "cost" and d.agree}
        return sorted({d.step for d in self.differences if d.quantity == "v" and not d.agree and d.step in cost_agrees})

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "backends": list(self.backends), "agree": self.agree,
                "tolerances": {k: {"abs": a, "rel": r} for k, (a, r) in TOLERANCES.items()},
                "informational_quantities": list(INFORMATIONAL),
                "statuses": [{"step": k, "a": a, "b": b} for k, a, b in self.statuses],
                "differences": [d.to_dict() for d in self.differences],
                "informational": [d.to_dict() for d in self.informational],
                "drift": self.drift, "notes": self.notes, "flat_optimum_steps": self.flat_optimum_steps(),
                "answer_mismatches": self.answer_mismatches, "answer_counts": self.answer_counts,
                "allow_fallbacks": self.allow_fallbacks}


def _ratio(d: Difference) -> float:
    return d.difference if d.quantity in INFORMATIONAL else d.difference / max(d.tolerance, 1e-300)


def _diff(quantity: str, step: int | None, a, b) -> Difference:
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    if a.shape != b.shape:
        return Difference(quantity, step, float("inf"), 0.0, 0.0, False)
    diff = float(np.max(np.abs(a - b))) if a.size else 0.0
    scale = float(max(np.max(np.abs(a)) if a.size else 0.0, np.max(np.abs(b)) if b.size else 0.0))
    abs_tol, rel_tol = TOLERANCES.get(quantity, (0.0, 0.0))
    tol = abs_tol + rel_tol * scale
    return Difference(quantity, step, diff, scale, tol, bool(diff <= tol))


def compare_designs(spec: ProblemSpec, backends=("drake", "cvxpy")) -> tuple[list[Difference], list[OfflineDesign]]:
    """Offline designs of both backends: K, P and μ as each computes them; then X0, w̄, f̄ and X_f
    with backend B given backend A's K and P, so that the LP parts are compared at LP accuracy.
    Returns the differences and the two independent designs."""
    from dataclasses import replace

    from amcp_drake.offline.auto import chosen_options

    a = design(spec.problem, spec.design, backends[0])
    same_template = chosen_options(spec.design, a)  # backend B designs on the template A's auto mode chose
    b = design(spec.problem, same_template, backends[1])
    out = [_diff("K", None, a.K, b.K), _diff("P", None, a.P, b.P), _diff("mu", None, a.mu, b.mu)]
    b_same_gain = design(spec.problem, replace(same_template, K=a.K, P=a.P), backends[1])
    out += _compare_sets(a, b_same_gain)
    return out, [a, b]


def _compare_sets(a: OfflineDesign, b: OfflineDesign) -> list[Difference]:
    """X0 (H_x), w̄, f̄ and X_f by its support function in 64 directions (computed with scipy)."""
    from amcp_drake.model import polytope

    out = [_diff("H_x", None, a.H_x, b.H_x)]
    if out[0].agree:
        out += [_diff("w_bar", None, a.w_bar, b.w_bar), _diff("f_bar", None, a.f_bar, b.f_bar)]
    dim = a.H_T.shape[1] + 1
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(64, dim))
    sup = []
    for d in (a, b):
        H = np.vstack([np.column_stack([d.H_T, d.h_T]), np.r_[np.zeros(dim - 1), -1.0]])
        h = np.r_[np.ones(len(d.H_T)), 0.0]
        sup.append([polytope.support(H, h, e).value for e in directions])
    out.append(_diff("X_f support", None, sup[0], sup[1]))
    return out


def lockstep(spec: ProblemSpec, steps: int, seed: int, backends=("drake", "cvxpy"), options: OnlineOptions | None = None,
             backend_options: tuple[dict, dict] = ({}, {}), progress: bool = False,
             compare_offline: bool = True, allow_fallbacks: bool = False, offline: OfflineDesign | None = None) -> Comparison:
    """Lockstep comparison (module docstring); with ``compare_offline`` the designs too. ``offline``: a
    design to run both controllers on instead of designing (the designs are then not compared)."""
    pr, sc = spec.problem, spec.scenario
    comp = Comparison("lockstep", (backends[0], backends[1]), allow_fallbacks=allow_fallbacks)
    if offline is not None:
        d = offline
    elif compare_offline:
        design_diffs, (d, _) = compare_designs(spec, backends)
        comp.differences += design_diffs
    else:
        d = design(pr, spec.design, backends[0])
    ctrl_a = AdaptiveMPC(pr, d, backends[0], options, **backend_options[0])
    ctrl_b = AdaptiveMPC(pr, d, backends[1], options, **backend_options[1])
    W = disturbance_sequence(pr, sc.disturbance_for(steps), steps, seed)
    theta = np.asarray(sc.theta_star_for(steps), float)
    check_theta_rate(theta, ctrl_a.options.d_theta)
    x = np.asarray(sc.x0, float)
    iterator = range(steps + 1)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="lockstep", unit="step")
    for k in iterator:
        _sync(ctrl_b, ctrl_a)
        u_a, ra = ctrl_a.step(x)
        u_b, rb = ctrl_b.step(x)
        comp.statuses.append((k, ra.status.value, rb.status.value))
        _compare_answers(comp, k, ra, rb)
        comp.differences.append(_diff("h_theta", k, ra.h_theta, rb.h_theta))
        comp.differences.append(_diff("theta_hat", k, ra.theta_hat, rb.theta_hat))
        if u_a is None or u_b is None:
            comp.notes.append(f"step {k}: statuses {ra.status.value} / {rb.status.value}; run ends")
            break
        comp.differences += [_diff("u", k, u_a, u_b), _diff("v", k, ra.v, rb.v), _diff("cost", k, ra.cost, rb.cost)]
        if options is not None and options.pe_window is not None:
            comp.differences += _pe_diffs(k, ra, rb)
        comp.informational += [_diff("z", k, ra.z, rb.z), _diff("alpha", k, ra.alpha, rb.alpha)]
        if k == steps:
            break
        x = pr.step(x, u_a, theta[k] if theta.ndim == 2 else theta, W[k])
    return comp


def _compare_answers(comp: Comparison, k: int, ra, rb) -> None:
    """Count both records' answers and note where one backend needed help the other did not."""
    comp.count_answers(comp.backends[0], ra)
    comp.count_answers(comp.backends[1], rb)
    comp.answer_mismatches += answers.mismatches(k, ra.answers, rb.answers, comp.backends)


def _pe_diffs(k: int, ra, rb) -> list[Difference]:
    """PE at step k (docs/explanation/paper.md §8): the same status (which QP, which rung of the ladder) and level."""
    same = ra.pe_status == rb.pe_status and ra.pe_dim == rb.pe_dim
    out = [Difference("pe_status", k, 0.0 if same else 1.0, 0.0, 0.0, same)]
    if ra.pe_level is not None or rb.pe_level is not None:
        out.append(_diff("pe_level", k, -1.0 if ra.pe_level is None else ra.pe_level,
                         -1.0 if rb.pe_level is None else rb.pe_level))
    return out


def _sync(target: AdaptiveMPC, source: AdaptiveMPC) -> None:
    """Give ``target`` the state of ``source`` (Θ_{k-1}, θ̂_{k-1}, previous x, u, window, ...): the
    state is immutable, so both controllers can hold the same one."""
    target.state = source.state


def independent(spec: ProblemSpec, steps: int, seed: int, backends=("drake", "cvxpy"),
                options: OnlineOptions | None = None, backend_options: tuple[dict, dict] = ({}, {}),
                allow_fallbacks: bool = False, offline: OfflineDesign | None = None, simulate=None) -> Comparison:
    """Two closed loops, each with its own design, on the same disturbance sequence; with ``offline``
    both on that design (not designed, not compared). ``simulate``: the closed-loop function (default
    :func:`amcp_drake.online.simulate.simulate`; same arguments)."""
    if simulate is None:
        from amcp_drake.online.simulate import simulate

    pr, sc = spec.problem, spec.scenario
    comp = Comparison("independent", (backends[0], backends[1]), allow_fallbacks=allow_fallbacks)
    if offline is not None:
        designs = [offline, offline]
    else:
        design_diffs, designs = compare_designs(spec, backends)
        comp.differences += design_diffs
    W = disturbance_sequence(pr, sc.disturbance_for(steps), steps, seed)
    trajs = [simulate(AdaptiveMPC(pr, dsg, b, options, **bo), sc.x0, sc.theta_star_for(steps), steps, W)
             for dsg, b, bo in zip(designs, backends, backend_options)]
    ta, tb = trajs
    for k, (ra, rb) in enumerate(zip(ta.records, tb.records)):
        comp.statuses.append((k, ra.status.value, rb.status.value))
        _compare_answers(comp, k, ra, rb)
    n = min(len(ta.x), len(tb.x))
    comp.drift = [float(np.linalg.norm(ta.x[k] - tb.x[k])) for k in range(n)]
    for k in range(min(ta.steps, tb.steps)):
        comp.differences.append(_diff("u", k, ta.u[k], tb.u[k]))
    if ta.steps != tb.steps:
        comp.notes.append(f"run lengths differ: {ta.steps} vs {tb.steps} steps")
    return comp
