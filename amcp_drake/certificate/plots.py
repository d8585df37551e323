"""Plots of a closed-loop run and its certificate (``amcp.plots``), for a report or a paper.

Every function draws into ``ax`` when given (a matplotlib ``Axes``; ``axes`` for the two-panel plots),
else into a new ``matplotlib.figure.Figure``, and returns that Figure (python-control's convention), so
that a plot can be placed in a figure of one's own and saved in any format::

    import amcp_drake as amcp
    fig = amcp.plots.tubes(traj, plane=(1, 3))          # the tube in the plane of x2 and x4
    fig.savefig("tube.pdf")

The report (``report.html``) is drawn by these same functions and embeds them as SVG. Drawn with
matplotlib's object API (no pyplot: no global figure state). Labels use matplotlib's mathtext in the
paper's notation ($\\Theta_k$, $\\hat\\theta_k$, $X_{l|k}$) and the names and units of the problem's states
and inputs (``name [unit]``; $x_i$, $u_i$ when the problem names none). Legends are placed outside the
data area, to the right of each panel.

**The default plane** of the tube plots (:func:`tightest_plane`): the two states whose constraints the
closed loop's tubes come closest to. The *use* of a state row r of Z (F_r x <= 1, no input term) is the
largest value of F_r x over the recorded closed-loop states x_k and the sections X_{0|k} and X_{1|k}
(X_{l|k} = z_{l|k} ⊕ α_{l|k} X0, Proposition 9) of every solved step k: the sets that contain x_k and
x_{k+1}. 1 means the row is active, 0.5 that the tube reaches half-way to it. (The later stages are left
out: the predicted tube grows towards the terminal set and comes close to every row, so it does not
tell the rows apart.) The *score* of state i is the largest use of the rows that involve
x_i (F_{r,i} ≠ 0); a state without such a row has no score. The plane is the two states with the
highest scores (ties: the lower index first; states without a score last, in index order), drawn in
index order.
"""

from __future__ import annotations

import numpy as np

#: Steps k at which the run-along tube panel shows X_{0|k} and X_{1|k} (evenly spread, k = 0 first).
RUN_TUBE_STEPS = 4
#: Stages l of the predicted tube X_{l|0} drawn: 0, 1, 2, then every ⌈N/4⌉-th, and N.
TUBE_EARLY_STAGES = 3


# -- figure plumbing ---------------------------------------------------------------------------------
def _axes(ax, width: float = 8.0, height: float = 3.2):
    """(figure, axes): the given axes and its figure, or a new constrained-layout Figure with one axes."""
    if ax is not None:
        return ax.figure, ax
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    return fig, fig.add_subplot()


def _two_axes(axes, width: float, height: float):
    if axes is not None:
        left, right = axes
        return left.figure, left, right
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    return fig, fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)


def legend_outside(ax, handles=None, labels=None, ncol: int = 1) -> None:
    """The legend of ``ax`` to the right of its data area (never over the data)."""
    if handles is None:
        handles, labels = ax.get_legend_handles_labels()
    ax.legend(handles, labels, fontsize="small", ncol=ncol, loc="upper left", bbox_to_anchor=(1.02, 1.0),
              borderaxespad=0.0, frameon=False)


def _finish(ax, ylabel: str | None, xlabel: str = "step $k$", ncol: int = 1) -> None:
    """The axis labels, legend and grid every time-series plot shares."""
    ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    legend_outside(ax, ncol=ncol)
    ax.grid(alpha=0.3)


def _dotted_columns(ax, k, values: np.ndarray, symbol: str) -> list:
    """One dotted line per column of the per-step matrix ``values`` against k, labelled $symbol_i$."""
    return [ax.plot(k, values[:, i], marker=".", label=f"${symbol}_{{{i + 1}}}$")[0] for i in range(values.shape[1])]


def _single_bounds(F: np.ndarray, G: np.ndarray, on_state: bool) -> list[tuple[int, float]]:
    """(index, bound) of rows of Fx + Gu <= 1 that bound one state (G row zero) or one input (F row zero):
    a_i y_j <= 1 gives y_j <= 1/a or y_j >= 1/a."""
    own, other = (F, G) if on_state else (G, F)
    out = []
    for row, rest in zip(own, other):
        nz = np.flatnonzero(row)
        if len(nz) == 1 and not np.any(rest):
            out.append((int(nz[0]), 1.0 / row[nz[0]]))
    return out


