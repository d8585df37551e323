"""The shipped-answers property (``test_shipped_answers.py``) for the large shipped examples (n = 6, 8 and the
102-facet quadrotor X0) on the Drake backend, in both formulations of (20), under Clarabel settings that emulate
another machine (:data:`amcp_properties.clarabel_settings.CLARABEL_PROFILES`): every step is answered by the
first answer of the run's own formulation (checked by amcp_drake.online.answer_checks; no re-solve after a
failed check, no fallback to the other formulation, nothing unanswered), and its v and cost equal the cvxpy
reference's (the vertex form of amcp_reference at the same x_k, Θ_k, θ̂_k, Clarabel at 1e-10) within the
backend comparison's tolerances (amcp_drake.comparison.compare.TOLERANCES)."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.comparison.compare import ACCURATE_CLARABEL, TOLERANCES
from amcp_drake.model.examples import EXAMPLES
from amcp_drake.online import answers

from .clarabel_settings import CLARABEL_PROFILES, LARGE_EXAMPLE_STEPS

CASES = [(name, form, profile) for name in LARGE_EXAMPLE_STEPS for form in ("plain", "vertex")
         for profile in CLARABEL_PROFILES]


@pytest.fixture(scope="module")
def designs() -> dict:
    """Offline design (Drake, Clarabel's defaults) and the cvxpy reference controller per example, on first need."""
    return {}


def _design(designs: dict, name: str):
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC

    if name not in designs:
        spec = EXAMPLES[name]()
        offline = design(spec.problem, spec.design, backend="drake")
        reference = AdaptiveMPC(spec.problem, offline, backend="cvxpy", options=spec.online, formulation="vertex",
                                solver_options=dict(ACCURATE_CLARABEL))
        designs[name] = (spec, offline, reference)
    return designs[name]


def within(quantity: str, a, b) -> bool:
    """|a − b| within TOLERANCES[quantity] (absolute + relative to the larger magnitude), as ``amcp compare``."""
    a, b = np.atleast_1d(np.asarray(a, float)), np.atleast_1d(np.asarray(b, float))
    abs_tol, rel_tol = TOLERANCES[quantity]
    scale = float(max(np.max(np.abs(a)), np.max(np.abs(b))))
    return a.shape == b.shape and float(np.max(np.abs(a - b))) <= abs_tol + rel_tol * scale


def test_within_is_the_comparison_tolerance_on_both_sides():
    """The helper passes a difference just inside the tolerance and fails one just outside (2x)."""
    v = np.array([1.0, -2.0])
    tol = TOLERANCES["v"][0] + TOLERANCES["v"][1] * 2.0
    assert within("v", v, v + np.array([0.0, 0.5 * tol]))
    assert not within("v", v, v + np.array([0.0, 2.0 * tol]))


@pytest.mark.slow
@pytest.mark.parametrize("name, formulation, profile", CASES)
def test_large_examples_answer_themselves_under_other_clarabel_settings(name, formulation, profile, designs):
    from amcp_drake.online.replay import run_scenario

    spec, offline, reference = _design(designs, name)
    traj = run_scenario(spec, "drake", offline=offline, steps=LARGE_EXAMPLE_STEPS[name], formulation=formulation,
                        backend_options={"solver_options": dict(CLARABEL_PROFILES[profile])})
    assert traj.stop_reason == "completed", traj.stop_reason
    assert answers.unknown_steps(traj.records) == []
    helped = [(r.k, e) for r in traj.records for e in r.answers if e["outcome"] != "first"]
    assert helped == [], f"{name}, {formulation} form, {profile}: answers not the first of the form: {helped[:5]}"
    for r in traj.records:
        entry = answers.of(r, "tube_qp")
        assert entry is not None and entry["outcome"] == "first", (r.k, entry)
        ref = reference.mpc.solve(r.x, r.h_theta, r.theta_hat)
        assert ref.status.value == "optimal", (r.k, ref.status, ref.detail)
        assert within("v", r.v, ref.v), (r.k, np.max(np.abs(np.asarray(r.v) - ref.v)))
        assert within("cost", r.cost, ref.cost), (r.k, r.cost, ref.cost)
