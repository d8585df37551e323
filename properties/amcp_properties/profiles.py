"""Hypothesis settings profiles of the property suite, selected by ``AMCP_PROFILE``.

* ``ci`` (default): derandomized and small, so that every property for both backends runs in
  about 6 minutes on a 2-core machine. Every test uses the same explicit seed
  (:data:`CI_SEED`, overridable with ``AMCP_SEED``), so tests that share a strategy see the same
  examples and the closed-loop runs are simulated once and checked by every claim
  (:class:`amcp_properties.cases.Runner`). Hypothesis forbids an example database together with
  derandomization (``derandomize=True implies database=None``), so a ci failure is replayed from
  the files written to ``AMCP_FAILURE_DIR`` and from the printed ``@reproduce_failure`` blob.
  ci does not shrink: shrinking a closed-loop counterexample takes Hypothesis' full 5-minute
  shrink budget per failing property (measured), which would triple the CI time exactly when
  something fails; the unshrunk failing example is still saved and replayable.
* ``thorough``: random seeds (new examples on every run), about 4x the ci examples per property
  and twice the steps, shrinking, and Hypothesis' example database in its default directory
  (``.hypothesis/examples``), which replays earlier failures first. Sized to finish within an
  hour on a 2-core machine (measured: 31 min for both backends, README): every example of a closed-loop
  property is a fresh offline design plus a run (about 0.6 s), so the earlier sizes (2000 examples
  of 50 steps per property) would have taken about 9 hours and were never run to completion. For
  a longer search, run it repeatedly: the seeds are random and the database keeps what failed.
  thorough draws systems of up to 5 states (``Sizes.max_n``; ci up to 3): a quarter of its problems
  have n = 4 or 5 (:func:`amcp_properties.strategies.problem_shapes`), designed by the automatic
  design; the coverage report counts the draws and runs per n. With them the hour no longer holds
  (measured on the shared 2-core machine, 2026-11-27: the seven properties of Theorem 14, Lemmas 3
  and 5 and Assumption 11 took 28 min on Drake; Theorem 14 (i) alone took 8 min on cvxpy): the whole
  profile for both backends takes a few hours (docs/how-to/property-suite.md).

Sizes are per kind of property: ``closed_loop`` (the claims checked on one shared run), ``design``
(Assumption 11), ``long`` (Corollary 16 and the finite gain) and ``lockstep``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from hypothesis import HealthCheck, Phase, seed, settings

PROFILE_ENV = "AMCP_PROFILE"
SEED_ENV = "AMCP_SEED"
#: The ci seed: Automatica vol. 103, p. 461 (the paper).
CI_SEED = 103_461
#: Health checks that do not apply: generating one example runs the offline design (0.1-2 s), and
#: a closed-loop run is a few hundred QPs; both are slow by nature, not by mistake. filter_too_much
#: stays on: a generator that starts rejecting most designs must fail loudly.
SUPPRESSED = [HealthCheck.too_slow, HealthCheck.data_too_large]


@dataclass(frozen=True)
class Sizes:
    """Examples per property kind and closed-loop run lengths (steps)."""

    closed_loop: int
    design: int
    long: int
    lockstep: int
    steps: int          # closed-loop claims and lockstep
    tail: int           # Corollary 16: steps after the disturbance stops
    gain_steps: int     # finite-gain runs
    max_n: int = 3      # largest state dimension drawn (strategies.problem_shapes)


SIZES = {
    "ci": Sizes(closed_loop=56, design=56, long=16, lockstep=16, steps=20, tail=40, gain_steps=90),
    "thorough": Sizes(closed_loop=200, design=200, long=40, lockstep=40, steps=40, tail=100, gain_steps=200,
                      max_n=5),
}

_COMMON = dict(deadline=None, suppress_health_check=SUPPRESSED, print_blob=True)


def register() -> None:
    """Register both profiles with Hypothesis."""
    settings.register_profile("ci", derandomize=True, max_examples=SIZES["ci"].closed_loop,
                              phases=[Phase.explicit, Phase.generate], **_COMMON)
    settings.register_profile("thorough", derandomize=False, max_examples=SIZES["thorough"].closed_loop,
                              **_COMMON)


def name() -> str:
    """The selected profile (``AMCP_PROFILE``, default ``ci``); ValueError when unknown."""
    value = os.environ.get(PROFILE_ENV, "ci")
    if value not in SIZES:
        raise ValueError(f"{PROFILE_ENV}={value!r}: expected one of {sorted(SIZES)}")
    return value


def load() -> str:
    """Register the profiles and load the selected one; returns its name."""
    register()
    selected = name()
    settings.load_profile(selected)
    return selected


def sizes() -> Sizes:
    """Sizes of the selected profile."""
    return SIZES[name()]


def examples(kind: str):
    """A settings decorator with the profile's example count for a property kind."""
    return settings(max_examples=getattr(sizes(), kind))


def shared_seed(test):
    """Under ``ci``, run ``test`` with the suite's explicit seed (the same for every test, so that
    runs are shared); under ``thorough``, leave it random."""
    if name() != "ci":
        return test
    return seed(int(os.environ.get(SEED_ENV, CI_SEED)))(test)
