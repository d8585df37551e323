"""The adaptive MPC as a Drake System: :class:`AdaptiveMPCSystem`, a ``LeafSystem`` to wire next to a
Drake plant in a ``Diagram`` (docs/how-to/drake-plant.md, docs/reference/drake-system.md).

Ports: input ``x`` (n), the measured state x_k; output ``u`` (m), the input u_k of (21).
State: one abstract state, a :class:`ControllerRun` — the controller's :class:`~amcp_drake.online.state.
ControllerState` (Θ_k, θ̂_k, the previous x and u, k, ...), the input held on the output, the step records
of the run and, once the run has stopped, why. Nothing that changes is kept in Python attributes: two
contexts of one system are two independent runs, and a fresh context starts a fresh run.

Timing: a periodic unrestricted update at t_k = k·period steps the controller at x(t_k) (the value on the
input port then) and stores u_k; the output ``u`` is a zero-order hold of that u_k on [t_k, t_{k+1}).
Drake's Simulator applies unrestricted updates before discrete updates at the same time, and a
discrete plant's update at t_k reads the ``u`` just stored: x_{k+1} = f(x_k, u_k), the convention of
:func:`amcp_drake.online.simulate.simulate` (u_k computed from x_k and applied at once). The plant must
therefore update by a discrete (or continuous) update, as Drake's ``LinearSystem``, ``AffineSystem`` and
a discrete ``MultibodyPlant`` do. One controller step per period; the output costs no solve.

A step without an input (the QP (20) not solved, or Θ_{k−1} ∩ Δ_k = ∅ recorded as the data contradicting
Θ and W) ends the run: the event is recorded, the output holds the last applied input, and the update
returns Drake's "reached termination", so ``Simulator.AdvanceTo`` returns early with that message and the
partial run stays certifiable (:meth:`AdaptiveMPCSystem.trajectory`). With ``on_inconsistent="reset"`` the
run goes on instead after an empty Θ_{k−1} ∩ Δ_k: the step is taken again from Θ_k = Θ (the declared set,
Θ_0), θ̂_{k−1} kept and the contradicting transition dropped (no Δ_k at this step); the steps at which this
happened are in ``ControllerRun.resets`` and the trajectory's ``meta["theta_resets"]``. The certificate then
reports ``data_consistency`` failing at the first of them (docs/decisions.md, "Inconsistent data in a Diagram").
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from pydrake.common.value import Value
from pydrake.systems.framework import EventStatus, LeafSystem

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import Problem
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online.controller import AdaptiveMPC, StepRecord, is_inconsistent
from amcp_drake.online.measured import measured_trajectory
from amcp_drake.online.simulate import Trajectory
from amcp_drake.online.state import ControllerState, frozen_array

#: The period of the update when neither the call nor the problem (``Problem.dt``) gives one: the model (1)
#: then counts steps, not seconds.
DEFAULT_PERIOD = 1.0
#: ``meta["simulator"]`` of a trajectory whose plant ran in a Drake Diagram.
DRAKE_SIMULATOR = "drake"
#: What :class:`AdaptiveMPCSystem` does when Θ_{k−1} ∩ Δ_k is empty: "stop" the run (default) or "reset"
#: Θ_k to Θ and go on (module docstring).
ON_INCONSISTENT = ("stop", "reset")


@dataclass(frozen=True)
class ControllerRun:
    """The abstract state of :class:`AdaptiveMPCSystem` (immutable).

    ``state``: the controller's state before the next step; ``u``: the input held on the output port (zeros
    before the first step); ``records``: the step records so far, as a chain (newest, older chain) so that a
    step adds one link without copying the run; ``stopped``: why the run ended ("" while it goes on);
    ``resets``: the steps at which Θ_{k−1} ∩ Δ_k was empty and Θ_k was reset to Θ (``on_inconsistent="reset"``)."""

    state: ControllerState
    u: np.ndarray
    records: tuple | None = None
    stopped: str = ""
    resets: tuple[int, ...] = ()

    def __deepcopy__(self, memo) -> ControllerRun:
        # Drake clones abstract state values (pydrake: copy.deepcopy) when it copies a context or makes an
        # update's scratch state; the value is immutable, so the clone is the value itself (no O(k) copy)
        return self

    def record_list(self) -> list[StepRecord]:
        """The step records of the run, oldest first."""
        out, link = [], self.records
        while link is not None:
            out.append(link[0])
            link = link[1]
        return out[::-1]

    @property
    def steps(self) -> int:
        """The number of step records."""
        n, link = 0, self.records
        while link is not None:
            n, link = n + 1, link[1]
        return n


class AdaptiveMPCSystem(LeafSystem):
    """The adaptive robust MPC of Lorenzen et al. (2019) as a Drake ``LeafSystem`` (module docstring).

    ``problem``, ``design``, ``options``, ``backend`` and ``backend_options`` as for
    :class:`~amcp_drake.online.controller.AdaptiveMPC`, which is built once here (its programs are built
    once and updated in place at every step). ``period``: the sample period of the update (default: the
    problem's sample time ``Problem.dt``, else :data:`DEFAULT_PERIOD`). ``controller``: an AdaptiveMPC to use
    instead of building one (``problem``, ``design``, ``options``, ``backend`` are then taken from it).
    ``on_inconsistent``: "stop" (default) ends the run when Θ_{k−1} ∩ Δ_k is empty; "reset" goes on from
    Θ_k = Θ (module docstring).
    """

    def __init__(self, problem: Problem | None = None, design: OfflineDesign | None = None,
                 options: OnlineOptions | None = None, backend: str = "drake", *, period: float | None = None,
                 controller: AdaptiveMPC | None = None, on_inconsistent: str = "stop",
                 **backend_options: Any) -> None:
        LeafSystem.__init__(self)
        if on_inconsistent not in ON_INCONSISTENT:
            raise ProblemError("on_inconsistent", " or ".join(repr(o) for o in ON_INCONSISTENT), repr(on_inconsistent))
        self.on_inconsistent = on_inconsistent
        if controller is None:
            if problem is None or design is None:
                raise ProblemError("AdaptiveMPCSystem", "a problem and its design (or controller=AdaptiveMPC)",
                                   "problem=None" if problem is None else "design=None")
            controller = AdaptiveMPC(problem, design, backend, options, **backend_options)
        if period is None:
            dt = getattr(controller.problem, "dt", None)
            period = DEFAULT_PERIOD if dt is None else dt
        if (isinstance(period, bool) or not isinstance(period, (int, float, np.floating))
                or not np.isfinite(period) or period <= 0):
            raise ProblemError("period", "a finite sample period > 0 (seconds per step)", repr(period))
        self.controller = controller
        self.period = float(period)
        pr = controller.problem
        self.n, self.m = pr.n, pr.m
        initial = ControllerRun(state=controller.initial_state(), u=frozen_array(np.zeros(pr.m)))
        self._x_port = self.DeclareVectorInputPort("x", pr.n)
        self._run_index = self.DeclareAbstractState(Value[object](initial))
        self.DeclarePeriodicUnrestrictedUpdateEvent(self.period, 0.0, self._update)
        self._u_port = self.DeclareVectorOutputPort(
            "u", pr.m, self._calc_u, prerequisites_of_calc={self.abstract_state_ticket(self._run_index)})

    # -- ports and state ---------------------------------------------------------------------------
    def get_x_input_port(self):
        """The input port ``x`` (n): the measured state."""
        return self._x_port

    def get_u_output_port(self):
        """The output port ``u`` (m): the input u_k, held from t_k to t_{k+1}."""
        return self._u_port

    def run(self, context) -> ControllerRun:
        """The run held in ``context`` (this system's context, or a Diagram's root context)."""
        return self._own(context).get_abstract_state(self._run_index).get_value()

    def controller_state(self, context) -> ControllerState:
        """The controller's state held in ``context`` (before the next step)."""
        return self.run(context).state

    def _own(self, context):
        try:
            return self.GetMyContextFromRoot(context)
        except (RuntimeError, ValueError):
            return context

    def measured_state(self, context) -> np.ndarray:
        """The value on the input port ``x``, checked: ProblemError naming the port when nothing is
        connected or the value is not a finite vector of length n."""
        port = f"input port 'x' of AdaptiveMPCSystem '{self.get_name()}'"
        if not self._x_port.HasValue(context):
            raise ProblemError(port, f"a connected state of length {self.n}", "nothing connected")
        x = np.asarray(self._x_port.Eval(context), float)
        if x.shape != (self.n,) or not np.all(np.isfinite(x)):
            raise ProblemError(port, f"a finite state vector of length {self.n}",
                               f"{x.tolist()!r} at t = {context.get_time():g}")
        return x

    # -- the update and the output ------------------------------------------------------------------
    def _update(self, context, state) -> EventStatus:
        run = context.get_abstract_state(self._run_index).get_value()
        if run.stopped:
            return EventStatus.ReachedTermination(self, run.stopped)
        x = self.measured_state(context)
        u, nxt, record, reset = self._step(run.state, x)
        resets = (*run.resets, record.k) if reset else run.resets
        chain = (record, run.records)
        if u is None:
            k = record.k
            why = (f"inconsistent data at step {k}" if is_inconsistent(record)
                   else f"step {k}: status {record.status.value}")
            state.get_mutable_abstract_state(self._run_index).set_value(
                replace(run, records=chain, stopped=why, resets=resets))
            return EventStatus.ReachedTermination(self, f"adaptive MPC stopped: {why}")
        state.get_mutable_abstract_state(self._run_index).set_value(
            ControllerRun(state=nxt, u=frozen_array(u), records=chain, resets=resets))
        return EventStatus.Succeeded()

    def _step(self, state: ControllerState, x: np.ndarray):
        """(u, next state, record, whether Θ_k was reset) of the controller's step at x from ``state``,
        with the recovery of ``on_inconsistent="reset"`` (module docstring)."""
        u, nxt, record = self.controller.step_from(state, x, on_inconsistent="record")
        if u is not None or self.on_inconsistent != "reset" or not is_inconsistent(record):
            return u, nxt, record, False
        u, nxt, record = self.controller.step_from(self._reset(state), x, on_inconsistent="record")
        record.detail = (f"Θ_(k−1) ∩ Δ_k empty at step {record.k}: Θ_k reset to Θ, the transition dropped"
                         + (f"; {record.detail}" if record.detail else ""))
        return u, nxt, record, True

    def _reset(self, state: ControllerState) -> ControllerState:
        """``state`` with Θ_k = Θ (the design's Θ_0) and no previous step (the contradicting transition is
        dropped, no Δ_k at the step taken from it), θ̂ kept (a point of Θ_{k−1} ⊆ Θ)."""
        initial = self.controller.initial_state()
        return state.replace(H_theta=initial.H_theta, h_theta=initial.h_theta, prev=None, window=(),
                             exact_rows_irredundant=False, checked_vertices=None)

    def _calc_u(self, context, output) -> None:
        output.SetFromVector(context.get_abstract_state(self._run_index).get_value().u)

    # -- the run as a Trajectory -----------------------------------------------------------------------
    def trajectory(self, context, *, theta_star=None, w=None, final_step: bool = True,
                   meta: dict[str, Any] | None = None) -> Trajectory:
        """The run held in ``context`` as a :class:`~amcp_drake.online.simulate.Trajectory` that
        ``amcp.certify`` reads. ``context``: this system's context or the Diagram's root context.

        ``final_step``: when the run has not stopped, the step at the state now on the input port x_T is
        computed (not applied, the context is not changed) and recorded last, as
        :func:`~amcp_drake.online.simulate.simulate` records Θ_T and θ̂_T at x_T. ``theta_star`` and
        ``w`` (the disturbances applied, at least one per applied input): when both are given, the
        trajectory is that of a known plant (every claim checked); when both are None, a measured run
        (θ* and w unknown). ``meta`` is added to the trajectory's meta; ``meta["simulator"]`` is "drake".
        """
        own = self._own(context)
        run = self.run(context)
        records, resets = run.record_list(), run.resets
        if not run.stopped and final_step:
            x = self.measured_state(own)
            last = self._step(run.state, x)
            records.append(last[2])
            resets = (*resets, last[2].k) if last[3] else resets
        if not records:
            raise ProblemError("context", "a context in which AdaptiveMPCSystem stepped at least once "
                               "(Simulator.AdvanceTo past t = 0)", "no step recorded")
        info = {"simulator": DRAKE_SIMULATOR, "period": self.period, **(meta or {})}
        if resets:
            info["theta_resets"] = list(resets)
        traj = measured_trajectory(self.controller, records, meta=info)
        if (theta_star is None) != (w is None):
            raise ProblemError("theta_star" if theta_star is None else "w",
                               "given together with " + ("w" if theta_star is None else "theta_star")
                               + " (a known plant), or both None (a measured run)", "None")
        if theta_star is None:
            return traj
        W = np.asarray(w, float).reshape(-1, self.n)
        if len(W) < traj.steps:
            raise ProblemError("w", f"at least {traj.steps} disturbances (one per applied input)",
                               f"{len(W)}")
        return replace(traj, theta_star=np.asarray(theta_star, float), w=W[:traj.steps].copy())


__all__ = ["AdaptiveMPCSystem", "ControllerRun", "DEFAULT_PERIOD", "DRAKE_SIMULATOR", "ON_INCONSISTENT"]
