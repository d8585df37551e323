"""Plain summaries of a Trajectory used by the CLI and the README: interval hull of Θ_k, tables."""

from __future__ import annotations

import numpy as np

from amcp_drake.model import polytope


def interval_hull(H: np.ndarray, h: np.ndarray) -> np.ndarray:
    """[min θ_i, max θ_i] over {H θ <= h} for each i, shape (p, 2), by LPs (scipy)."""
    p = H.shape[1]
    out = np.empty((p, 2))
    for i in range(p):
        e = np.zeros(p)
        e[i] = 1.0
        out[i, 1] = polytope.support(H, h, e).value
        out[i, 0] = -polytope.support(H, h, -e).value
    return out


def step_table(traj, every: int = 1) -> list[dict]:
    """One row per recorded step: k, x, u, status, Θ_k interval widths, θ̂_k, solver time."""
    rows = []
    for r in traj.records[::every]:
        hull = interval_hull(r.H_theta, r.h_theta)
        rows.append({
            "k": r.k, "x": r.x, "u": r.u, "status": r.status.value,
            "widths": hull[:, 1] - hull[:, 0], "theta_hat": r.theta_hat,
            "solver_ms": 1e3 * r.times.get("solver", float("nan")),
            "total_ms": 1e3 * r.times.get("total", float("nan")),
        })
    return rows


def signals_header(problem) -> list[str]:
    """The lines naming the entries of x_k and u_k (and the sample time) above a table, when the problem
    names its states or inputs or gives a sample time; none otherwise."""
    if not (problem.states or problem.inputs or problem.dt is not None):
        return []
    line = (f"x_k = ({', '.join(problem.state_label(i) for i in range(problem.n))}), "
            f"u_k = ({', '.join(problem.input_label(j) for j in range(problem.m))})")
    return [line + (f", sample time dt = {problem.dt:g} s" if problem.dt is not None else "")]


def format_table(rows: list[dict], problem=None) -> str:
    """Fixed-width text table of :func:`step_table` rows, headed by :func:`signals_header` of ``problem``."""
    def vec(a, width=7):
        return "[" + " ".join(f"{v:{width}.3f}" for v in np.atleast_1d(a)) + "]" if a is not None else "-"

    lines = signals_header(problem) if problem is not None else []
    lines += [f"{'k':>3}  {'x_k':22s} {'u_k':10s} {'status':9s} {'widths of Theta_k (interval hull)':36s} "
             f"{'theta_hat_k':28s} {'QP ms':>6s}"]
    for row in rows:
        lines.append(f"{row['k']:3d}  {vec(row['x']):22s} {vec(row['u']):10s} {row['status'][:9]:9s} "
                     f"{vec(row['widths'], 6):36s} {vec(row['theta_hat'], 6):28s} {row['solver_ms']:6.1f}")
    return "\n".join(lines)
