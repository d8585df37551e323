"""The property suite's memory bounds (properties/amcp_properties/cases.py, strategies.py): its caches
keep at most their byte limits, a controller dropped from the cache is freed, and a drawn case whose run
is estimated above the per-run bound is refused before the run and counted per n."""

from __future__ import annotations

import gc
import weakref
from dataclasses import replace

import numpy as np

from amcp_drake.model.limits import estimate_for
from amcp_drake.model.options import OnlineOptions
from amcp_properties.cases import Case, Memo, Runner, controller_bytes, trajectory_bytes
from amcp_properties.coverage import refusal_line
from amcp_properties.strategies import GeneratorStats, refuse_oversized_run


def test_a_memo_keeps_at_most_its_byte_limit_and_counts_what_it_drops():
    """Values of 40, 40, 40 bytes under a 100-byte limit: the oldest is dropped at the third; a value of
    150 bytes is returned but not kept, and drops everything older."""
    dropped = []
    memo = Memo(size=10, max_bytes=100, weigh=len, on_evict=lambda: dropped.append(1))
    for key in "abc":
        assert memo.get(key, lambda: b"x" * 40) == b"x" * 40
    assert "a" not in memo and "b" in memo and "c" in memo
    assert memo.nbytes == 80 and memo.evicted == 1 and dropped == [1]
    big = memo.get("d", lambda: b"y" * 150)
    assert len(big) == 150 and len(memo) == 0 and memo.nbytes == 0 and memo.evicted == 4
    assert memo.misses == 4 and memo.hits == 0


def test_a_memo_at_its_limit_keeps_it_exactly():
    """Two values of 50 bytes under a 100-byte limit are both kept (the bound is inclusive), a third drops one."""
    memo = Memo(size=10, max_bytes=100, weigh=len)
    memo.get("a", lambda: b"x" * 50)
    memo.get("b", lambda: b"x" * 50)
    assert len(memo) == 2 and memo.evicted == 0
    memo.get("c", lambda: b"x")
    assert len(memo) == 2 and "a" not in memo


def _case(spec, design, update: str, steps: int = 3) -> Case:
    pr = spec.problem
    return Case(spec=spec, design=design, x0=np.array([0.5, 0.5]), theta_star=np.asarray(pr.theta_hat0, float),
                w=np.zeros((steps, pr.n)), options=OnlineOptions(update=update))


def test_the_runner_bounds_its_controllers_by_their_estimate_and_frees_the_dropped_one(example_spec, example_design):
    """Two controllers of Example 1 (updates "fixed" and "exact"), a limit of 1.5 controllers' estimate:
    the first is dropped when the second is built, and no reference to it is left (collected at once)."""
    first, second = _case(example_spec, example_design, "fixed"), _case(example_spec, example_design, "exact")
    weight = controller_bytes(first)
    assert weight == estimate_for(first.problem, first.spec.design, 1, first.options, design=first.design).memory_bytes
    runner = Runner(controller_bytes_max=int(1.5 * weight))
    ctrl = runner.controller(first, "drake")
    ref = weakref.ref(ctrl)
    assert runner.controller(first, "drake") is ctrl  # reused while kept
    del ctrl
    runner.controller(second, "drake")
    assert runner.controllers.evicted == 1 and len(runner.controllers) == 1
    assert ref() is None
    assert runner.controllers.nbytes == controller_bytes(second) <= 1.5 * weight


def test_the_runner_keeps_runs_up_to_its_byte_limit(example_spec, example_design):
    """Runs of 3 steps under a limit of 1.5 runs' bytes: the second run drops the first; the cache
    holds trajectories only (their weight is that of their arrays)."""
    first, second = _case(example_spec, example_design, "fixed"), replace(
        _case(example_spec, example_design, "fixed"), x0=np.array([0.4, 0.5]))
    probe = Runner().run(first, "drake")
    runner = Runner(max_bytes=int(1.5 * trajectory_bytes(probe)))
    runner.run(first, "drake")
    runner.run(second, "drake")
    assert runner.evicted == 1 and len(runner) == 1 and (second.key(), "drake") in runner
    assert 0 < runner.nbytes <= 1.5 * trajectory_bytes(probe)


def test_a_draw_over_the_run_memory_bound_is_refused_and_counted(example_spec, example_design):
    """Example 1 with 40 steps is estimated at a few MiB (limits.estimate_for): refused under a limit of
    half its estimate, accepted under twice it; both sized cases counted, the refusal per n."""
    pr = example_spec.problem
    est = estimate_for(pr, example_spec.design, 40, OnlineOptions(), design=example_design).memory_bytes / 2**20
    stats = GeneratorStats()
    reason = refuse_oversized_run(pr, example_spec, example_design, 40, OnlineOptions(), est / 2, stats)
    assert reason is not None and "estimated memory" in reason and "RUN_MEMORY_MB" in reason
    assert refuse_oversized_run(pr, example_spec, example_design, 40, OnlineOptions(), est * 2, stats) is None
    assert stats.refused_by_dimension() == {2: (2, 1)} and stats.refusal_rate() == 0.5
    assert refusal_line(stats.refused_by_dimension(), est / 2).endswith("1 of 2 closed-loop cases (50.0%); by n: n=2: 1 of 2")


def test_a_dropped_value_in_a_reference_cycle_is_collected_at_once():
    """Without the collection on eviction a controller in a reference cycle stays until Python's next full
    collection; with it, at once (the Runner passes gc.collect)."""
    class Cyclic:
        def __init__(self):
            self.me = self

    gc.disable()
    try:
        memo = Memo(size=1, on_evict=gc.collect)
        memo.get("a", Cyclic)
        ref = weakref.ref(memo.get("a", Cyclic))
        memo.get("b", Cyclic)
        assert ref() is None
    finally:
        gc.enable()


def test_thorough_designs_of_every_n_have_the_candidate_time_budget_and_ci_designs_up_to_3_none(monkeypatch, example_spec):
    """The budget each design gets from the generator's cache: thorough at n = 2 the 60 s candidate budget, ci none
    (its examples must not depend on the machine's speed); a design over the budget is a rejection (cached error)."""
    from amcp_drake.offline.budget import DEFAULT_CANDIDATE_SECONDS, CandidateTimeout
    from amcp_properties import strategies

    seen = []

    def fake_design(problem, options, backend, budget):
        seen.append(budget)
        raise CandidateTimeout("terminal set X_f, iteration 25", DEFAULT_CANDIDATE_SECONDS)

    monkeypatch.setattr(strategies, "design", fake_design)
    thorough = strategies._DesignCache(4, strategies.timed_from_n("thorough"))
    ci = strategies._DesignCache(4, strategies.timed_from_n("ci"))
    for cache in (thorough, ci):
        try:
            cache.get(example_spec)
        except CandidateTimeout:
            pass
        else:
            raise AssertionError("the design's timeout must reach the generator as a rejection")
    assert seen[0].candidate_seconds == DEFAULT_CANDIDATE_SECONDS and seen[1] is None
