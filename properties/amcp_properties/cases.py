"""A closed-loop experiment (:class:`Case`) and how to run it on a backend (:class:`Runner`).

A case is fully explicit (problem, design, x0, θ*, the whole disturbance array, online
options), so a run is a deterministic function of (case, backend); :class:`Runner` memoises runs
and controllers by content hash, which lets every property of the ci profile check its claim
on the same runs without re-simulating them.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from amcp_drake.model.errors import InconsistentDataError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import Problem, ProblemSpec, Scenario
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate

#: Trajectories and controllers kept in memory by a Runner (a trajectory of 20-80 steps with its
#: multipliers is 0.1-2 MB; the ci profile needs about 2 x max_examples of them at a time).
RUN_CACHE_SIZE = 96
CONTROLLER_CACHE_SIZE = 32


@dataclass(frozen=True, eq=False)
class Case:
    """One closed-loop experiment. ``w`` (T, n) is the whole disturbance sequence (T steps);
    ``zero_from`` is the step from which w = 0 (None: never forced); ``seed`` generated ``w``;
    ``ray_length`` is the distance from 0 to the feasible-set boundary along x0's direction."""

    spec: ProblemSpec
    design: OfflineDesign
    x0: np.ndarray
    theta_star: np.ndarray
    w: np.ndarray
    options: OnlineOptions
    labels: dict = field(default_factory=dict)
    seed: int = 0
    zero_from: int | None = None
    ray_length: float = float("nan")

    @property
    def problem(self) -> Problem:
        return self.spec.problem

    @property
    def steps(self) -> int:
        return len(self.w)

    def design_key(self) -> str:
        """Hash of the problem and its design (identifies a controller)."""
        h = hashlib.sha1()
        for name in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "Q", "R", "theta_hat0"):
            h.update(np.ascontiguousarray(getattr(self.problem, name)).tobytes())
        h.update(str(self.problem.N).encode())
        for name in ("K", "P", "H_x", "H_T", "h_T", "H_theta", "h_theta0"):
            h.update(np.ascontiguousarray(getattr(self.design, name)).tobytes())
        h.update(repr(self.design.mu).encode())
        return h.hexdigest()

    def key(self) -> str:
        """Hash of everything that determines a run."""
        h = hashlib.sha1(self.design_key().encode())
        for arr in (self.x0, self.theta_star, self.w):
            h.update(np.ascontiguousarray(arr, float).tobytes())
        h.update(repr((self.options.update, self.options.window, self.options.projection)).encode())
        return h.hexdigest()

    def to_spec(self) -> ProblemSpec:
        """The problem file of this case (its scenario names the disturbance kind and seed; the
        exact disturbance array is in the trajectory file written next to it)."""
        kind = self.labels.get("disturbance", "uniform")
        scenario = Scenario(x0=self.x0, theta_star=self.theta_star, steps=self.steps,
                            disturbance=kind if kind in ("uniform", "vertices", "zero") else "uniform",
                            seed=int(self.seed) % (2**31))
        return ProblemSpec(self.problem, self.spec.design, scenario)


def run(case: Case, backend: str, controller: AdaptiveMPC | None = None) -> Trajectory:
    """Simulate ``case`` on ``backend`` (no cache). Θ_{k-1} ∩ Δ_k = ∅ ends the run: the partial
    trajectory is returned with ``stop_reason`` saying so (the claims then fail on it)."""
    ctrl = controller or AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options)
    try:
        return simulate(ctrl, case.x0, case.theta_star, case.steps, disturbance=case.w, seed=case.seed)
    except InconsistentDataError as exc:
        return exc.trajectory


class Runner:
    """Memoised :func:`run`: (case, backend) -> Trajectory, controllers reused via ``reset()``."""

    def __init__(self, size: int = RUN_CACHE_SIZE, controllers: int = CONTROLLER_CACHE_SIZE) -> None:
        self._runs: OrderedDict[tuple[str, str], Trajectory] = OrderedDict()
        self._controllers: OrderedDict[tuple[str, str, tuple], AdaptiveMPC] = OrderedDict()
        self._size, self._csize = size, controllers
        self.hits = 0
        self.misses = 0

    def controller(self, case: Case, backend: str) -> AdaptiveMPC:
        key = (case.design_key(), backend, (case.options.update, case.options.window, case.options.projection))
        if key not in self._controllers:
            self._controllers[key] = AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options)
            if len(self._controllers) > self._csize:
                self._controllers.popitem(last=False)
        self._controllers.move_to_end(key)
        return self._controllers[key]

    def run(self, case: Case, backend: str) -> Trajectory:
        key = (case.key(), backend)
        if key in self._runs:
            self.hits += 1
            self._runs.move_to_end(key)
            return self._runs[key]
        self.misses += 1
        traj = run(case, backend, self.controller(case, backend))
        self._runs[key] = traj
        if len(self._runs) > self._size:
            self._runs.popitem(last=False)
        return traj
