"""The candidate's time budget holds inside the gain LMI (16): a deliberately slow LMI, on a deterministic
CPU counter, stops its candidate within 10 % of the budget and is the phase named; the Drake backend
checks the budget before every solve of the LMI."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.backends import get_backend
from amcp_drake.model.examples import get_example
from amcp_drake.offline.auto import design_auto
from amcp_drake.offline.budget import CandidateTimeout, DesignBudget
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import _design_as_written, robust_gain


class FakeCPU:
    """A CPU-time counter that only advances when told to."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


class SlowGainBackend:
    """The Drake backend with a gain LMI that takes ``steps`` iterations of ``step`` CPU seconds each and
    calls the budget's tick after each one, as an iterative solver with a callback would."""

    def __init__(self, clock: FakeCPU, step: float, steps: int = 200) -> None:
        self._inner = get_backend("drake")
        self.name = self._inner.name
        self.clock, self.step, self.steps = clock, step, steps
        self.iterations = 0
        self.stops: list[float] = []  # the CPU counter where each call was stopped by the budget

    def robust_gain(self, A_vertices, B_vertices, Q, R, margin, tick=None):
        start = self.clock.now
        for _ in range(self.steps):
            self.clock.now += self.step
            self.iterations += 1
            if tick is not None:
                try:
                    tick("gain LMI (16): solver iteration")
                except CandidateTimeout:
                    self.stops.append(self.clock.now - start)
                    raise
        return self._inner.robust_gain(A_vertices, B_vertices, Q, R, margin)

    def __getattr__(self, name):
        return getattr(self._inner, name)


@pytest.mark.parametrize("step", [4.0, 5.9])
def test_a_slow_gain_lmi_stops_its_candidate_within_ten_percent_of_a_60_s_budget(step):
    """60 s budget, ticks every ``step`` s of (fake) CPU: the candidate ends "time budget" at the first
    tick past 60 s (64 or 65.9 s: within 66), naming the gain LMI; without the check it would run
    200 steps (800+ s)."""
    clock = FakeCPU()
    be = SlowGainBackend(clock, step)
    spec = get_example("lorenzen2019")
    lines: list[str] = []
    budget = DesignBudget(candidate_seconds=60.0, progress=lines.append, clock=clock)
    with pytest.raises(Exception) as err:  # every candidate shares the slow gain: AutoDesignError
        design_auto(spec.problem, spec.design, be, _design_as_written, robust_gain, verify_design, budget=budget)
    first = err.value.attempts[0]
    assert first.outcome == "time budget"
    assert "gain LMI (16)" in first.reason
    stopped_at = int(np.floor(60.0 / step)) + 1  # the first tick past 60 s
    assert be.stops, "the slow LMI was never stopped by the budget"
    assert 60.0 < be.stops[0] <= 66.0
    assert be.stops[0] == pytest.approx(stopped_at * step, abs=1e-9)


def test_a_tick_at_the_budget_continues_and_one_past_it_stops():
    """The edge: exactly 60.0 s used is inside the budget; 60.01 s is not."""
    clock = FakeCPU()
    budget = DesignBudget(candidate_seconds=60.0, clock=clock)
    clock.now = 60.0
    budget.tick("gain LMI (16)")
    clock.now = 60.01
    with pytest.raises(CandidateTimeout, match=r"gain LMI \(16\) \(60\.0 s used\)") as err:
        budget.tick("gain LMI (16)")
    assert err.value.used == pytest.approx(60.01)


def test_the_drake_gain_lmi_checks_the_budget_before_every_solve(monkeypatch):
    """Every solve of the LMI (the retry ladder included) is preceded by a tick naming the gain LMI, in
    the form as written (n = 2) and in the compact form (n >= COMPACT_FROM_N)."""
    from amcp_drake.backends import drake_
    from amcp_drake.model.problem_io import spec_from_dict
    from amcp_drake.studies.chains import mass_chain

    for spec in (get_example("lorenzen2019"), spec_from_dict(mass_chain(5))):
        pr = spec.problem
        be = get_backend("drake")
        events: list[str] = []
        real = be._sdp.solve

        def solve(prog, options=None, _real=real):
            events.append("solve")
            return _real(prog, options)

        monkeypatch.setattr(be._sdp, "solve", solve)
        tv = pr.theta_vertices()
        gain = be.robust_gain(np.array([pr.A_of(t) for t in tv]), np.array([pr.B_of(t) for t in tv]), pr.Q, pr.R,
                              1e-6, tick=lambda stage: events.append(stage))
        assert gain.status.value == "optimal"
        assert events.count("solve") >= 1
        for i, e in enumerate(events):
            if e == "solve":
                assert i > 0 and events[i - 1].startswith("gain LMI (16)")
        assert (pr.n >= drake_.COMPACT_FROM_N) == any("vertices" in e for e in events)
