"""A measured run: the Trajectory of a user's own loop around :meth:`AdaptiveMPC.step`.

A plant other than amcp's simulator of (1) (a Drake plant, another simulator, hardware) gives the
controller x_k and applies u_k; θ* and the disturbances w_k stay unknown. The loop keeps the step
records, and :func:`measured_trajectory` turns them into a :class:`~amcp_drake.online.simulate.Trajectory`
with ``theta_star`` and ``w`` None, which ``amcp.certify`` and ``amcp certify --trajectory`` check
(docs/how-to/certify-measured-run.md)::

    ctrl = amcp.AdaptiveMPC(problem, offline)
    records = []
    x = measure()
    for k in range(steps):
        u, record = ctrl.step(x, on_inconsistent="record")
        records.append(record)
        if u is None:                 # the QP (20) had no answer, or Θ_{k−1} ∩ Δ_k = ∅: stop
            break
        x = apply_and_measure(u)
    else:
        records.append(ctrl.step(x, on_inconsistent="record")[1])   # Θ_T, θ̂_T at the last state
    traj = amcp.measured_trajectory(ctrl, records)

The records must be those of one run from ``ctrl.reset()`` (k = 0, 1, ... in order), every one but
the last with an applied input. The last record may have an input (computed, not applied: no state
after it was measured) or none (the step failed, or recorded inconsistent data).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from amcp_drake.model.errors import ProblemError
from amcp_drake.online.controller import AdaptiveMPC, StepRecord, is_inconsistent
from amcp_drake.online.simulate import Trajectory, formulation_meta

#: ``meta["simulator"]`` of a trajectory built from a user's loop (the plant that ran is not amcp's).
USER_LOOP = "user_loop"


def measured_trajectory(controller: AdaptiveMPC, records: Sequence[StepRecord], *,
                        meta: dict[str, Any] | None = None) -> Trajectory:
    """The measured-run Trajectory of ``records`` (module docstring): x_k from the records, u_k the
    applied inputs, ``theta_star`` and ``w`` None, the controller's problem, design, options and backend.

    ``stop_reason`` is ``"completed"`` when the last record solved, ``"inconsistent data at step K"``
    when it recorded Θ_{K−1} ∩ Δ_K = ∅, ``"step K: status S"`` otherwise. ``meta`` is added to the
    trajectory's meta (default ``{"simulator": "user_loop"}``). ProblemError names the first record
    that does not fit (numbering, a missing input before the last record, a state of the wrong shape).
    """
    records = list(records)
    if not records:
        raise ProblemError("records", "at least one step record of controller.step", "an empty list")
    problem = controller.problem
    for i, r in enumerate(records):
        if not isinstance(r, StepRecord):
            raise ProblemError(f"records[{i}]", "a StepRecord returned by controller.step", type(r).__name__)
        if r.k != i:
            raise ProblemError(f"records[{i}].k", f"{i} (the records of one run from controller.reset(), in order)",
                               repr(r.k))
        if np.shape(r.x) != (problem.n,):
            raise ProblemError(f"records[{i}].x", f"a state of length {problem.n}", f"shape {np.shape(r.x)}")
        if i < len(records) - 1 and r.u is None:
            raise ProblemError(f"records[{i}].u", "an applied input (only the last record may have none: the loop "
                               "stops at a step without an input)", "None")
    last = records[-1]
    T = len(records) - 1
    if is_inconsistent(last):
        stop = f"inconsistent data at step {T}"
    elif last.u is None:
        stop = f"step {T}: status {last.status.value}"
    else:
        stop = "completed"
    x = np.array([np.asarray(r.x, float) for r in records])
    u = np.array([np.asarray(r.u, float) for r in records[:-1]]).reshape(-1, problem.m)
    info = {"simulator": USER_LOOP, **formulation_meta(controller)}
    return Trajectory(problem=problem, design=controller.design, options=controller.options,
                      backend=controller.backend.name, theta_star=None, x=x, u=u, w=None, records=records,
                      stop_reason=stop, mu_state_bound=controller.design.mu_state_bound,
                      meta={**info, **(meta or {})})


__all__ = ["USER_LOOP", "measured_trajectory"]
