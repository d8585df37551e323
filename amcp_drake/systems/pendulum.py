"""A nonlinear plant in Drake, worked end to end: an inverted pendulum as a discrete ``MultibodyPlant``,
its model for the controller (a linearisation affine in two uncertain physical parameters, eq. (2)), a
disturbance set W that covers the linearisation error over the constraint set, and the closed loop with
:class:`~amcp_drake.systems.controller_system.AdaptiveMPCSystem` run by Drake's Simulator and certified as
a measured run (docs/how-to/nonlinear-plant.md; the script examples/pendulum_in_drake.py).

The plant: a point mass ``mass`` on a massless rod of length ``length`` above a hinge about the y axis
(q = 0 upright, an unstable equilibrium), viscous hinge damping ``damping``, a torque actuator. The
``MultibodyPlant`` is discrete with ``time_step`` = the controller's sample period: its one-step map
x_{k+1} = f(x_k, u_k; mass, damping), x = (q, v), with the input held over the step, is the plant the
controller's model describes (no further discretisation). Drake's discrete solver treats the damping
implicitly, so f is not affine in the parameters even at the equilibrium.

The model (1)-(2): θ ∈ Θ = [−1, 1]², mass = mass₀ + θ_1·Δm, damping = b₀ + θ_2·Δb.
A0, B0: Drake's ``Linearize`` of f at the upright equilibrium with the nominal parameters; A_i, B_i: central
differences of the linearisations at the parameter values θ = ±e_i, (A(e_i) − A(−e_i))/2. W: a box with
half-widths ``margin`` × max |f(x, u; θ) − A(θ)x − B(θ)u| per state, the maximum over every corner of
Z × Θ and ``samples`` uniform points of Z × Θ (:func:`linearisation_error`). The error comes from sin q ≠ q
and from the parameters' non-affine effect; it is largest at the corners of Z, which the sample contains.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import RevoluteJoint, SpatialInertia, UnitInertia
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import Linearize

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import Problem
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.offline.design import design as offline_design
from amcp_drake.online.simulate import Trajectory
from amcp_drake.systems.closed_loop import ClosedLoop, closed_loop
from amcp_drake.systems.controller_system import ON_INCONSISTENT, AdaptiveMPCSystem


@dataclass(frozen=True)
class PendulumSpec:
    """The physical pendulum, its uncertain parameters and the controller's problem data.

    ``mass`` [kg] and ``damping`` [N·m·s/rad]: nominal values; ``mass_spread``, ``damping_spread``: the
    half-widths Δm, Δb of the parameter box (θ ∈ [−1, 1]²); ``q_max`` [rad], ``v_max`` [rad/s], ``u_max``
    [N·m]: the box Z; ``margin``: the factor on the sampled linearisation error that gives W;
    ``samples``, ``seed``: the uniform sample of Z × Θ of :func:`linearisation_error`."""

    length: float = 0.5
    gravity: float = 9.81
    mass: float = 1.0
    mass_spread: float = 0.2
    damping: float = 0.1
    damping_spread: float = 0.05
    dt: float = 0.05
    q_max: float = 0.4
    v_max: float = 1.5
    u_max: float = 4.0
    N: int = 8
    Q: tuple = ((10.0, 0.0), (0.0, 1.0))
    R: tuple = ((0.1,),)
    margin: float = 1.5
    samples: int = 2000
    seed: int = 0

    def physical(self, theta) -> tuple[float, float]:
        """(mass, damping) at θ: mass₀ + θ_1·Δm, b₀ + θ_2·Δb."""
        th = np.asarray(theta, float)
        return self.mass + th[0] * self.mass_spread, self.damping + th[1] * self.damping_spread


class Pendulum:
    """The inverted pendulum as a discrete Drake ``MultibodyPlant`` (module docstring) with its
    parameters set per Context: :meth:`set_parameters`, :meth:`step` (the one-step map f) and
    :meth:`linearise` (Drake's ``Linearize`` at the upright equilibrium)."""

    def __init__(self, spec: PendulumSpec) -> None:
        self.spec = spec
        plant = MultibodyPlant(time_step=spec.dt)
        com = [0.0, 0.0, spec.length]  # the mass above the hinge: q = 0 is upright
        body = plant.AddRigidBody("bob", SpatialInertia(spec.mass, com, UnitInertia.PointMass(com)))
        joint = plant.AddJoint(RevoluteJoint("hinge", plant.world_frame(), body.body_frame(), [0.0, 1.0, 0.0],
                                             spec.damping))
        plant.AddJointActuator("torque", joint)
        plant.mutable_gravity_field().set_gravity_vector([0.0, 0.0, -spec.gravity])
        # the state output is the state itself (no sampled copy): Linearize needs a discrete state only
        plant.SetUseSampledOutputPorts(False)
        plant.Finalize()
        plant.set_name("pendulum")
        self.plant, self.body, self.joint = plant, body, joint
        self._context = plant.CreateDefaultContext()

    def set_parameters(self, context, theta) -> None:
        """Sets mass and damping of θ (:meth:`PendulumSpec.physical`) in ``context`` (the plant's own)."""
        mass, damping = self.spec.physical(theta)
        self.body.SetMass(context, mass)
        self.joint.SetDamping(context, damping)

    def step(self, x, u, theta) -> np.ndarray:
        """f(x, u; θ): the plant's discrete update from x = (q, v) with the torque u held."""
        ctx = self._context
        self.set_parameters(ctx, theta)
        self.plant.SetPositionsAndVelocities(ctx, np.asarray(x, float))
        self.plant.get_actuation_input_port().FixValue(ctx, np.asarray(u, float).reshape(1))
        return self.plant.EvalUniquePeriodicDiscreteUpdate(ctx).get_vector().CopyToVector()

    def linearise(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) of f at x = 0, u = 0 (upright, no torque) and θ: Drake's ``Linearize`` (autodiff)."""
        ctx = self.plant.CreateDefaultContext()
        self.set_parameters(ctx, theta)
        self.plant.get_actuation_input_port().FixValue(ctx, [0.0])
        lin = Linearize(self.plant, ctx, input_port_index=self.plant.get_actuation_input_port().get_index(),
                        output_port_index=self.plant.get_state_output_port().get_index())
        return np.asarray(lin.A(), float), np.asarray(lin.B(), float)


def affine_family(pendulum: Pendulum) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A0, B0, A, B) of (2): A0, B0 the linearisation at θ = 0, A_i = (A(e_i) − A(−e_i))/2 and likewise
    B_i (central differences of linearisations at parameter values)."""
    A0, B0 = pendulum.linearise(np.zeros(2))
    A, B = [], []
    for i in range(2):
        e = np.zeros(2)
        e[i] = 1.0
        Ap, Bp = pendulum.linearise(e)
        Am, Bm = pendulum.linearise(-e)
        A.append((Ap - Am) / 2)
        B.append((Bp - Bm) / 2)
    return A0, B0, np.array(A), np.array(B)


@dataclass(frozen=True)
class ErrorEstimate:
    """The sampled linearisation error of :func:`linearisation_error`: ``max_abs`` (n,) the largest
    |f − A(θ)x − B(θ)u| per state, ``points`` how many points of Z × Θ were evaluated, ``argmax`` the
    point (x, u, θ) of the largest error of each state."""

    max_abs: np.ndarray
    points: int
    argmax: tuple = field(default=())


def linearisation_error(pendulum: Pendulum, A0, B0, A, B) -> ErrorEstimate:
    """max over Z × Θ of |f(x, u; θ) − A(θ)x − B(θ)u| per state, estimated on every corner of the box
    Z × Θ (2^5 points) and ``spec.samples`` uniform points of it (``spec.seed``)."""
    s = pendulum.spec
    hi = np.array([s.q_max, s.v_max, s.u_max, 1.0, 1.0])
    corners = np.array(list(itertools.product((-1.0, 1.0), repeat=5))) * hi
    rng = np.random.default_rng(s.seed)
    pts = np.vstack([corners, rng.uniform(-hi, hi, size=(s.samples, 5))])
    errs = np.empty((len(pts), 2))
    for j, z in enumerate(pts):
        x, u, th = z[:2], z[2:3], z[3:]
        A_th = A0 + np.tensordot(th, A, axes=1)
        B_th = B0 + np.tensordot(th, B, axes=1)
        errs[j] = pendulum.step(x, u, th) - A_th @ x - B_th @ u
    worst = np.abs(errs).argmax(axis=0)
    return ErrorEstimate(np.abs(errs).max(axis=0), len(pts), tuple(tuple(pts[i].tolist()) for i in worst))


def pendulum_problem(spec: PendulumSpec | None = None, w_scale: float = 1.0) -> tuple[Problem, Pendulum, ErrorEstimate]:
    """The controller's problem for the pendulum of ``spec``: the affine family of :func:`affine_family`,
    Θ = [−1, 1]², Z the box |q| <= q_max, |v| <= v_max, |u| <= u_max, and W the box of half-widths
    ``w_scale`` × ``spec.margin`` × the sampled error (:func:`linearisation_error`). ``w_scale`` < 1/margin
    makes a W that does not cover the linearisation error (the data then contradict the model)."""
    spec = spec or PendulumSpec()
    if isinstance(w_scale, bool) or not isinstance(w_scale, (int, float)) or not (np.isfinite(w_scale) and w_scale > 0):
        raise ProblemError("w_scale", "a finite number > 0", repr(w_scale))
    pend = Pendulum(spec)
    A0, B0, A, B = affine_family(pend)
    err = linearisation_error(pend, A0, B0, A, B)
    problem = Problem.from_matrices(
        A0, B0, A, B, W_box=(w_scale * spec.margin * err.max_abs).tolist(), Theta_box=[(-1.0, 1.0), (-1.0, 1.0)],
        x_bounds={"q": (-spec.q_max, spec.q_max), "v": (-spec.v_max, spec.v_max)},
        u_bounds={"tau": (-spec.u_max, spec.u_max)}, Q=np.array(spec.Q), R=np.array(spec.R), N=spec.N, dt=spec.dt,
        states=[("q", "rad"), ("v", "rad/s")], inputs=[("tau", "N m")], name="pendulum")
    return problem, pend, err


def pendulum_loop(controller: AdaptiveMPCSystem, pendulum: Pendulum) -> ClosedLoop:
    """The Diagram plant + controller: the pendulum's ``MultibodyPlant`` wrapped with the ports ``u``
    (its actuation input) and ``x`` (its state output), wired by :func:`closed_loop` (no disturbance
    source: the plant's own nonlinearity is the disturbance)."""
    builder = DiagramBuilder()
    plant = builder.AddSystem(pendulum.plant)
    builder.ExportInput(plant.get_actuation_input_port(), "u")
    builder.ExportOutput(plant.get_state_output_port(), "x")
    wrapped = builder.Build()
    wrapped.set_name("pendulum plant")
    return closed_loop(controller, wrapped)


@dataclass
class PendulumRun:
    """A closed-loop run of :func:`run_pendulum`: the problem, its design, the estimate behind W, the
    measured-run trajectory (θ* and w unknown to the controller), the Drake closed loop and how the
    Simulator returned."""

    problem: Problem
    design: OfflineDesign
    error: ErrorEstimate
    trajectory: Trajectory
    loop: ClosedLoop
    theta_true: np.ndarray
    #: the Simulator's answer: ``SimulatorStatus.ReturnReason`` of ``AdvanceTo``, its message, the time reached
    reason: object = None
    message: str = ""
    time: float = 0.0


def run_pendulum(steps: int = 25, *, x0=(0.25, 0.0), theta_true=(0.5, 0.6), w_scale: float = 1.0,
                 spec: PendulumSpec | None = None, on_inconsistent: str = "stop",
                 update: str = "exact", backend: str = "drake") -> PendulumRun:
    """Designs the controller for :func:`pendulum_problem`, runs the Diagram of the pendulum (with the
    parameters ``theta_true``, unknown to the controller) and :class:`AdaptiveMPCSystem` in Drake's
    Simulator for ``steps`` periods from ``x0`` = (q, v), and returns the run as a measured-run
    trajectory. A run stopped by the controller (Θ_{k−1} ∩ Δ_k = ∅ with ``on_inconsistent="stop"``, or a
    QP without answer) ends early; its trajectory holds the steps so far and the reason."""
    spec = spec or PendulumSpec()
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ProblemError("steps", "an integer >= 1", repr(steps))
    if on_inconsistent not in ON_INCONSISTENT:
        raise ProblemError("on_inconsistent", " or ".join(repr(o) for o in ON_INCONSISTENT), repr(on_inconsistent))
    problem, pend, err = pendulum_problem(spec, w_scale)
    theta = np.asarray(theta_true, float)
    if theta.shape != (2,) or not np.all(np.abs(theta) <= 1.0):
        raise ProblemError("theta_true", "a point of [-1, 1]^2 (the parameter box)", repr(theta_true))
    x_init = np.asarray(x0, float)
    if x_init.shape != (2,) or not np.all(np.isfinite(x_init)):
        raise ProblemError("x0", "a finite state (q, v)", repr(x0))
    offline = offline_design(problem, None, backend=backend)
    controller = AdaptiveMPCSystem(problem, offline, OnlineOptions(update=update), backend=backend, period=spec.dt,
                                   on_inconsistent=on_inconsistent)
    loop = pendulum_loop(controller, pend)
    simulator = Simulator(loop.diagram)
    root = simulator.get_mutable_context()
    plant_ctx = pend.plant.GetMyMutableContextFromRoot(root)
    pend.set_parameters(plant_ctx, theta)
    pend.plant.SetPositionsAndVelocities(plant_ctx, x_init)
    simulator.Initialize()
    status = simulator.AdvanceTo(steps * spec.dt)
    meta = {"plant": "pendulum (Drake MultibodyPlant, discrete)", "w_scale": float(w_scale)}
    traj = controller.trajectory(root, meta=meta)
    return PendulumRun(problem, offline, err, traj, loop, theta, status.reason(), status.message(),
                       simulator.get_context().get_time())


def summary(run: PendulumRun, certificate) -> dict:
    """The numbers of a run and its certificate (docs/results.md): steps, stop reason, W and the error
    estimate behind it, the verdict and claim counts, and each claim's status, margin and worst step."""
    half = 1.0 / np.abs(run.problem.H_w).max(axis=0)
    return {
        "steps": run.trajectory.steps, "stop_reason": run.trajectory.stop_reason,
        "theta_resets": run.trajectory.meta.get("theta_resets", []),
        "error_max_abs": run.error.max_abs.tolist(), "error_points": run.error.points, "W_half_widths": half.tolist(),
        "theta_hat_T": run.trajectory.records[-1].theta_hat.tolist(),
        "verdict": certificate.verdict, "counts": certificate.counts(),
        "claims": {c.data["id"]: {"status": c.status, "margin": c.margin, "worst_step": c.data.get("worst_step")}
                   for c in certificate.claims},
    }


__all__ = ["ErrorEstimate", "Pendulum", "PendulumRun", "PendulumSpec", "affine_family", "linearisation_error",
           "pendulum_loop", "pendulum_problem", "run_pendulum", "summary"]
