"""Scaling sweeps of the online loop: one factor at a time around Example 1.

Defaults (Example 1, docs/explanation/paper.md §9): N = 10, X0 with 8 facets, n = 2, p = 3, x0 = [2, 3], θ* = [0.8,
0.2, −0.5], uniform disturbance, seed 0. Each sweep changes one factor and keeps the others:

* ``N`` ∈ {5, 10, 20, 40}: the horizon;
* ``x0_facets`` ∈ {4, 8, 16}: the facets of the X0 template;
* ``p`` ∈ {2, 3, 4}: Example 1's first p parameters (p = 4 adds A₄ = [[0.02, 0], [0.01, 0.02]],
  B₄ = [0.02, 0]ᵀ; Θ = [−1, 1]^p);
* ``n`` ∈ {2, 3, 4}: :func:`problem_with_n`, Example 1 embedded in n states (n = 2 is Example 1).

x0 is Example 1's [2, 3] (zero-padded for n > 2); where the tube QP (20) at k = 0 is infeasible for
it (the n = 4 point), the largest of its multiples in :data:`X0_SCALES` whose QP is feasible
(:func:`feasible_x0`; the row's ``x0_scale`` and the table say which).

Every point is designed (its CPU and wall time reported: ``design_cpu_s``, ``design_s``), then the
configurations (default: Drake plain (15), vertex, vertex + DAQP fast path) run in lockstep with
the per-step CPU and wall times of :func:`amcp_drake.studies.bench.lockstep`. :func:`scaling_markdown`
renders the table of benchmarks/README.md (``amcp bench --only scaling`` writes it as
``scaling.md`` next to bench.json and bench.png).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

#: The extra parameter of the p = 4 sweep point (the first three are Example 1's).
A4 = np.array([[0.02, 0.0], [0.01, 0.02]])
B4 = np.array([[0.02], [0.0]])
#: θ* of the p = 4 sweep point (the first three are Example 1's).
THETA_STAR_4 = np.array([0.8, 0.2, -0.5, 0.3])
#: Disturbance bound of the n >= 3 points, |w_i| <= 0.05: with Example 1's 0.1 the terminal set of
#: the n = 3 and n = 4 systems below is empty for every X0 template tried (4 to 18 facets).
W_BOUND_N = 0.05


#: Multiples of x0 tried, in order, until the tube QP (20) at k = 0 is feasible (feasible_x0).
X0_SCALES = (1.0, 0.5, 0.25, 0.125)


def feasible_x0(problem, design, x0: np.ndarray) -> tuple[np.ndarray, float]:
    """(s·x0, s) for the first s in X0_SCALES at which the QP (20) with Θ_0 and θ̂_0 (Drake, vertex
    form) is solved to optimality; (x0, 1.0) when none is (the run then reports the infeasibility)."""
    from amcp_drake.backends import TubeMPCData, get_backend
    from amcp_drake.model.status import SolveStatus

    d = design
    data = TubeMPCData(A0=problem.A0, B0=problem.B0, A=problem.A, B=problem.B, F=problem.F, G=problem.G, Q=problem.Q,
                       R=problem.R, N=problem.N, K=d.K, P=d.P, H_x=d.H_x, X0_vertices=d.X0_vertices, w_bar=d.w_bar,
                       f_bar=d.f_bar, H_T=d.H_T, h_T=d.h_T, H_theta=d.H_theta, h_theta0=d.h_theta0)
    qp = get_backend("drake", formulation="vertex").tube_mpc(data)
    for scale in X0_SCALES:
        if qp.solve(scale * x0, d.h_theta0, problem.theta_hat0).status is SolveStatus.OPTIMAL:
            return scale * x0, scale
    return x0, 1.0


def problem_with_p(problem, p: int):
    """Example 1 with its first p parameters (p = 4 adds A_4 = A4, B_4 = B4); Θ = [-1, 1]^p."""
    A = np.concatenate([problem.A, A4[None]])[:p]
    B = np.concatenate([problem.B, B4[None]])[:p]
    return problem.with_changes(A=A, B=B, H_theta=np.vstack([np.eye(p), -np.eye(p)]), h_theta=np.ones(2 * p),
                                theta_hat0=np.zeros(p))


def problem_with_n(problem, n: int):
    """Example 1 (n = 2) embedded in n states: A0 = diag(0.5 … 0.6) + 0.2 on the superdiagonal −
    0.1 on the subdiagonal (Example 1's A0 for n = 2), B0 = 0.5 e_n, the parameter matrices A_i in
    the leading 2×2 block and B_i in the last two rows, W = {|w_i| <= W_BOUND_N}, Z: Example 1's rows
    on (x_1, x_2) and the input, Q = I, R = 1. Returns ``problem`` itself for n = 2."""
    if n == problem.n:
        return problem
    if n < 2:
        raise ValueError(f"n: expected >= 2, got {n}")
    A0 = np.diag(np.linspace(0.5, 0.6, n)) + 0.2 * np.eye(n, k=1) - 0.1 * np.eye(n, k=-1)
    B0 = np.zeros((n, problem.m))
    B0[-1] = 0.5
    A = np.zeros((problem.p, n, n))
    A[:, :2, :2] = problem.A
    B = np.zeros((problem.p, n, problem.m))
    B[:, -2:, :] = problem.B
    F = np.zeros((problem.F.shape[0], n))
    F[:, :2] = problem.F
    H_w = np.vstack([np.eye(n), -np.eye(n)]) / W_BOUND_N
    return problem.with_changes(A0=A0, B0=B0, A=A, B=B, F=F, H_w=H_w, Q=np.eye(n))


def sweep_points(settings) -> dict[str, list[tuple[int, Any, Any, np.ndarray, np.ndarray]]]:
    """axis -> [(value, problem, design options, x0, θ*)] for the sweeps of ``settings``."""
    from amcp_drake.model.examples import lorenzen2019_spec

    spec = lorenzen2019_spec()
    sc, base, options = spec.scenario, spec.problem, spec.design
    x0, theta = np.asarray(sc.x0, float), np.asarray(sc.theta_star, float)

    def x0_n(n: int) -> np.ndarray:
        return np.concatenate([x0, np.zeros(n - 2)])

    return {
        "N": [(N, base.with_changes(N=N), options, x0, theta) for N in settings.sweep_N],
        "x0_facets": [(f, base, replace(options, x0_facets=f), x0, theta) for f in settings.sweep_facets],
        "p": [(p, problem_with_p(base, p), options, x0, THETA_STAR_4[:p]) for p in settings.sweep_p],
        "n": [(n, problem_with_n(base, n), options, x0_n(n), theta) for n in settings.sweep_n],
    }


def scaling_benchmark(settings, progress: Callable[[str], None] = lambda s: None) -> dict[str, list[dict[str, Any]]]:
    """Run every sweep point of ``settings`` (see the module docstring)."""
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.offline.design import design
    from amcp_drake.studies.bench_run import lockstep, summaries

    configs = settings.configs(settings.scaling_backends)
    out: dict[str, list[dict[str, Any]]] = {}
    for axis, items in sweep_points(settings).items():
        rows: list[dict[str, Any]] = []
        for value, problem, options, x0, theta_star in items:
            progress(f"scaling: {axis} = {value}, {settings.scaling_steps} steps")
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                d = design(problem, options, backend="drake")
            except AmcpError as exc:
                rows.append({axis: value, "status": f"design failed: {exc}", "design_s": time.perf_counter() - wall,
                             "design_cpu_s": time.thread_time() - cpu})
                continue
            timing = {"design_s": time.perf_counter() - wall, "design_cpu_s": time.thread_time() - cpu}
            x0, scale = feasible_x0(problem, d, x0)
            runs = lockstep(problem, d, configs, x0, theta_star, settings.scaling_steps, settings.seed)
            rows.extend(summaries(runs, {axis: value, "N": problem.N, "p": problem.p, "n": problem.n,
                                          "x0_facets": int(len(d.H_x)), "steps": settings.scaling_steps,
                                          "x0_scale": scale, **timing}))
        out[axis] = rows
    return out


def scaling_markdown(scaling: dict[str, list[dict[str, Any]]]) -> str:
    """The scaling table (CPU medians, ms per full step; wall medians in brackets; design time)."""
    lines = ["| sweep | N | X0 facets | n | p | design CPU s (wall) | formulation | full step CPU ms (wall) "
             "| QP solver CPU ms | outside solvers CPU ms | fast path DAQP / fallbacks |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for axis, rows in scaling.items():
        for r in rows:
            if "times_ms" not in r:
                spent = f"{r['design_cpu_s']:.1f} ({r['design_s']:.1f})" if "design_cpu_s" in r else ""
                lines.append(f"| {axis} = {r[axis]} | | | | | {spent} | {r['status']} | | | | |")
                continue
            t = r["times_ms"]
            fp = r.get("fast_path")
            fp_text = "" if fp is None else f"{fp['daqp']} / {fp['fallback']}"
            status = "" if r["status"] == "completed" else f" [{r['status']}]"
            scaled = "" if r.get("x0_scale", 1.0) == 1.0 else f" (x0 × {r['x0_scale']:g})"
            lines.append(
                f"| {axis} = {r[axis]}{scaled} | {r['N']} | {r['x0_facets']} | {r['n']} | {r['p']} "
                f"| {r['design_cpu_s']:.1f} ({r['design_s']:.1f}) | {r['backend']} {r['formulation']}{status} "
                f"| {_fmt(t['cpu_total']['median'])} ({_fmt(t['total']['median'])}) "
                f"| {_fmt(t['cpu_qp_solver']['median'])} | {_fmt(t['cpu_outside_solvers']['median'])} "
                f"| {fp_text} |")
    return "\n".join(lines) + "\n"


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


__all__ = ["A4", "B4", "THETA_STAR_4", "W_BOUND_N", "problem_with_n", "problem_with_p", "scaling_benchmark", "scaling_markdown", "sweep_points"]
