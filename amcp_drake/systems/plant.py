"""The true system (1) as Drake Systems: :func:`drake_plant` x⁺ = A(θ*)x + B(θ*)u + w, with the disturbance
on an input port of its own, and :class:`RecordedDisturbance`, a source of a recorded sequence w_0, w_1, ...
(docs/how-to/drake-plant.md)."""

from __future__ import annotations

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import AffineSystem, Multiplexer

from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError
from amcp_drake.model.problem import Problem
from amcp_drake.systems.controller_system import DEFAULT_PERIOD

#: θ* may lie outside Θ by this much (the tolerance of amcp.simulate's check of Assumption 1).
THETA_STAR_TOL = 1e-9


def _period(period) -> float:
    period = DEFAULT_PERIOD if period is None else period
    if isinstance(period, bool) or not isinstance(period, (int, float, np.floating)) or not np.isfinite(period) \
            or period <= 0:
        raise ProblemError("period", "a finite sample period > 0 (seconds per step)", repr(period))
    return float(period)


def drake_plant(problem: Problem, theta_star, period: float | None = None):
    """x_{k+1} = A(θ*) x_k + B(θ*) u_k + w_k of (1)-(2) as a Drake Diagram: a discrete ``AffineSystem``
    with input ports ``u`` (m) and ``w`` (n, the disturbance) and the
    output port ``x`` (n, the state, no feedthrough); ``period`` defaults to the problem's sample time
    ``Problem.dt``, else 1.0. Set its initial state with
    ``plant.GetMyMutableContextFromRoot(root_context).SetDiscreteState(x0)``.

    ``theta_star``: the true parameter θ* (p,), a point of Θ (ProblemError otherwise)."""
    theta = np.asarray(theta_star, float)
    if theta.shape != (problem.p,) or not np.all(np.isfinite(theta)):
        raise ProblemError("theta_star", f"a finite vector of length {problem.p} (a constant θ*: the Drake "
                           "plant is time-invariant)", f"shape {theta.shape}")
    if polytope.max_violation(problem.H_theta, problem.h_theta, theta) > THETA_STAR_TOL:
        raise ProblemError("theta_star", "a point of Theta (Assumption 1)", f"{theta.tolist()}")
    n, m = problem.n, problem.m
    affine = AffineSystem(A=problem.A_of(theta), B=np.hstack([problem.B_of(theta), np.eye(n)]), f0=np.zeros(n),
                          C=np.eye(n), D=np.zeros((n, m + n)), y0=np.zeros(n),
                          time_period=_period(getattr(problem, "dt", None) if period is None else period))
    builder = DiagramBuilder()
    builder.AddNamedSystem("affine", affine)
    mux = builder.AddNamedSystem("inputs", Multiplexer([m, n]))
    builder.Connect(mux.get_output_port(0), affine.get_input_port())
    builder.ExportInput(mux.get_input_port(0), "u")
    builder.ExportInput(mux.get_input_port(1), "w")
    builder.ExportOutput(affine.get_output_port(), "x")
    plant = builder.Build()
    plant.set_name(f"{problem.name or 'problem'} plant")
    return plant


class RecordedDisturbance(LeafSystem):
    """A recorded disturbance sequence as a Drake source: output ``w`` (n) is w_k on [t_k, t_{k+1}),
    t_k = k·period, and zero after the sequence (past the run it was recorded for)."""

    def __init__(self, w, period: float | None = None) -> None:
        LeafSystem.__init__(self)
        W = np.asarray(w, float)
        if W.ndim != 2 or W.shape[0] < 1 or not np.all(np.isfinite(W)):
            raise ProblemError("w", "a finite (steps, n) array of disturbances", f"shape {W.shape}")
        self.w = W.copy()
        self.w.setflags(write=False)
        self.period = _period(period)
        self.DeclareVectorOutputPort("w", W.shape[1], self._calc)

    def index_at(self, t: float) -> int:
        """k with t in [t_k, t_{k+1}) (t_k computed by the Simulator as k·period, met to round-off)."""
        return int(np.floor(t / self.period + 1e-9))

    def _calc(self, context, output) -> None:
        k = self.index_at(context.get_time())
        output.SetFromVector(self.w[k] if 0 <= k < len(self.w) else np.zeros(self.w.shape[1]))


__all__ = ["RecordedDisturbance", "THETA_STAR_TOL", "drake_plant"]
