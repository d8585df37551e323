"""``amcp bench --only drake``: the closed loop of Example 1 in a Drake Diagram against amcp's simulator.

Two closed loops of Example 1 (Drake backend, plain form, the same disturbances), advanced in lockstep
(step k of each, then step k+1; the order alternates step by step): amcp's loop (``AdaptiveMPC.step``
and the numpy step of (1)) and the Drake Diagram of :func:`amcp_drake.systems.closed_loop.closed_loop`
(one ``Simulator.AdvanceTo`` of one period: the controller's update, the plant's affine update, the
disturbance source, the loggers). Per full step (k >= 1), the thread CPU time of each, and the QP
solver's wall time as the step records it. The ratio of the medians is the cost of running in Drake;
the QP solver's ratio shows that the QP is the same. The two runs' states are compared (max |Δx|).
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable
from typing import Any

import numpy as np

#: The Diagram's CPU per step may be at most this multiple of amcp's simulator.
TARGET_RATIO = 1.3


def _ms(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {"median": None, "p90": None, "n": 0}
    ms = 1e3 * np.asarray(values, float)
    return {"median": float(np.median(ms)), "p90": float(np.percentile(ms, 90)), "n": int(len(ms))}


def drake_loop_benchmark(steps: int, seed: int, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Run both loops of Example 1 for ``steps`` steps (module docstring); a JSON-ready dict."""
    from pydrake.systems.analysis import Simulator

    from amcp_drake.model.examples import lorenzen2019_spec
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence
    from amcp_drake.systems.closed_loop import closed_loop
    from amcp_drake.systems.controller_system import AdaptiveMPCSystem
    from amcp_drake.systems.plant import RecordedDisturbance, drake_plant

    spec = lorenzen2019_spec()
    pr, sc = spec.problem, spec.scenario
    progress(f"Drake Diagram against amcp's simulator: Example 1, {steps} steps, seed {seed}")
    offline = design(pr, spec.design, backend="drake")
    theta = np.asarray(sc.theta_star, float)
    W = disturbance_sequence(pr, "uniform", steps, seed)
    builtin = AdaptiveMPC(pr, offline, "drake")
    system = AdaptiveMPCSystem(controller=AdaptiveMPC(pr, offline, "drake"))
    loop = closed_loop(system, drake_plant(pr, theta, system.period), RecordedDisturbance(W, system.period))
    simulator = Simulator(loop.diagram)
    loop.plant.GetMyMutableContextFromRoot(simulator.get_mutable_context()).SetDiscreteState(np.asarray(sc.x0, float))
    simulator.Initialize()
    x = np.asarray(sc.x0, float)
    xs, cpu = [x], {"builtin": [], "drake": []}
    solver = {"builtin": [], "drake": []}
    status = "completed"
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        for k in range(steps):
            for who in (("builtin", "drake") if k % 2 == 0 else ("drake", "builtin")):
                start = time.thread_time()
                if who == "builtin":
                    u, rec = builtin.step(x)
                    if u is not None:
                        x = pr.step(x, u, theta, W[k])
                else:
                    simulator.AdvanceTo((k + 1) * system.period)
                    run = system.run(simulator.get_context())
                    rec = run.record_list()[-1] if run.steps else None
                spent = time.thread_time() - start
                if rec is None or rec.u is None:
                    status = f"{who}: no input at step {k}"
                    break
                if k >= 1:
                    cpu[who].append(spent)
                    solver[who].append(float(rec.times.get("solver", 0.0)))
            if status != "completed":
                break
            xs.append(x)
    finally:
        if was_enabled:
            gc.enable()
    drake_x = [r.x for r in system.run(simulator.get_context()).record_list()] + [
        np.asarray(loop.plant.GetMyContextFromRoot(simulator.get_context()).get_discrete_state_vector().value())]
    n = min(len(xs), len(drake_x))
    dx = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) for a, b in zip(xs[:n], drake_x[:n]))
    b_cpu, d_cpu = _ms(cpu["builtin"]), _ms(cpu["drake"])
    ratio = (d_cpu["median"] / b_cpu["median"]) if b_cpu["median"] and d_cpu["median"] is not None else None
    b_qp, d_qp = _ms(solver["builtin"]), _ms(solver["drake"])
    qp_ratio = (d_qp["median"] / b_qp["median"]) if b_qp["median"] and d_qp["median"] is not None else None
    return {"problem": pr.name, "steps": steps, "seed": seed, "status": status,
            "builtin_cpu_ms": b_cpu, "drake_cpu_ms": d_cpu, "cpu_ratio": ratio,
            "builtin_qp_solver_ms": b_qp, "drake_qp_solver_ms": d_qp, "qp_solver_ratio": qp_ratio,
            "target_ratio": TARGET_RATIO, "met": None if ratio is None else bool(ratio <= TARGET_RATIO),
            "max_abs_dx": dx}


def drake_loop_summary(result: dict[str, Any]) -> list[str]:
    """The lines of ``amcp bench`` for :func:`drake_loop_benchmark`."""
    def f(v, digits=3):
        return "-" if v is None else f"{v:.{digits}f}"
    met = {True: "met", False: "NOT met", None: "not measured"}[result["met"]]
    return [f"Drake Diagram vs amcp's simulator, {result['problem']}, {result['steps']} steps: CPU per full step "
            f"{f(result['drake_cpu_ms']['median'])} vs {f(result['builtin_cpu_ms']['median'])} ms (median), ratio "
            f"{f(result['cpu_ratio'], 2)}x (target <= {result['target_ratio']:g}x: {met}); QP solver ratio "
            f"{f(result['qp_solver_ratio'], 2)}x; max |dx| {result['max_abs_dx']:.1e}; {result['status']}"]


__all__ = ["TARGET_RATIO", "drake_loop_benchmark", "drake_loop_summary"]
