"""A closed-loop experiment (:class:`Case`) and how to run it on a backend (:class:`Runner`).

A case (:class:`amcp_drake.studies.random_problems.RandomCase`) is fully explicit (problem, design, x0, θ*, the whole disturbance array, online
options), so a run is a deterministic function of (case, backend); :class:`Runner` memoises runs
and controllers by content hash, which lets every property of the ci profile check its claim
on the same runs without re-simulating them.

Memory (the runs of the thorough profile reach n = 5, where one controller of the plain form (15) can
hold a GiB): both caches are bounded by bytes as well as by entries. A run is weighed by the arrays of
its records (:func:`trajectory_bytes`, measured: the cache holds the recorded trajectory only, which
refers to no backend object), a controller by the size estimate of its tube QP
(:func:`amcp_drake.model.limits.estimate_for` with the case's design: the estimate ``amcp certify``
refuses runs by). A controller dropped from the cache is collected at once (``gc.collect``): cvxpy's
expression trees are reference cycles, which Python otherwise frees only at its next full collection,
rare in a process with millions of long-lived objects. A single draw whose run is estimated above
:data:`RUN_MEMORY_MB` never reaches a Runner: the strategy refuses it before the run and counts it
(:func:`amcp_properties.strategies.closed_loop_cases`).

The formulation of (20): the backend's default (the plain form (15)) for problems of up to
:data:`~amcp_properties.strategies.SMALL_N` states; above, the one ``--formulation auto`` chooses, as campaigns over
larger state dimensions do (``formulation="auto"``, :data:`amcp_drake.studies.campaign.LARGE_FORMULATION`).
"""

from __future__ import annotations

import gc
from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from amcp_drake.model.errors import InconsistentDataError
from amcp_drake.model.limits import DEFAULT_MAX_MEMORY_MB, estimate_for
from amcp_drake.online import run_size
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate
from amcp_drake.studies.campaign import LARGE_FORMULATION
from amcp_drake.studies.random_problems import RandomCase

#: Trajectories and controllers kept in memory by a Runner (a trajectory of 20-80 steps with its
#: multipliers is 0.1-2 MB at n <= 3, up to 100 MB at n = 5; the ci profile needs about 2 x max_examples
#: of them at a time).
RUN_CACHE_SIZE = 96
CONTROLLER_CACHE_SIZE = 32
#: Most bytes of recorded trajectories a Runner keeps (:func:`trajectory_bytes`); the least recently
#: used are dropped beyond it.
RUN_CACHE_BYTES = 512 * 2**20
#: Most estimated bytes of the controllers a Runner keeps (:func:`controller_bytes`).
CONTROLLER_CACHE_BYTES = 2048 * 2**20
#: Per-run memory bound of the property suite, MiB: a drawn case whose run (tube QP and recorded
#: trajectory, :func:`amcp_drake.model.limits.check_run_size` with its design) is estimated above it is
#: refused before the run and counted; the default limit of ``amcp certify`` (measured: a cvxpy
#: plain-form run of n = 5 with a 47-facet, 301-vertex X0, estimated at 2064 MiB, took 1.1 GB and
#: 156 s of CPU; at 1024 MiB half the n = 5 cases of a thorough run were refused).
RUN_MEMORY_MB = DEFAULT_MAX_MEMORY_MB
#: Problems with more states than this run with :data:`LARGE_FORMULATION` (the ci profile draws up to 3).
PLAIN_MAX_N = 3


#: One closed-loop experiment: the library's case type (the numpy generator builds it for campaigns,
#: the Hypothesis strategies for the property suite).
Case = RandomCase


def formulation_options(case: Case) -> dict[str, str]:
    """The controller's formulation option for ``case`` (module docstring): none up to
    :data:`PLAIN_MAX_N` states (the backend's plain form), ``formulation=LARGE_FORMULATION`` above."""
    return {} if case.problem.n <= PLAIN_MAX_N else {"formulation": LARGE_FORMULATION}


def run_formulation(problem, design, options) -> str:
    """The form of (20) a case of ``problem`` runs in ("plain", or what ``auto`` resolves to with its
    design above :data:`PLAIN_MAX_N` states): the form its size is estimated for."""
    if problem.n <= PLAIN_MAX_N:
        return "plain"
    return run_size.run_formulation(LARGE_FORMULATION, problem, design, options)


def controller_for(case: Case, backend: str) -> AdaptiveMPC:
    """A new controller of ``case`` on ``backend`` in the case's formulation."""
    return AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options, **formulation_options(case))


