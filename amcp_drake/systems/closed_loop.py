"""The closed loop plant + controller + disturbance as a Drake Diagram run by Drake's Simulator, and
:func:`simulate_in_drake`, the Drake counterpart of :func:`amcp_drake.online.simulate.simulate` (same
arguments, same Trajectory; ``amcp run|certify|compare --simulator drake``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import LogVectorOutput

from amcp_drake.model.errors import InconsistentDataError, ProblemError
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, disturbance_sequence, formulation_meta
from amcp_drake.systems.controller_system import AdaptiveMPCSystem
from amcp_drake.systems.plant import RecordedDisturbance, drake_plant


@dataclass
class ClosedLoop:
    """The parts of :func:`closed_loop`: the Diagram, its systems and Drake loggers of x and u (one sample
    per period, at the sample times)."""

    diagram: Any
    controller: AdaptiveMPCSystem
    plant: Any
    disturbance: Any
    x_log: Any
    u_log: Any


def _check_size(port, expected: int, what: str, source) -> None:
    if port.size() != expected:
        raise ProblemError(what, f"a vector port of size {expected}",
                           f"port '{source.get_name()}' of '{source.get_system().get_name()}' of size {port.size()}")


def closed_loop(controller: AdaptiveMPCSystem, plant, disturbance=None) -> ClosedLoop:
    """A Diagram of ``plant`` (input ports ``u``, ``w`` or ``u`` only; output port ``x``, e.g.
    :func:`~amcp_drake.systems.plant.drake_plant`), ``controller`` and ``disturbance`` (a source whose first
    output feeds the plant's ``w``; None only for a plant without ``w``). Port sizes are checked before
    wiring: ProblemError names the port and the size it received. Loggers sample x and u at the
    controller's period."""
    builder = DiagramBuilder()
    builder.AddSystem(plant)
    builder.AddSystem(controller)
    x_out = plant.GetOutputPort("x") if plant.HasOutputPort("x") else plant.get_output_port(0)
    _check_size(x_out, controller.n, "input port 'x' of AdaptiveMPCSystem", x_out)
    u_in = plant.GetInputPort("u") if plant.HasInputPort("u") else plant.get_input_port(0)
    _check_size(u_in, controller.m, f"input port '{u_in.get_name()}' of '{plant.get_name()}'",
                controller.get_u_output_port())
    builder.Connect(x_out, controller.get_x_input_port())
    builder.Connect(controller.get_u_output_port(), u_in)
    if plant.HasInputPort("w"):
        if disturbance is None:
            raise ProblemError("disturbance", f"a source for the input port 'w' of '{plant.get_name()}'", "None")
        builder.AddSystem(disturbance)
        w_out = disturbance.get_output_port(0)
        w_in = plant.GetInputPort("w")
        _check_size(w_out, w_in.size(), f"input port 'w' of '{plant.get_name()}'", w_out)
        builder.Connect(w_out, w_in)
    x_log = LogVectorOutput(x_out, builder, controller.period)
    u_log = LogVectorOutput(controller.get_u_output_port(), builder, controller.period)
    return ClosedLoop(builder.Build(), controller, plant, disturbance, x_log, u_log)


def simulate_in_drake(controller: AdaptiveMPC, x0, theta_star, steps: int, disturbance: str | np.ndarray = "uniform",
                      seed: int = 0, progress: bool = False, mu_state_bound: float | None = None,
                      period: float | None = None) -> Trajectory:
    """:func:`~amcp_drake.online.simulate.simulate` with the plant in Drake: :func:`drake_plant` of θ*, the
    disturbances w_k (``disturbance``, ``seed`` as there) from a :class:`RecordedDisturbance`, and an
    :class:`AdaptiveMPCSystem` around ``controller``, run by Drake's Simulator to t = steps·period. The
    Trajectory records ``meta["simulator"] = "drake"``; the closed loop is the one of ``simulate`` (u_k
    computed from x_k and applied at once), up to the round-off of Drake's affine update. InconsistentDataError
    (Θ_{k−1} ∩ Δ_k empty) carries the partial trajectory as ``exc.trajectory``, as in ``simulate``.
    ``progress`` is accepted for the same signature (no progress bar)."""
    problem = controller.problem
    x = np.asarray(x0, float)
    if x.shape != (problem.n,) or not np.all(np.isfinite(x)):
        raise ProblemError("x0", f"a finite vector of length {problem.n}", f"{np.asarray(x0)!r}")
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ProblemError("steps", "an integer >= 1", repr(steps))
    theta = np.asarray(theta_star, float)
    if theta.ndim == 2 and len(theta) and np.all(theta == theta[0]):
        theta = theta[0]
    W = disturbance_sequence(problem, disturbance, steps, seed)
    system = AdaptiveMPCSystem(controller=controller, period=period)
    loop = closed_loop(system, drake_plant(problem, theta, system.period), RecordedDisturbance(W, system.period))
    simulator = Simulator(loop.diagram)
    root = simulator.get_mutable_context()
    loop.plant.GetMyMutableContextFromRoot(root).SetDiscreteState(x)
    simulator.Initialize()
    simulator.AdvanceTo(steps * system.period)
    if mu_state_bound is None:
        mu_state_bound = getattr(controller.design, "mu_state_bound", None)
    meta = {"disturbance": disturbance if isinstance(disturbance, str) else "array", "seed": seed,
            **formulation_meta(controller)}
    traj = system.trajectory(root, theta_star=theta, w=W, meta=meta)
    traj.mu_state_bound = mu_state_bound
    if traj.stop_reason.startswith("inconsistent data"):
        exc = InconsistentDataError(traj.steps, "recorded by AdaptiveMPCSystem in the last step record")
        exc.trajectory = traj
        raise exc
    return traj


__all__ = ["ClosedLoop", "closed_loop", "simulate_in_drake"]
