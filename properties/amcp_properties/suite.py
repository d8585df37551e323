"""The strategies used by the property tests, built once per profile, and the per-example
bookkeeping (coverage events, notes).

Tests that share a strategy object and the ci seed see the same examples, so their closed-loop
runs are simulated once (:class:`amcp_properties.cases.Runner`).
"""

from __future__ import annotations

import numpy as np
from hypothesis import note
from hypothesis import strategies as st

from . import profiles
from .coverage import emit_events, features
from .strategies import closed_loop_cases, designed_problems

SIZES = profiles.sizes()
#: Corollary 16: the disturbance stops after a step in [0, ZERO_AFTER_MAX].
ZERO_AFTER_MAX = 15

#: Short closed-loop runs from (near-)boundary initial states: Theorem 14, Lemmas 3 and 5,
#: Proposition 9, lockstep.
CLOSED_LOOP = closed_loop_cases(steps=SIZES.steps, max_n=SIZES.max_n)
#: Designs only: Assumption 11.
DESIGNS = designed_problems(max_n=SIZES.max_n)
#: Finite-energy disturbances: w = 0 from a step in [0, 15] on, then ``tail`` more steps.
VANISHING = closed_loop_cases(steps=ZERO_AFTER_MAX + SIZES.tail, zero_after=st.integers(0, ZERO_AFTER_MAX),
                              max_n=SIZES.max_n)
#: Long runs for the finite gain (22): persistent disturbances, or finite energy (boolean).
LONG = closed_loop_cases(steps=SIZES.gain_steps,
                         zero_after=st.one_of(st.none(), st.integers(1, SIZES.gain_steps // 3)), max_n=SIZES.max_n)


def observe(case, traj, test: str, backend: str, coverage) -> None:
    """Record coverage of one run (events and recorder) and note the case for failure reports."""
    f = features(traj, case.labels)
    emit_events(f)
    coverage.record(f"{test}[{backend}]", f)
    pr = case.problem
    note(f"case: n={pr.n} m={pr.m} p={pr.p} N={pr.N} labels={case.labels}")
    note(f"x0={np.array2string(case.x0, precision=6)} theta*={np.array2string(case.theta_star, precision=6)} "
         f"options={case.options} run: {traj.stop_reason}, {len(traj.u)} steps")