def run(case: Case, backend: str, controller: AdaptiveMPC | None = None) -> Trajectory:
    """Simulate ``case`` on ``backend`` (no cache). Θ_{k-1} ∩ Δ_k = ∅ ends the run: the partial
    trajectory is returned with ``stop_reason`` saying so (the claims then fail on it)."""
    ctrl = controller or controller_for(case, backend)
    try:
        return simulate(ctrl, case.x0, case.theta_star, case.steps, disturbance=case.w, seed=case.seed)
    except InconsistentDataError as exc:
        return exc.trajectory


def trajectory_bytes(traj: Trajectory) -> int:
    """Bytes of the numpy arrays a trajectory holds (states, inputs, disturbances and every record's)."""
    total = sum(np.asarray(a).nbytes for a in (traj.x, traj.u, traj.w))
    for record in traj.records:
        total += sum(v.nbytes for v in vars(record).values() if isinstance(v, np.ndarray))
    return total


def controller_bytes(case: Case) -> int:
    """Estimated bytes of a controller of ``case``: the tube QP of :func:`~amcp_drake.model.limits.estimate_for`
    with the case's design (one step: nothing recorded yet)."""
    return estimate_for(case.problem, case.spec.design, 1, case.options, design=case.design,
                        formulation=run_formulation(case.problem, case.design, case.options)).memory_bytes


class Memo:
    """key -> value computed once, the least recently used dropped beyond ``size`` entries or beyond
    ``max_bytes`` in total (each value weighed by ``weigh``; a value heavier than ``max_bytes`` is
    returned but not kept); ``hits`` and ``misses`` count the look-ups (the run counts printed at the
    end of the property run), ``evicted`` the values dropped. ``on_evict`` is called after values were
    dropped."""

    def __init__(self, size: int, max_bytes: int | None = None, weigh: Callable[[Any], int] | None = None,
                 on_evict: Callable[[], None] | None = None) -> None:
        self._items: OrderedDict[Hashable, Any] = OrderedDict()
        self._weights: dict[Hashable, int] = {}
        self._size = size
        self._max_bytes = max_bytes
        self._weigh = weigh
        self._on_evict = on_evict
        self.hits = self.misses = self.evicted = 0

    @property
    def nbytes(self) -> int:
        """Total weight of the values kept (0 without ``weigh``)."""
        return sum(self._weights.values())

    def __len__(self) -> int:
        return len(self._items)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._items

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        if key in self._items:
            self.hits += 1
            self._items.move_to_end(key)
            return self._items[key]
        self.misses += 1
        value = compute()
        self.put(key, value)
        return value

    def put(self, key: Hashable, value: Any, weight: int | None = None) -> None:
        """Keep ``value`` under ``key`` (weighed by ``weigh`` unless ``weight`` is given), then drop
        the least recently used values beyond the limits."""
        self._items[key] = value
        self._items.move_to_end(key)
        if weight is None:
            weight = self._weigh(value) if self._weigh is not None else 0
        self._weights[key] = int(weight)
        dropped = 0
        while self._items and (len(self._items) > self._size
                               or (self._max_bytes is not None and self.nbytes > self._max_bytes)):
            old = self._items.popitem(last=False)[0]  # (the value is not bound: on_evict can free it)
            del self._weights[old]
            dropped += 1
        self.evicted += dropped
        if dropped and self._on_evict is not None:
            self._on_evict()


class Runner(Memo):
    """Memoised :func:`run`: (case, backend) -> Trajectory, controllers reused via ``reset()``; both
    caches bounded by entries and bytes (module docstring)."""

    def __init__(self, size: int = RUN_CACHE_SIZE, controllers: int = CONTROLLER_CACHE_SIZE,
                 max_bytes: int = RUN_CACHE_BYTES, controller_bytes_max: int = CONTROLLER_CACHE_BYTES) -> None:
        super().__init__(size, max_bytes, trajectory_bytes)
        self._controllers = Memo(controllers, controller_bytes_max, on_evict=gc.collect)

    @property
    def controllers(self) -> Memo:
        """The controller cache (its ``nbytes`` is the estimate of the controllers kept)."""
        return self._controllers

    def controller(self, case: Case, backend: str) -> AdaptiveMPC:
        key = (case.design_key(), backend, (case.options.update, case.options.window, case.options.projection))
        if key in self._controllers:
            return self._controllers.get(key, lambda: None)
        self._controllers.misses += 1
        ctrl = controller_for(case, backend)
        self._controllers.put(key, ctrl, controller_bytes(case))
        return ctrl

    def run(self, case: Case, backend: str) -> Trajectory:
        return self.get((case.key(), backend), lambda: run(case, backend, self.controller(case, backend)))
