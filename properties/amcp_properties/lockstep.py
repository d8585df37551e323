"""Lockstep comparison of the two backends on a recorded run.

The leader's trajectory fixes x_k, Θ_{k-1}, θ̂_{k-1}, (x_{k-1}, u_{k-1}) and the moving window; the
follower backend receives exactly these at every step and performs one step of the algorithm
(set update (9), projected LMS (12), QP (20)). Any difference then comes from the formulation
or the solver, never from drift. Both backends use Clarabel with :data:`ACCURATE` tolerances
(leader and follower, :func:`accurate_run`) and the same design: "cross-backend comparisons use
the same accurate solver". At Clarabel's defaults (1e-8 on the gap) v is determined only to about
1e-5 on flat optima: the thorough profile found a run (x0 on the boundary, vertex disturbances,
tests/data/lockstep-flat-optimum-problem.json) whose step-0 v differed by 1.14e-5 > 1.06e-5
between the backends at defaults, with the cvxpy answer 1.2e-5 and the Drake answer 9e-7 from the
optimum (both backends agree to 3.6e-9 at ACCURATE).

The follower's state is set as a :class:`~amcp_drake.online.state.ControllerState` (Θ_{k−1}, θ̂_{k−1},
the previous x and u, the window of data sets), as ``amcp_drake.comparison.compare`` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from amcp_drake.comparison.compare import ACCURATE_CLARABEL
from amcp_drake.model import polytope
from amcp_drake.model.check_result import CheckResult, judge
from amcp_drake.model.status import SolveStatus
from amcp_drake.online.controller import AdaptiveMPC

#: Clarabel options of both backends in the comparison (tube QP, and the LPs and projections, which
#: already run at 1e-10): the tolerances of tests/test_formulations.py and of ``amcp compare --accurate``.
ACCURATE = ACCURATE_CLARABEL

#: quantity -> (absolute, relative) tolerance; a difference d passes when d <= abs + rel·scale.
#: v is unique (the cost (17) is strictly convex in v, R ≻ 0) and both QPs are solved by Clarabel
#: to 1e-10 (ACCURATE); h_θ by LPs at 1e-10 (or simplex); θ̂ by projection QPs at 1e-10 (both, scaled form).
#: Worst |difference| / tolerance on 60 generated runs (seed 31, Drake leading): v 0.006,
#: h_θ 0.003, cost 0.0007, θ̂ 0.14 (the same tolerances as amcp_drake.comparison.compare.TOLERANCES).
TOLERANCES = {"v": (1e-5, 1e-5), "cost": (1e-5, 1e-6), "h_theta": (1e-6, 1e-6), "theta_hat": (1e-6, 1e-6)}


@dataclass
class Difference:
    step: int
    quantity: str
    difference: float
    tolerance: float

    @property
    def agree(self) -> bool:
        return self.difference <= self.tolerance


def _diff(step: int, quantity: str, a, b) -> Difference:
    a = np.atleast_1d(np.asarray(a, float))
    b = np.atleast_1d(np.asarray(b, float))
    if a.shape != b.shape:
        return Difference(step, quantity, float("inf"), 0.0)
    abs_tol, rel_tol = TOLERANCES[quantity]
    scale = float(max(np.max(np.abs(a)), np.max(np.abs(b)))) if a.size else 0.0
    return Difference(step, quantity, float(np.max(np.abs(a - b))) if a.size else 0.0, abs_tol + rel_tol * scale)


def _theta_k_diff(step: int, lead, rec) -> Difference:
    """Θ_k of the two backends compared. Same rows H_θ (update (9), the window): the offsets h_θ.
    Other rows (the exact update (7) keeps the rows its redundancy LPs leave, and two backends may keep
    different rows of the same set): the sets, by their support functions in the unit directions of
    both row sets (HiGHS at certified tolerances; equal sets have equal supports in every direction,
    and a set larger in some direction shows it in the other set's facet normal)."""
    H_a, H_b = np.asarray(lead.H_theta, float), np.asarray(rec.H_theta, float)
    if H_a.shape == H_b.shape and np.array_equal(H_a, H_b):
        return _diff(step, "h_theta", lead.h_theta, rec.h_theta)
    D = np.vstack([H_a, H_b])
    D = D / np.linalg.norm(D, axis=1)[:, None]
    supports = [[polytope.support(H, h, d, certified=True).value for d in D]
                for H, h in ((H_a, np.asarray(lead.h_theta, float)), (H_b, np.asarray(rec.h_theta, float)))]
    return _diff(step, "h_theta", supports[0], supports[1])


def vertex_case(case):
    """``case`` with the online options the vertex form of (20) takes: the certainty-equivalence cost
    (17), constant θ (d_θ = 0) and no persistent excitation (the min-max cost, the predicted sets (26)
    and the PE constraint need the plain form); the problem, design, x0, θ*, disturbances, update,
    window and projection are the case's."""
    return replace(case, options=replace(case.options, cost="certainty_equivalence", d_theta=0.0, pe_window=None))


def accurate_controller(case, backend: str, formulation: str = "plain") -> AdaptiveMPC:
    """The controller of ``case`` on ``backend`` with Clarabel at :data:`ACCURATE` tolerances."""
    return AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options, solver_options=ACCURATE,
                       formulation=formulation)


