"""The controller's state as one immutable value (amcp_drake.online.state): ``step_from(state, x)`` is a
function of (state, x), so two states stepped by one controller, interleaved, are two independent runs."""

from __future__ import annotations

from copy import deepcopy

import numpy as np
import pytest

from amcp_drake.model.options import OnlineOptions
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate
from amcp_drake.online.state import ControllerState

STEPS = 6
#: Two runs of Example 1 that differ in their start and their disturbances.
RUNS = ((np.array([2.0, 3.0]), 1), (np.array([-1.5, 2.0]), 2))

RECORD_ARRAYS = ("x", "u", "H_theta", "h_theta", "theta_hat", "theta_tilde", "v", "z", "alpha", "Lambda",
                 "set_Lambda", "h_theta_stages")


def _bits(a) -> bytes | None:
    return None if a is None else np.asarray(a, float).tobytes() + repr(np.shape(a)).encode()


def _close(a, b, tol: float) -> bool:
    if a is None or b is None or tol == 0.0:
        return _bits(a) == _bits(b)
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= tol * np.maximum(1.0, np.abs(a))))


def _same_record(a, b, tol: float = 0.0) -> list[str]:
    """Names of the fields in which two step records differ (arrays to the bit, or to ``tol`` relative)."""
    arrays = RECORD_ARRAYS if tol == 0.0 else RUN_FIELDS
    diff = [name for name in arrays if not _close(getattr(a, name), getattr(b, name), tol)]
    if not _close(a.cost, b.cost, tol):
        diff.append("cost")
    for name in ("k", "status", "set_status", "projection_status", "pe_status", "pe_bounds", "pe_level",
                 "pe_dim", "detail", "qp_detail", "answers"):
        if getattr(a, name) != getattr(b, name):
            diff.append(name)
    return diff


#: Where a backend's programs keep something from one solve to the next that changes answers at round-off,
#: a run is compared to ROUND_OFF (relative) in the fields that carry the run (RUN_FIELDS) instead of to
#: the bit: the cvxpy backend keeps its Clarabel solver (cvxpy's warm_start: the equilibration of its first
#: setup is reused; measured on Example 1: u_0 2.8e-15 apart between a first and a later solve of one QP,
#: the multipliers Λ further); the Drake plain form under the exact update (7) keeps its program while
#: Θ_k's row count fits the program's padded capacity (u 2.9e-11 apart). Everything else to the bit.
ROUND_OFF = 1e-9
RUN_FIELDS = ("x", "u", "H_theta", "h_theta", "theta_hat", "theta_tilde", "v")

CONFIGS = [
    ("drake", "plain", OnlineOptions(), 0.0),
    ("cvxpy", "plain", OnlineOptions(), ROUND_OFF),
    ("drake", "vertex", OnlineOptions(), 0.0),
    ("drake", "plain", OnlineOptions(update="window", window=3), 0.0),
    ("drake", "plain", OnlineOptions(update="exact"), ROUND_OFF),
    ("drake", "plain", OnlineOptions(pe_window=3, pe_level=0.2), 0.0),
]


@pytest.mark.parametrize(("backend", "formulation", "options", "tol"), CONFIGS,
                         ids=[f"{b}-{f}-{o.update}{'-pe' if o.pe_window else ''}" for b, f, o, _ in CONFIGS])
def test_two_states_stepped_by_one_controller_are_two_independent_runs(example_spec, example_design, backend,
                                                                        formulation, options, tol):
    """Runs A and B, each by its own controller (simulate), then both by one controller with their states
    interleaved step by step, fed the same states x_k: every record equal to the bit."""
    pr, theta_star = example_spec.problem, np.asarray(example_spec.scenario.theta_star, float)
    alone = [simulate(AdaptiveMPC(pr, example_design, backend, options, formulation=formulation), x0, theta_star,
                      STEPS, seed=seed) for x0, seed in RUNS]
    for traj in alone:
        assert traj.stop_reason == "completed"
    shared = AdaptiveMPC(pr, example_design, backend, options, formulation=formulation)
    states = [shared.initial_state(), shared.initial_state()]
    for k in range(STEPS + 1):
        for i, traj in enumerate(alone):
            u, states[i], record = shared.step_from(states[i], traj.x[k])
            assert _same_record(record, traj.records[k], tol) == [], (i, k)
            if k < STEPS:
                assert _close(u, traj.u[k], tol)
    assert [s.k for s in states] == [STEPS + 1, STEPS + 1]


def test_step_from_leaves_its_state_unchanged_and_step_advances_the_current_one(example_spec, example_design):
    """The input state is not changed (its arrays are read-only); step() is step_from on the current
    state; the same state stepped twice gives the same answer and the same next state."""
    pr = example_spec.problem
    ctrl = AdaptiveMPC(pr, example_design, "drake")
    x0 = np.array([2.0, 3.0])
    u0, _ = ctrl.step(x0)
    x1 = pr.step(x0, u0, np.asarray(example_spec.scenario.theta_star, float), np.array([0.05, -0.05]))
    before = ctrl.state
    copy = deepcopy(before)
    u_a, next_a, rec_a = ctrl.step_from(before, x1)
    u_b, next_b, rec_b = ctrl.step_from(before, x1)
    assert before.same_as(copy) and ctrl.state is before
    assert _bits(u_a) == _bits(u_b) and next_a.same_as(next_b) and _same_record(rec_a, rec_b) == []
    assert not next_a.same_as(before) and next_a.k == before.k + 1 == 2
    with pytest.raises(ValueError):
        before.h_theta[0] = 0.0
    u_c, rec_c = ctrl.step(x1)
    assert _bits(u_c) == _bits(u_a) and ctrl.state.same_as(next_a)


def test_a_state_is_copied_read_only_when_made(example_design):
    """Arrays given to a state are copied: changing the caller's array later does not change the state."""
    h = np.array(example_design.h_theta0, float)
    state = ControllerState(k=0, H_theta=example_design.H_theta, h_theta=h, theta_hat=np.zeros(2),
                            prev=(np.ones(2), np.ones(1)), window=[(np.ones((1, 2)), np.ones(1))], u_hist=[1])
    h[0] += 1.0
    assert state.h_theta[0] == h[0] - 1.0
    assert not state.h_theta.flags.writeable and not state.prev[0].flags.writeable
    assert not state.window[0][0].flags.writeable and state.u_hist == (1.0,)
    assert state.replace(k=3).k == 3 and state.k == 0
    assert not state.replace(h_theta=h).same_as(state)


def test_a_step_with_inconsistent_data_recorded_returns_the_state_it_was_given(example_spec, example_design):
    """on_inconsistent="record": a step whose data contradict Θ and W returns u = None, the very state it
    was given (Θ_(k−1), θ̂_(k−1) and k unchanged) and a record of the event; "raise" raises."""
    from amcp_drake.model.errors import InconsistentDataError
    from amcp_drake.online.controller import is_inconsistent

    pr = example_spec.problem
    ctrl = AdaptiveMPC(pr, example_design, "drake")
    x0 = np.array([2.0, 3.0])
    u0, _ = ctrl.step(x0)
    x1 = pr.step(x0, u0, np.asarray(example_spec.scenario.theta_star, float), 10.0 * pr.w_vertices()[0])
    state = ctrl.state
    u, nxt, record = ctrl.step_from(state, x1, on_inconsistent="record")
    assert u is None and nxt is state and is_inconsistent(record) and record.k == state.k == 1
    with pytest.raises(InconsistentDataError):
        ctrl.step_from(state, x1)
    assert ctrl.state is state
