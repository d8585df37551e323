"""A closed-loop experiment (:class:`Case`) and how to run it on a backend (:class:`Runner`).

A case (:class:`amcp_drake.studies.random_problems.RandomCase`) is fully explicit (problem, design, x0, θ*, the whole disturbance array, online
options), so a run is a deterministic function of (case, backend); :class:`Runner` memoises runs
and controllers by content hash, which lets every property of the ci profile check its claim
on the same runs without re-simulating them.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

from amcp_drake.model.errors import InconsistentDataError
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate
from amcp_drake.studies.random_problems import RandomCase

#: Trajectories and controllers kept in memory by a Runner (a trajectory of 20-80 steps with its
#: multipliers is 0.1-2 MB; the ci profile needs about 2 x max_examples of them at a time).
RUN_CACHE_SIZE = 96
CONTROLLER_CACHE_SIZE = 32


#: One closed-loop experiment: the library's case type (the numpy generator builds it for campaigns,
#: the Hypothesis strategies for the property suite).
Case = RandomCase


def run(case: Case, backend: str, controller: AdaptiveMPC | None = None) -> Trajectory:
    """Simulate ``case`` on ``backend`` (no cache). Θ_{k-1} ∩ Δ_k = ∅ ends the run: the partial
    trajectory is returned with ``stop_reason`` saying so (the claims then fail on it)."""
    ctrl = controller or AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options)
    try:
        return simulate(ctrl, case.x0, case.theta_star, case.steps, disturbance=case.w, seed=case.seed)
    except InconsistentDataError as exc:
        return exc.trajectory


class Memo:
    """key -> value computed once, the least recently used dropped beyond ``size`` entries; ``hits``
    and ``misses`` count the look-ups (the run counts printed at the end of the property run)."""

    def __init__(self, size: int) -> None:
        self._items: OrderedDict[Hashable, Any] = OrderedDict()
        self._size = size
        self.hits = self.misses = 0

    def get(self, key: Hashable, compute: Callable[[], Any]) -> Any:
        if key in self._items:
            self.hits += 1
            self._items.move_to_end(key)
            return self._items[key]
        self.misses += 1
        value = self._items[key] = compute()
        if len(self._items) > self._size:
            self._items.popitem(last=False)
        return value


class Runner(Memo):
    """Memoised :func:`run`: (case, backend) -> Trajectory, controllers reused via ``reset()``."""

    def __init__(self, size: int = RUN_CACHE_SIZE, controllers: int = CONTROLLER_CACHE_SIZE) -> None:
        super().__init__(size)
        self._controllers = Memo(controllers)

    def controller(self, case: Case, backend: str) -> AdaptiveMPC:
        key = (case.design_key(), backend, (case.options.update, case.options.window, case.options.projection))
        return self._controllers.get(key, lambda: AdaptiveMPC(case.problem, case.design, backend=backend,
                                                              options=case.options))

    def run(self, case: Case, backend: str) -> Trajectory:
        return self.get((case.key(), backend), lambda: run(case, backend, self.controller(case, backend)))