def _include_bounds(ax, values: np.ndarray, bounds: list[float]) -> None:
    """y-limits that show the data and every constraint line (axhline does not autoscale)."""
    points = np.concatenate([np.ravel(values), bounds]) if len(bounds) else np.ravel(values)
    if points.size == 0:
        return
    lo, hi = float(np.min(points)), float(np.max(points))
    pad = 0.05 * max(hi - lo, 1e-9)
    ax.set_ylim(lo - pad, hi + pad)


def _polygon(vertices: np.ndarray) -> np.ndarray:
    """The closed outline of a convex polygon from its vertices (sorted by angle about their mean)."""
    centre = vertices.mean(axis=0)
    order = np.argsort(np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0]))
    closed = vertices[order]
    return np.vstack([closed, closed[:1]])


def hull2d(points: np.ndarray) -> np.ndarray:
    """The closed outline of the convex hull of 2-D points (the points themselves when degenerate)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
        ring = points[hull.vertices]
        return np.vstack([ring, ring[:1]])
    except (QhullError, ValueError):
        return points[np.lexsort(points.T[::-1])]


# -- states and inputs -----------------------------------------------------------------------------------
def signal_label(pr, i: int, on_state: bool = True) -> str:
    """Text of state (input) i on an axis or in a legend: ``name [unit]`` when the problem names it, else
    $x_{i+1}$ ($u_{i+1}$). Names and units are restricted to a character set without ``$`` or markup
    (model/signals.py), so they are shown as plain text."""
    named = pr.states if on_state else pr.inputs
    if named:
        return pr.state_label(i) if on_state else pr.input_label(i)
    return f"${'x' if on_state else 'u'}_{{{i + 1}}}$"


def states(traj, ax=None):
    """x_k (dots) against k, each state with the rows of Z that bound it alone (dashed)."""
    return _signal(traj, True, ax)


def inputs(traj, ax=None):
    """u_k (held over the step) against k, each input with its bounds in Z (dashed)."""
    return _signal(traj, False, ax)


def _signal(traj, on_state: bool, ax):
    pr = traj.problem
    values, width = (traj.x, pr.n) if on_state else (traj.u, pr.m)
    bounds = _single_bounds(pr.F, pr.G, on_state)
    fig, ax = _axes(ax)
    k = np.arange(len(values))
    for j in range(width):
        label = signal_label(pr, j, on_state)
        if on_state:
            line, = ax.plot(k, values[:, j], marker=".", label=label)
        else:
            line, = ax.step(k, values[:, j], where="post", label=label)
        labelled = False
        for idx, bound in bounds:
            if idx == j:
                ax.axhline(bound, ls="--", color=line.get_color(), lw=1,
                           label=None if labelled else f"bound on {label} (Z)")
                labelled = True
    _include_bounds(ax, values, [b for _, b in bounds])
    _finish(ax, "state" if on_state else "input")
    return fig


# -- tubes ---------------------------------------------------------------------------------------------
def tube_stages(N: int) -> list[int]:
    """The stages l of X_{l|0} the tube plot draws: 0, 1, 2, every ⌈N/4⌉-th and N."""
    step = max(1, -(-N // 4))
    return sorted(set(range(min(TUBE_EARLY_STAGES, N + 1))) | set(range(0, N + 1, step)) | {N})


def run_tube_steps(solved_ks: list[int]) -> list[int]:
    """The steps k of the run-along panel: at most RUN_TUBE_STEPS, evenly spread over the solved steps after
    the first (which the predicted-tube panel shows), the last included; the first when it is the only one."""
    later = solved_ks[1:] or solved_ks
    picks = np.linspace(0, len(later) - 1, min(RUN_TUBE_STEPS, len(later)))
    return sorted({later[int(round(i))] for i in picks}) if later else []


def _solved(traj) -> list:
    return [r for r in traj.records if r.z is not None and r.alpha is not None]


def _x0_vertices(design) -> np.ndarray:
    from amcp_drake.model import polytope

    return polytope.vertices(design.H_x, np.ones(len(design.H_x)))


def state_row_scores(traj) -> np.ndarray:
    """Per state, the largest use of the rows of Z that involve it (module docstring; NaN: no such row)."""
    pr = traj.problem
    rows = [r for r in range(len(pr.F)) if not np.any(pr.G[r]) and np.any(pr.F[r])]
    scores = np.full(pr.n, np.nan)
    if not rows:
        return scores
    F = pr.F[rows]
    use = np.max(traj.x @ F.T, axis=0) if len(traj.x) else np.full(len(rows), -np.inf)
    solved = _solved(traj)
    if solved:
        support = np.max(F @ _x0_vertices(traj.design).T, axis=1)  # max_j F_r x^j over the vertices of X0
        for r in solved:
            tube = np.asarray(r.z[:2]) @ F.T + np.outer(r.alpha[:2], support)  # max of F_r x over X_{0|k}, X_{1|k}
            use = np.maximum(use, tube.max(axis=0))
    for i in range(pr.n):
        mine = F[:, i] != 0
        if np.any(mine):
            scores[i] = float(np.max(use[mine]))
    return scores


def tightest_plane(traj) -> tuple[int, int]:
    """The default plane of the tube plots: the two states with the highest :func:`state_row_scores`
    (module docstring), in index order; (0, 1) when no state is constrained."""
    scores = state_row_scores(traj)
    order = sorted(range(traj.problem.n), key=lambda i: (np.isnan(scores[i]), -np.nan_to_num(scores[i]), i))
    i, j = sorted(order[:2])
    return int(i), int(j)


def _plane(traj, plane) -> tuple[int, int]:
    n = traj.problem.n
    if n < 2:
        raise ValueError(f"a tube plot needs a plane of two states; this problem has n = {n}")
    if plane is None:
        return tightest_plane(traj)
    i, j = (int(v) for v in plane)
    if not (0 <= i < n and 0 <= j < n and i != j):
        raise ValueError(f"plane: expected two different state indices from 0 to {n - 1}; received {tuple(plane)}")
    return i, j


def _section(r, l: int, X0v: np.ndarray, plane: tuple[int, int], n: int) -> np.ndarray:
    """The outline of X_{l|k} = z_{l|k} ⊕ α_{l|k} X0 in the plane (n > 2: the projection, the hull of the
    projected vertices)."""
    points = (r.z[l] + r.alpha[l] * X0v)[:, list(plane)]
    return _polygon(points) if n == 2 else hull2d(points)


def _view(points: np.ndarray, pad: float = 0.08) -> tuple[tuple[float, float], tuple[float, float]]:
    lo, hi = points.min(axis=0), points.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    return ((lo[0] - pad * span[0], hi[0] + pad * span[0]), (lo[1] - pad * span[1], hi[1] + pad * span[1]))


def z_rows_in_plane(pr, plane: tuple[int, int]) -> list[int]:
    """The rows of Z that bound only the two states of ``plane`` (no input term, no other state)."""
    i, j = plane
    others = [c for c in range(pr.n) if c not in plane]
    return [r for r in range(len(pr.F))
            if not np.any(pr.G[r]) and np.any(pr.F[r, [i, j]]) and not np.any(pr.F[r, others])]


def _z_boundary(ax, pr, plane, xlim, ylim) -> bool:
    """Draw F_r x = 1 for the rows of Z on the plane's states only, hatching the excluded side; True when
    any row was drawn."""
    xs = np.linspace(*xlim, 300)
    ys = np.linspace(*ylim, 300)
    XX, YY = np.meshgrid(xs, ys)
    drawn = False
    for r in z_rows_in_plane(pr, plane):
        value = pr.F[r, plane[0]] * XX + pr.F[r, plane[1]] * YY
        if not (np.min(value) <= 1.0 <= np.max(value)):
            continue
        ax.contourf(XX, YY, value, levels=[1.0, np.inf], colors="none", hatches=["////"])
        ax.contour(XX, YY, value, levels=[1.0], colors=["tab:red"], linewidths=1.5)
        drawn = True
    return drawn


def _finish_plane(ax, pr, plane, view, title: str, extra=(), ncol: int = 1) -> None:
    from matplotlib.patches import Patch

    drawn = _z_boundary(ax, pr, plane, *view)
    ax.set_xlim(view[0])
    ax.set_ylim(view[1])
    ax.set_xlabel(signal_label(pr, plane[0]))
    ax.set_ylabel(signal_label(pr, plane[1]))
    ax.set_title(title, fontsize="medium")
    ax.grid(alpha=0.3)
    handles, labels = ax.get_legend_handles_labels()
    for handle, label in extra:
        handles.append(handle)
        labels.append(label)
    if drawn:
        handles.append(Patch(facecolor="none", edgecolor="tab:red", hatch="////"))
        labels.append("boundary of Z, excluded side")
    legend_outside(ax, handles, labels, ncol=ncol)


def predicted_tube(traj, plane=None, ax=None):
    """The tube predicted at the first solved step k: the outlines of X_{l|k} = z_{l|k} ⊕ α_{l|k} X0 at the
    stages of :func:`tube_stages`, its centres z_{l|k} and the closed loop x_k, in the plane of two states
    (``plane``: 0-based indices (i, j); default :func:`tightest_plane`), with the rows of Z on those two states."""
    from matplotlib import colormaps

    pr = traj.problem
    plane = _plane(traj, plane)
    solved = _solved(traj)
    if not solved:
        raise ValueError("no solved step: the run has no tube to draw")
    fig, ax = _axes(ax, 6.0, 4.8)
    X0v = _x0_vertices(traj.design)
    first = solved[0]
    N = len(first.z) - 1
    stages = tube_stages(N)
    cmap = colormaps["viridis"]
    rings = [_section(first, l, X0v, plane, pr.n) for l in stages]
    for l, ring in zip(stages, rings):
        ax.plot(ring[:, 0], ring[:, 1], color=cmap(l / max(N, 1)), lw=1.4, label=f"$X_{{{l}|{first.k}}}$")
    centres = np.array([first.z[l] for l in range(N + 1)])[:, list(plane)]
    ax.plot(centres[:, 0], centres[:, 1], ":", color="0.4", lw=1, label=f"$z_{{l|{first.k}}}$, $l = 0..{N}$")
    xs = traj.x[:, list(plane)]
    ax.plot(xs[:, 0], xs[:, 1], "k.-", lw=0.8, ms=3, label="$x_k$ (closed loop)")
    _finish_plane(ax, pr, plane, _view(np.vstack([*rings, xs])), f"predicted tube at $k = {first.k}$")
    return fig


def tube_along_run(traj, plane=None, ax=None):
    """X_{0|k} (solid, containing x_k: circle) and X_{1|k} (dashed, containing x_{k+1}: cross) at the steps
    of :func:`run_tube_steps`, in the plane of two states (``plane`` as in :func:`predicted_tube`)."""
    from matplotlib import colormaps
    from matplotlib.lines import Line2D

    pr = traj.problem
    plane = _plane(traj, plane)
    solved = _solved(traj)
    if not solved:
        raise ValueError("no solved step: the run has no tube to draw")
    fig, ax = _axes(ax, 6.0, 4.8)
    X0v = _x0_vertices(traj.design)
    colors = colormaps["tab10"]
    xs = traj.x[:, list(plane)]
    pts = []  # the view is that of the picked sections (the transient is in the predicted-tube panel)
    for c, k in enumerate(run_tube_steps([r.k for r in solved])):
        r = traj.records[k]
        r0, r1 = _section(r, 0, X0v, plane, pr.n), _section(r, 1, X0v, plane, pr.n)
        pts += [r0, r1]
        ax.plot(r0[:, 0], r0[:, 1], color=colors(c), lw=1.4, label=f"$k = {k}$")
        ax.plot(r1[:, 0], r1[:, 1], color=colors(c), lw=1.2, ls="--")
        ax.plot(*xs[k], "o", color=colors(c), ms=5)
        if k + 1 < len(xs):
            ax.plot(*xs[k + 1], "x", color=colors(c), ms=7, mew=2)
    view = _view(np.vstack(pts))
    ax.plot(xs[:, 0], xs[:, 1], "-", color="0.6", lw=0.8, zorder=0)
    extra = [(Line2D([], [], color="0.3", lw=1.4), "$X_{0|k}$"), (Line2D([], [], color="0.3", lw=1.2, ls="--"), "$X_{1|k}$"),
             (Line2D([], [], color="0.3", marker="o", ls=""), "$x_k$"),
             (Line2D([], [], color="0.3", marker="x", ls=""), "$x_{k+1}$")]
    _finish_plane(ax, pr, plane, view, "along the run", extra)
    return fig


def tubes(traj, plane=None, axes=None):
    """Both tube panels side by side (``axes``: a pair of Axes): :func:`predicted_tube` and
    :func:`tube_along_run`, in the same plane."""
    plane = _plane(traj, plane)
    fig, left, right = _two_axes(axes, 12.0, 5.0)
    predicted_tube(traj, plane, ax=left)
    tube_along_run(traj, plane, ax=right)
    return fig


# -- parameter estimates -------------------------------------------------------------------------------------
def theta_widths(cert, ax=None):
    """max θ_i − min θ_i over Θ_k per parameter, and the diameter of Θ_k, against k."""
    s = cert.series
    widths = np.array(s["theta_width"], float)
    fig, ax = _axes(ax)
    for i in range(widths.shape[1]):
        ax.plot(s["k"], widths[:, i], marker=".", label=f"width in $\\theta_{{{i + 1}}}$")
    ax.plot(s["k"], s["theta_diameter"], "k--", lw=1, label=r"diameter of $\Theta_k$")
    ax.set_ylim(bottom=0)
    _finish(ax, r"width of $\Theta_k$")
    return fig


def theta_interval(traj, cert, ax=None):
    """p = 1: Θ_k = [lo_k, hi_k] against k, with θ* (unless measured) and θ̂_k."""
    s = cert.series
    fig, ax = _axes(ax)
    k = np.asarray(s["k"])
    lo, hi = np.asarray(s["theta_lower"], float)[:, 0], np.asarray(s["theta_upper"], float)[:, 0]
    ax.fill_between(k, lo, hi, step="mid", color="tab:blue", alpha=0.25, label=r"$\Theta_k$ (interval)")
    ax.step(k, lo, where="mid", color="tab:blue", lw=1)
    ax.step(k, hi, where="mid", color="tab:blue", lw=1)
    if not traj.measured:
        ax.plot(k, [traj.theta_star_at(int(j))[0] for j in k], "r--", lw=1.2, label=r"$\theta^*$")
    ax.plot(k, np.asarray(s["theta_hat"], float)[:, 0], "k.", ms=4, label=r"$\hat\theta_k$")
    _finish(ax, r"$\theta_1$")
    return fig


def theta_projection(traj, pair=(0, 1), ax=None):
    """The projections of Θ_0 and of the last Θ_k onto the parameters ``pair`` (0-based), with θ* (unless
    measured) and the last θ̂_k."""
    from amcp_drake.model import polytope

    i, j = pair
    first, last = traj.records[0], traj.records[-1]
    fig, ax = _axes(ax, 4.5, 3.5)
    for r, color in ((first, "tab:blue"), (last, "tab:orange")):
        ring = hull2d(polytope.vertices(r.H_theta, r.h_theta)[:, [i, j]])
        ax.fill(ring[:, 0], ring[:, 1], color=color, alpha=0.15)
        ax.plot(ring[:, 0], ring[:, 1], color=color, lw=1.4, label=f"$\\Theta_{{{r.k}}}$")
    if not traj.measured:
        star = traj.theta_star_at(last.k)
        ax.plot(star[i], star[j], "r*", ms=11, label=r"$\theta^*$")
    ax.plot(last.theta_hat[i], last.theta_hat[j], "kx", ms=8, mew=2, label=f"$\\hat\\theta_{{{last.k}}}$")
    ax.set_xlabel(f"$\\theta_{{{i + 1}}}$")
    ax.set_ylabel(f"$\\theta_{{{j + 1}}}$")
    ax.grid(alpha=0.3)
    return fig


def theta_projections(traj, max_pairs: int = 6):
    """:func:`theta_projection` for each pair of parameters (at most ``max_pairs``) side by side, one legend."""
    from matplotlib.figure import Figure

    p = traj.problem.p
    pairs = [(i, j) for i in range(p) for j in range(i + 1, p)][:max_pairs]
    fig = Figure(figsize=(3.2 * len(pairs) + 1.8, 3.5), layout="constrained")
    for idx, pair in enumerate(pairs):
        ax = fig.add_subplot(1, len(pairs), idx + 1)
        theta_projection(traj, pair, ax=ax)
        if idx == len(pairs) - 1:
            legend_outside(ax)
    return fig


def theta_hat(traj, cert, ax=None):
    """θ̂_k (dots) against k, with θ*_i (dashed, same colour; a line per step when θ* varies)."""
    s = cert.series
    th = np.array(s["theta_hat"], float)
    fig, ax = _axes(ax, 8.0, 3.6)
    varying = np.ndim(traj.theta_star) == 2
    for i, line in enumerate(_dotted_columns(ax, s["k"], th, r"\hat\theta")):
        if traj.measured:  # θ* unknown: the estimates alone
            continue
        label = f"$\\theta^*_{{{i + 1}}}$" + (" (varying)" if varying else "")
        if varying:
            ax.plot(range(len(traj.theta_star)), np.asarray(traj.theta_star)[:, i], ls="--", lw=1,
                    color=line.get_color(), label=label)
        else:
            ax.axhline(traj.theta_star[i], ls="--", lw=1, color=line.get_color(), label=label)
    _finish(ax, "parameter", ncol=2)
    return fig


def lemma5(cert, ax=None):
    """Both sides of Lemma 5's inequality, as running sums over m."""
    s = cert.series
    m = np.arange(len(s["lemma5_lhs"]))
    fig, ax = _axes(ax)
    ax.plot(m, s["lemma5_lhs"], marker=".",
            label=r"$\frac{1}{\mu}\|\hat\theta_{m+1}-\theta^*\|^2 + \sum_{k\leq m}\|\tilde x_{1|k}\|^2$")
    ax.plot(m, s["lemma5_rhs"], marker=".", label=r"$\frac{1}{\mu}\|\hat\theta_0-\theta^*\|^2 + \sum_{k\leq m}\|w_k\|^2$")
    _finish(ax, None, xlabel="$m$")
    return fig


