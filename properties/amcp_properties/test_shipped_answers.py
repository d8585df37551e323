"""Every shipped example, on each backend and in both formulations of (20), is answered by the backend
itself: no answer of the set update (9), the projection (12) or the tube QP (20) is rejected by its check
and replaced by a fallback (amcp_drake.online.answers). A seeded defect in a backend's answers (a wrong v,
a dropped constraint, wrong offsets of (9)) is caught here even when the fallbacks keep the run safe and
every claim of the paper holds on the applied answers."""

from __future__ import annotations

import pytest

from amcp_drake.model.examples import EXAMPLES, MEASURED_EXAMPLES, MEASURED_SKIPPED_FORMS, SHORT_RUN_STEPS
from amcp_drake.online import answers

#: Closed-loop steps per run (the scenario's x0 and θ*): the first steps, from x0 on the boundary of the
#: feasible region in most examples, are the hard ones for the solvers.
STEPS = 5


@pytest.fixture(scope="session")
def shipped_designs() -> dict:
    """Offline designs of the shipped examples, one per example (Drake), made on first need."""
    return {}


def _design(designs: dict, name: str):
    from amcp_drake.offline.design import design

    if name not in designs:
        spec = EXAMPLES[name]()
        designs[name] = (spec, design(spec.problem, spec.design, backend="drake"))
    return designs[name]


def _assert_answered_by_the_backend(name, formulation, backend, shipped_designs, steps):
    from amcp_drake.online.replay import run_scenario

    spec, offline = _design(shipped_designs, name)
    if formulation == "vertex" and spec.online is not None and spec.online.d_theta > 0:
        pytest.skip(f"{name}: time-varying θ* (d_θ > 0) has only the plain form of (20)")
    traj = run_scenario(spec, backend, offline=offline, steps=steps, formulation=formulation)
    assert traj.stop_reason == "completed", traj.stop_reason
    assert answers.unknown_steps(traj.records) == []
    helped = [(r.k, e) for r in traj.records for e in r.answers if e["outcome"] in ("fallback", "not_solved")]
    assert helped == [], f"{name}, {backend}, {formulation} form: answers not the backend's own: {helped[:5]}"
    qp = [answers.of(r, "tube_qp") for r in traj.records]
    assert all(e is not None and e["outcome"] in ("first", "resolved") for e in qp)


@pytest.mark.parametrize("formulation", ["plain", "vertex"])
@pytest.mark.parametrize("name", sorted(set(EXAMPLES) - set(MEASURED_EXAMPLES)))
def test_every_shipped_example_is_answered_by_the_backend_itself(name, formulation, backend, shipped_designs):
    _assert_answered_by_the_backend(name, formulation, backend, shipped_designs, STEPS)


@pytest.mark.parametrize("formulation", ["plain", "vertex"])
@pytest.mark.parametrize("name", sorted(MEASURED_EXAMPLES))
def test_large_shipped_examples_are_answered_by_the_backend_itself_in_short_runs(name, formulation, backend,
                                                                                shipped_designs):
    """The same for the examples whose full runs do not fit the suite (amcp_drake.model.examples,
    MEASURED_EXAMPLES; their 50-step certificates are in docs/results.md): SHORT_RUN_STEPS steps, and not the
    runs listed in MEASURED_SKIPPED_FORMS (deselected, with the reason, rather than passed)."""
    if (name, backend, formulation) in MEASURED_SKIPPED_FORMS:
        pytest.skip(f"{name}, {backend}, {formulation} form: {MEASURED_SKIPPED_FORMS[name, backend, formulation]}")
    _assert_answered_by_the_backend(name, formulation, backend, shipped_designs, SHORT_RUN_STEPS)
