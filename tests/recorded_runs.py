"""Recorded runs shared by the certificate tests: a closed-loop run of Example 1 as the JSON dict of its
trajectory file, independent copies of it, and the recorded campaign trajectory of tests/data."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

#: A recorded 15-step campaign trajectory.
TRAJECTORY_DATA = Path(__file__).parent / "data" / "campaign-0-126-trajectory.json.gz"


def trajectory() -> dict:
    """The recorded campaign trajectory (:data:`TRAJECTORY_DATA`) as a dict."""
    with gzip.open(TRAJECTORY_DATA, "rt") as handle:
        return json.load(handle)


def as_recorded(traj) -> dict:
    """A Trajectory as the JSON dict of its trajectory file."""
    return json.loads(json.dumps(traj.to_dict()))


def fresh(recorded: dict):
    """An independent Trajectory copy of a recorded one (through its file format)."""
    from amcp_drake.online.simulate import Trajectory

    return Trajectory.from_dict(json.loads(json.dumps(recorded)))


def example_1_recorded(spec, controller, steps: int) -> dict:
    """A ``steps``-step run of Example 1 (``spec``'s scenario, uniform disturbance, seed 0) with
    ``controller``, as the JSON dict of its trajectory file; it must complete."""
    from amcp_drake.online.simulate import simulate

    sc = spec.scenario
    traj = simulate(controller, sc.x0, sc.theta_star, steps, "uniform", seed=0,
                    mu_state_bound=spec.design.mu_state_bound)
    assert traj.stop_reason == "completed" and len(traj.records) == steps + 1
    return as_recorded(traj)
