"""The property suite's Theorem 14 (i) counts a step answered by a checked fallback of the other formulation
as solved, as the certificate does (docs/decisions.md, "Verified solver answers"), and re-checks its constraints.

Recorded data (tests/data/property-theorem14-checked-fallback/): a thorough-profile draw (n = 1, Θ_1 pinned to
width 1e-6 by w_0) on which the cvxpy plain form's answer of step 1 was 2.2e-5 above the vertex form's optimum
(allowed 4.6e-6) after its re-solve; the vertex form's checked answer was applied (status
"optimal_inaccurate", answers: fallback vertex_form). The claim used to fail on the status alone."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from amcp_drake.model.status import SolveStatus
from amcp_drake.online.simulate import Trajectory
from amcp_properties import claims

DATA = Path(__file__).parent / "data" / "property-theorem14-checked-fallback"


def _recorded() -> Trajectory:
    return Trajectory.load(DATA / "trajectory.json.gz")


def test_the_recorded_step_was_answered_by_a_checked_fallback():
    r = _recorded().records[1]
    assert r.status is SolveStatus.INACCURATE and r.z is not None
    qp = [e for e in r.answers if e["problem"] == "tube_qp"]
    assert qp == [{"problem": "tube_qp", "outcome": "fallback", "kind": "vertex_form", "check": "status optimal_inaccurate"}]


def test_recursive_feasibility_passes_on_the_checked_fallback_and_rechecks_its_constraints():
    traj = _recorded()
    result = claims.recursive_feasibility(traj)
    assert result.passed, result.detail
    assert 1 in claims._solved(traj)
    margins = claims.tube_constraint_margins(traj, 1)
    assert min(v for k, v in margins.items() if not k.startswith("_")) >= -claims.TUBE_TOL


def test_a_step_without_an_applied_answer_still_fails():
    """The same record marked "not solved" (no plan applied): the claim fails at step 1."""
    traj = _recorded()
    r = traj.records[1]
    traj.records[1] = dataclasses.replace(r, answers=[dict(e, outcome="not_solved", kind="") if e["problem"] == "tube_qp"
                                                      else e for e in r.answers])
    result = claims.recursive_feasibility(traj)
    assert not result.passed and "[1]" in result.detail


def test_a_checked_fallback_whose_plan_breaks_a_constraint_fails():
    """The fallback's plan with α_1 lowered by 2x the tolerance below the (5b) row it must cover: the
    re-check without the solver fails it (the answer's provenance does not excuse its constraints)."""
    traj = _recorded()
    r = traj.records[1]
    margins = claims.tube_constraint_margins(traj, 1)
    alpha = np.array(r.alpha, float)
    alpha[1] -= margins["(5b) tube propagation"] + 2 * claims.TUBE_TOL
    traj.records[1] = dataclasses.replace(r, alpha=alpha)
    assert not claims.recursive_feasibility(traj).passed