def baseline(cert, axes=None):
    """The adaptive run beside the robust baseline (``figures.robust_baseline`` of the certificate): ‖x_k‖
    (left) and the parametric part of the one-step tube (right)."""
    b = cert.figures["robust_baseline"]
    fig, ax, bx = _two_axes(axes, 11.0, 3.4)
    for key, name, style in (("adaptive", "adaptive (this run)", "-"), ("robust", "robust baseline", "--")):
        run = b[key]
        ax.plot(range(len(run["state_norm"])), run["state_norm"], style, marker=".", ms=3, label=name)
        tube = [np.nan if v is None else v for v in run["parametric_tube"]]
        bx.plot(range(len(tube)), tube, style, marker=".", ms=3, label=name)
    ax.set_yscale("log")
    _finish(ax, r"$\|x_k\|$")
    bx.set_ylim(bottom=0)
    _finish(bx, "parametric part of $s_k$")
    return fig


def solve_times(cert, ax=None):
    """Per-step time of the QP (20) solver and of the whole step, in ms."""
    s = cert.series
    fig, ax = _axes(ax)
    for key, name in (("solver_time_s", "QP (20) solver"), ("step_time_s", "whole step")):
        ax.plot(s["k"], [np.nan if v is None else 1e3 * v for v in s[key]], marker=".", label=name)
    ax.set_ylim(bottom=0)
    _finish(ax, "time [ms]")
    return fig


__all__ = ["baseline", "inputs", "legend_outside", "lemma5", "predicted_tube", "signal_label", "solve_times",
           "state_row_scores", "states", "theta_hat", "theta_interval", "theta_projection", "theta_projections",
           "theta_widths", "tightest_plane", "tube_along_run", "tube_stages", "tubes"]
