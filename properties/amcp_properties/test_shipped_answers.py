"""Every shipped example, on each backend and in each formulation of (20) it runs in, is answered by the backend
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


def _formulations(spec) -> tuple[str, ...]:
    """The formulations of (20) an example runs in: the vertex form needs θ* constant (d_θ = 0: the
    predicted sets (26) differ per stage otherwise), the certainty-equivalence cost (17) and no PE
    constraint; the plain form (15) takes every option."""
    online = spec.online
    if online is not None and (online.d_theta > 0 or online.cost != "certainty_equivalence"
                               or online.pe_window is not None):
        return ("plain",)
    return ("plain", "vertex")


_NAMES = sorted(EXAMPLES)
_FORMS = {name: _formulations(EXAMPLES[name]()) for name in _NAMES}
#: Every shipped example in every formulation it runs in (the examples of MEASURED_EXAMPLES in short runs).
CASES = [(name, form) for name in _NAMES if name not in MEASURED_EXAMPLES for form in _FORMS[name]]
MEASURED_CASES = [(name, form) for name in _NAMES if name in MEASURED_EXAMPLES for form in _FORMS[name]]
#: The (example, formulation) pairs left out of CASES and MEASURED_CASES: the controller refuses them.
LEFT_OUT = [(name, form) for name in _NAMES for form in ("plain", "vertex") if form not in _FORMS[name]]


def _assert_answered_by_the_backend(name, formulation, backend, shipped_designs, steps):
    from amcp_drake.online.replay import run_scenario

    spec, offline = _design(shipped_designs, name)
    traj = run_scenario(spec, backend, offline=offline, steps=steps, formulation=formulation)
    assert traj.stop_reason == "completed", traj.stop_reason
    assert answers.unknown_steps(traj.records) == []
    helped = [(r.k, e) for r in traj.records for e in r.answers if e["outcome"] in ("fallback", "not_solved")]
    assert helped == [], f"{name}, {backend}, {formulation} form: answers not the backend's own: {helped[:5]}"
    qp = [answers.of(r, "tube_qp") for r in traj.records]
    assert all(e is not None and e["outcome"] in ("first", "resolved") for e in qp)


@pytest.mark.parametrize("name, formulation", CASES)
def test_every_shipped_example_is_answered_by_the_backend_itself(name, formulation, backend, shipped_designs):
    _assert_answered_by_the_backend(name, formulation, backend, shipped_designs, STEPS)


@pytest.mark.parametrize("name, formulation", MEASURED_CASES)
def test_large_shipped_examples_are_answered_by_the_backend_itself_in_short_runs(name, formulation, backend,
                                                                                shipped_designs):
    """The same for the examples whose full runs do not fit the suite (amcp_drake.model.examples,
    MEASURED_EXAMPLES; their 50-step certificates are in docs/results.md): SHORT_RUN_STEPS steps; the runs
    listed in MEASURED_SKIPPED_FORMS are skipped visibly, with their cost as the reason."""
    if (name, backend, formulation) in MEASURED_SKIPPED_FORMS:
        pytest.skip(f"{name}, {backend}, {formulation} form: {MEASURED_SKIPPED_FORMS[name, backend, formulation]}")
    _assert_answered_by_the_backend(name, formulation, backend, shipped_designs, SHORT_RUN_STEPS)


@pytest.mark.parametrize("name, formulation", LEFT_OUT)
def test_the_formulations_left_out_are_refused_by_the_controller(name, formulation, backend, shipped_designs):
    """An (example, formulation) pair is left out of CASES only when the controller refuses it (a
    ProblemError naming ``formulation``), so no formulation an example runs in goes untested."""
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.online.controller import AdaptiveMPC

    spec, offline = _design(shipped_designs, name)
    with pytest.raises(ProblemError, match="formulation"):
        AdaptiveMPC(spec.problem, offline, backend=backend, options=spec.online, formulation=formulation)