def accurate_run(case, backend: str, formulation: str = "plain"):
    """The leader's run for the comparison (:func:`amcp_properties.cases.run` with :func:`accurate_controller`)."""
    from .cases import run

    return run(case, backend, accurate_controller(case, backend, formulation))


def follow(traj, case, follower: str, formulation: str = "plain") -> tuple[list[Difference], list[tuple[int, str, str]]]:
    """Replay every step of ``traj`` on ``follower`` (at :data:`ACCURATE` tolerances, as the leader
    of :func:`accurate_run`); returns the differences and the statuses (step, leader, follower) that differ."""
    ctrl = accurate_controller(case, follower, formulation)
    window = case.options.window if case.options.update == "window" else 1
    diffs: list[Difference] = []
    statuses: list[tuple[int, str, str]] = []
    for k, lead in enumerate(traj.records):
        ctrl.reset()
        if k > 0:
            prev = traj.records[k - 1]
            s = ctrl.state.working()
            ctrl.state = ctrl.state.replace(
                k=k, H_theta=prev.H_theta, h_theta=prev.h_theta, theta_hat=prev.theta_hat,
                prev=(traj.x[k - 1], traj.u[k - 1]),
                window=[ctrl._delta(s, traj.x[j - 1], traj.u[j - 1], traj.x[j])
                        for j in range(k - 1, max(k - window, 0), -1)])
        _, rec = ctrl.step(np.array(traj.x[k]))
        if rec.status is not lead.status:
            statuses.append((k, lead.status.value, rec.status.value))
            continue
        diffs.append(_theta_k_diff(k, lead, rec))
        diffs.append(_diff(k, "theta_hat", lead.theta_hat, rec.theta_hat))
        if lead.status is SolveStatus.OPTIMAL:
            diffs.append(_diff(k, "v", lead.v, rec.v))
            diffs.append(_diff(k, "cost", lead.cost, rec.cost))
    return diffs, statuses


def backends_agree(traj, case, follower: str, formulation: str = "plain") -> CheckResult:
    """Every compared quantity within its tolerance and the same status at every step."""
    form = "" if formulation == "plain" else f", {formulation} form"
    claim = f"backends agree in lockstep ({traj.backend} leads, {follower} follows{form})"
    diffs, statuses = follow(traj, case, follower, formulation)
    if statuses:
        k, a, b = statuses[0]
        return judge("lockstep", claim, -np.inf, 0.0, f"status differs at step {k}: {a} vs {b} ({len(statuses)} steps)")
    if not diffs:
        return judge("lockstep", claim, None, 0.0, "no step to compare")
    worst = max(diffs, key=lambda d: d.difference / max(d.tolerance, 1e-300))
    # a tolerance of 0 marks quantities of different shapes (_diff): they disagree outright
    margin = 1.0 - worst.difference / worst.tolerance if worst.tolerance > 0 else -np.inf
    by_quantity = {}
    for d in diffs:
        by_quantity[d.quantity] = max(by_quantity.get(d.quantity, 0.0), d.difference)
    return judge("lockstep", claim, margin, 0.0,
                 f"worst: {worst.quantity} at step {worst.step}, |Δ| = {worst.difference:.2e} (tol {worst.tolerance:.2e}); "
                 + ", ".join(f"max |Δ{q}| = {v:.1e}" for q, v in by_quantity.items()),
                 data={"max_difference": by_quantity})
