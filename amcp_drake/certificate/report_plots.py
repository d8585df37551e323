"""The plots of report.html, each a base64 PNG data URI and a caption note.

Drawn with matplotlib's object API (``matplotlib.figure.Figure`` on the Agg canvas; no pyplot, so no
global figure state). Labels use matplotlib's mathtext ($\\Theta_k$, $\\hat\\theta_k$, $X_{l|k}$), the
notation of the paper and of the report's text.
"""

from __future__ import annotations

import base64
import io

import numpy as np

from amcp_drake.certificate.certify import Certificate
from amcp_drake.online.simulate import Trajectory

#: Resolution of the inline PNGs (dots per inch; figures are 7-10 inches wide).
PNG_DPI = 90
#: Steps k at which the tube plot shows X_{0|k} and X_{1|k} along the run (evenly spread, k = 0 first).
RUN_TUBE_STEPS = 4
#: Stages l of the predicted tube X_{l|0} drawn: 0, 1, 2, then every ⌈N/4⌉-th, and N.
TUBE_EARLY_STAGES = 3

#: (id, alt text) of every plot the report can contain.
PLOTS = (
    ("plot-states", "State trajectory x_k with state constraints"),
    ("plot-tubes", "Predicted tube X_l|0 at a few stages l, and X_0|k, X_1|k along the run, with the boundary of Z"),
    ("plot-input", "Input u_k with input bounds"),
    ("plot-theta-widths", "Width of the set estimate Θ_k per parameter"),
    ("plot-theta-projections", "Θ_0 and the last Θ_k with θ* and θ̂: the interval over k for p = 1, "
                               "2-D projections for p ≥ 2"),
    ("plot-theta-hat", "Point estimate θ̂_k against θ*"),
    ("plot-lemma5", "Lemma 5 running sums, both sides"),
    ("plot-baseline", "Adaptive run and robust baseline on the same disturbance: ‖x_k‖ and the parametric "
                      "one-step tube"),
    ("plot-solve-times", "Per-step solve times"),
)


def draw(plot_id: str, traj: Trajectory, cert: Certificate) -> tuple[str | None, str]:
    """(PNG data URI or None, caption note) for one plot id."""
    drawer = {
        "plot-states": _plot_states, "plot-tubes": _plot_tubes, "plot-input": _plot_input,
        "plot-theta-widths": _plot_widths, "plot-theta-projections": _plot_projections,
        "plot-theta-hat": _plot_theta_hat, "plot-lemma5": _plot_lemma5, "plot-baseline": _plot_baseline,
        "plot-solve-times": _plot_times,
    }[plot_id]
    return drawer(traj, cert)


# -- helpers -----------------------------------------------------------------------------------------
def _png(fig) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=PNG_DPI)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(width: float = 8.0, height: float = 3.2):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _dotted_columns(ax, k, values: np.ndarray, symbol: str) -> list:
    """One dotted line per column of the per-step matrix ``values`` against k, labelled $symbol_i$."""
    return [ax.plot(k, values[:, i], marker=".", label=f"${symbol}_{{{i + 1}}}$")[0] for i in range(values.shape[1])]


def _finish(ax, ylabel: str | None, xlabel: str = "step $k$", ncol: int = 1, loc: str = "best") -> None:
    """The axis labels, legend and grid every time-series plot of the report shares."""
    ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    ax.legend(fontsize="small", ncol=ncol, loc=loc)
    ax.grid(alpha=0.3)


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


def _hull2d(points: np.ndarray) -> np.ndarray:
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


def _plot_states(traj: Trajectory, cert: Certificate):
    return (_plot_signal(traj, on_state=True),
            "Dashed: constraints of Z that bound a single state (mixed rows of Z are not drawn).")


def _plot_input(traj: Trajectory, cert: Certificate):
    return _plot_signal(traj, on_state=False), "Dashed: input bounds of Z (rows of Z without state terms)."


def _plot_signal(traj: Trajectory, on_state: bool) -> str:
    """x_k (dots) or u_k (held over the step) against k, each with the rows of Z that bound it alone."""
    pr = traj.problem
    values, width = (traj.x, pr.n) if on_state else (traj.u, pr.m)
    bounds = _single_bounds(pr.F, pr.G, on_state)
    fig = _figure()
    ax = fig.add_subplot()
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
    _finish(ax, "state" if on_state else "input", ncol=2)
    return _png(fig)


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


def _z_boundary(ax, pr, xlim, ylim) -> bool:
    """Draw F_i x = 1 for the rows of Z without input terms inside the view, hatching the excluded side;
    True when any row was drawn."""
    xs = np.linspace(*xlim, 300)
    ys = np.linspace(*ylim, 300)
    XX, YY = np.meshgrid(xs, ys)
    drawn = False
    for row, grow in zip(pr.F, pr.G):
        if np.any(grow) or not np.any(row[:2]) or np.any(row[2:]):
            continue
        value = row[0] * XX + row[1] * YY
        if not (np.min(value) <= 1.0 <= np.max(value)):
            continue
        ax.contourf(XX, YY, value, levels=[1.0, np.inf], colors="none", hatches=["////"])
        ax.contour(XX, YY, value, levels=[1.0], colors=["tab:red"], linewidths=1.5)
        drawn = True
    return drawn


def _view(points: np.ndarray, pad: float = 0.08) -> tuple[tuple[float, float], tuple[float, float]]:
    lo, hi = points.min(axis=0), points.max(axis=0)
    span = np.maximum(hi - lo, 1e-9)
    return ((lo[0] - pad * span[0], hi[0] + pad * span[0]), (lo[1] - pad * span[1], hi[1] + pad * span[1]))


def _plot_tubes(traj: Trajectory, cert: Certificate):
    pr, d = traj.problem, traj.design
    if pr.n < 2:
        return None, "Tube cross-sections are drawn in a state plane: this problem has n = 1."
    solved = [r for r in traj.records if r.z is not None and r.alpha is not None]
    if not solved:
        return None, "No solved step: there is no tube to draw."
    from matplotlib import colormaps
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    from amcp_drake.model import polytope

    X0v = polytope.vertices(d.H_x, np.ones(len(d.H_x)))
    fig = _figure(11.0, 5.2)
    first = solved[0]
    N = len(first.z) - 1
    stages = tube_stages(N)
    steps = run_tube_steps([r.k for r in solved])

    def section(r, l):  # n > 2: the projection onto (x1, x2), the hull of the projected vertices
        points = r.z[l] + r.alpha[l] * X0v
        return _polygon(points) if pr.n == 2 else _hull2d(points[:, :2])

    # left: the tube predicted at the first solved step, a few stages
    ax = fig.add_subplot(1, 2, 1)
    cmap = colormaps["viridis"]
    rings = [section(first, l) for l in stages]
    for l, ring in zip(stages, rings):
        ax.plot(ring[:, 0], ring[:, 1], color=cmap(l / max(N, 1)), lw=1.4, label=f"$X_{{{l}|{first.k}}}$")
    centres = np.array([first.z[l] for l in range(N + 1)])
    ax.plot(centres[:, 0], centres[:, 1], ":", color="0.4", lw=1, label=f"$z_{{l|{first.k}}}$, $l = 0..{N}$")
    ax.plot(traj.x[:, 0], traj.x[:, 1], "k.-", lw=0.8, ms=3, label="$x_k$ (closed loop)")
    xlim, ylim = _view(np.vstack([*rings, traj.x[:, :2]]))
    # right: X_{0|k} (solid) and X_{1|k} (dashed) at a few steps, with x_k and x_{k+1}
    bx = fig.add_subplot(1, 2, 2)
    colors = colormaps["tab10"]
    pts = []  # the view is that of the picked sections (the transient is in the left panel)
    for i, k in enumerate(steps):
        r = traj.records[k]
        c = colors(i)
        r0, r1 = section(r, 0), section(r, 1)
        pts += [r0, r1]
        bx.plot(r0[:, 0], r0[:, 1], color=c, lw=1.4, label=f"$k = {k}$")
        bx.plot(r1[:, 0], r1[:, 1], color=c, lw=1.2, ls="--")
        bx.plot(*traj.x[k, :2], "o", color=c, ms=5)
        if k + 1 < len(traj.x):
            bx.plot(*traj.x[k + 1, :2], "x", color=c, ms=7, mew=2)
    bxlim, bylim = _view(np.vstack(pts))
    bx.plot(traj.x[:, 0], traj.x[:, 1], "-", color="0.6", lw=0.8, zorder=0)
    for axis, (lx, ly), title in ((ax, (xlim, ylim), f"predicted tube at $k = {first.k}$"),
                                  (bx, (bxlim, bylim), "along the run")):
        drawn = _z_boundary(axis, pr, lx, ly)
        axis.set_xlim(lx)
        axis.set_ylim(ly)
        axis.set_xlabel(signal_label(pr, 0))
        axis.set_ylabel(signal_label(pr, 1))
        axis.set_title(title, fontsize="medium")
        axis.grid(alpha=0.3)
        handles, labels = axis.get_legend_handles_labels()
        if axis is bx:
            handles += [Line2D([], [], color="0.3", lw=1.4), Line2D([], [], color="0.3", lw=1.2, ls="--"),
                        Line2D([], [], color="0.3", marker="o", ls=""), Line2D([], [], color="0.3", marker="x", ls="")]
            labels += ["$X_{0|k}$", "$X_{1|k}$", "$x_k$", "$x_{k+1}$"]
        if drawn:
            handles.append(Patch(facecolor="none", edgecolor="tab:red", hatch="////"))
            labels.append("boundary of Z, excluded side")
        axis.legend(handles, labels, fontsize="small", loc="best", ncol=2 if axis is bx else 1)
    projected = "" if pr.n == 2 else f"Projections onto the plane (x_1, x_2) of the n = {pr.n} dimensional sets. "
    return _png(fig), (projected + f"Left: cross-sections X_l|{first.k} = z_l|{first.k} ⊕ α_l|{first.k} X0 of the tube "
                       f"predicted at k = {first.k}, stages l = {', '.join(map(str, stages))} of N = {N}. Right: at "
                       f"steps k = {', '.join(map(str, steps))}, X_0|k (solid, containing x_k: circle) and X_1|k "
                       "(dashed, containing the next state x_(k+1): cross). Red line and hatching: the boundary of Z "
                       "for its rows on x_1, x_2 only (other rows are not drawn).")


# -- parameter estimates -------------------------------------------------------------------------------------
def _plot_widths(traj: Trajectory, cert: Certificate):
    s = cert.series
    widths = np.array(s["theta_width"], float)
    fig = _figure()
    ax = fig.add_subplot()
    for i in range(widths.shape[1]):
        ax.plot(s["k"], widths[:, i], marker=".", label=f"width in $\\theta_{{{i + 1}}}$")
    ax.plot(s["k"], s["theta_diameter"], "k--", lw=1, label=r"diameter of $\Theta_k$")
    ax.set_ylim(bottom=0)
    _finish(ax, r"width of $\Theta_k$")
    return _png(fig), ("max θ_i − min θ_i over Θ_k (from its vertices), and the diameter max ‖θ − θ'‖ over Θ_k, "
                       "which Proposition 23 drives to 0 under persistent excitation.")


def _plot_projections(traj: Trajectory, cert: Certificate):
    from amcp_drake.model import polytope

    pr = traj.problem
    first, last = traj.records[0], traj.records[-1]
    star = None if traj.measured else traj.theta_star_at(last.k)  # a measured run: θ* unknown, not drawn
    if pr.p == 1:
        s = cert.series
        fig = _figure()
        ax = fig.add_subplot()
        k = np.asarray(s["k"])
        lo, hi = np.asarray(s["theta_lower"], float)[:, 0], np.asarray(s["theta_upper"], float)[:, 0]
        ax.fill_between(k, lo, hi, step="mid", color="tab:blue", alpha=0.25, label=r"$\Theta_k$ (interval)")
        ax.step(k, lo, where="mid", color="tab:blue", lw=1)
        ax.step(k, hi, where="mid", color="tab:blue", lw=1)
        if star is not None:
            stars = [traj.theta_star_at(int(j))[0] for j in k]
            ax.plot(k, stars, "r--", lw=1.2, label=r"$\theta^*$")
        ax.plot(k, np.asarray(s["theta_hat"], float)[:, 0], "k.", ms=4, label=r"$\hat\theta_k$")
        _finish(ax, r"$\theta_1$")
        return _png(fig), (f"p = 1: Θ_k is an interval; its bounds against k, from [{lo[0]:.4g}, {hi[0]:.4g}] to "
                           f"[{lo[-1]:.4g}, {hi[-1]:.4g}].")
    try:
        v0 = polytope.vertices(first.H_theta, first.h_theta)
        v1 = polytope.vertices(last.H_theta, last.h_theta)
    except ValueError as exc:
        return None, f"Θ_k vertices could not be enumerated: {exc}"
    pairs = [(i, j) for i in range(pr.p) for j in range(i + 1, pr.p)][:6]
    fig = _figure(3.2 * len(pairs) + 0.5, 3.5)
    for idx, (i, j) in enumerate(pairs):
        ax = fig.add_subplot(1, len(pairs), idx + 1)
        for v, name, color in ((v0, f"$\\Theta_{{{first.k}}}$", "tab:blue"),
                               (v1, f"$\\Theta_{{{last.k}}}$", "tab:orange")):
            ring = _hull2d(v[:, [i, j]])
            ax.fill(ring[:, 0], ring[:, 1], color=color, alpha=0.15)
            ax.plot(ring[:, 0], ring[:, 1], color=color, lw=1.4, label=name)
        if star is not None:
            ax.plot(star[i], star[j], "r*", ms=11, label=r"$\theta^*$")
        ax.plot(last.theta_hat[i], last.theta_hat[j], "kx", ms=8, mew=2, label=f"$\\hat\\theta_{{{last.k}}}$")
        ax.set_xlabel(f"$\\theta_{{{i + 1}}}$")
        ax.set_ylabel(f"$\\theta_{{{j + 1}}}$")
        ax.grid(alpha=0.3)
        if idx == 0:
            ax.legend(fontsize="x-small")
    with_star = "" if star is None else "θ* and "
    return _png(fig), (f"Projections of Θ_{first.k} and Θ_{last.k} onto each pair of parameters, with {with_star}the "
                       f"last point estimate θ̂_{last.k}.")


def _plot_theta_hat(traj: Trajectory, cert: Certificate):
    s = cert.series
    th = np.array(s["theta_hat"], float)
    fig = _figure(8.0, 3.6)
    ax = fig.add_subplot()
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
    _finish(ax, "parameter", ncol=2, loc="center left")
    ax.legend(fontsize="small", ncol=2, loc="center left", bbox_to_anchor=(1.01, 0.5))
    if traj.measured:
        return _png(fig), "Dots: θ̂_k (a measured run: the true parameter θ* is unknown)."
    return _png(fig), "Dots: θ̂_k; dashed, same colour: the true parameter θ*_i."


def _plot_lemma5(traj: Trajectory, cert: Certificate):
    s = cert.series
    if traj.measured:
        return None, "A measured run: Lemma 5's sums need θ* and the disturbances w_k, which are unknown."
    if not s["lemma5_lhs"]:
        return None, "No transition recorded: Lemma 5 has no terms."
    m = np.arange(len(s["lemma5_lhs"]))
    fig = _figure()
    ax = fig.add_subplot()
    ax.plot(m, s["lemma5_lhs"], marker=".",
            label=r"$\frac{1}{\mu}\|\hat\theta_{m+1}-\theta^*\|^2 + \sum_{k\leq m}\|\tilde x_{1|k}\|^2$")
    ax.plot(m, s["lemma5_rhs"], marker=".", label=r"$\frac{1}{\mu}\|\hat\theta_0-\theta^*\|^2 + \sum_{k\leq m}\|w_k\|^2$")
    _finish(ax, None, xlabel="$m$")
    return _png(fig), "Lemma 5 claims the first curve never exceeds the second."


# -- the robust baseline ---------------------------------------------------------------------------------
def _plot_baseline(traj: Trajectory, cert: Certificate):
    b = cert.figures.get("robust_baseline")
    if not b or "adaptive" not in b:
        return None, "The robust baseline was not run (see the section above)."
    fig = _figure(10.0, 3.4)
    ax = fig.add_subplot(1, 2, 1)
    bx = fig.add_subplot(1, 2, 2)
    for key, name, style in (("adaptive", "adaptive (this run)", "-"), ("robust", "robust baseline", "--")):
        run = b[key]
        ax.plot(range(len(run["state_norm"])), run["state_norm"], style, marker=".", ms=3, label=name)
        tube = [np.nan if v is None else v for v in run["parametric_tube"]]
        bx.plot(range(len(tube)), tube, style, marker=".", ms=3, label=name)
    ax.set_yscale("log")
    _finish(ax, r"$\|x_k\|$")
    bx.set_ylim(bottom=0)
    _finish(bx, "parametric part of $s_k$")
    return _png(fig), ("Left: ‖x_k‖ of both closed loops. Right: the parametric part of the one-step tube, what the "
                       "set estimate Θ_k costs the tube at the applied input (the robust baseline keeps Θ_k = Θ).")


def _plot_times(traj: Trajectory, cert: Certificate):
    s = cert.series
    fig = _figure()
    ax = fig.add_subplot()
    for key, name in (("solver_time_s", "QP (20) solver"), ("step_time_s", "whole step")):
        vals = [np.nan if v is None else 1e3 * v for v in s[key]]
        ax.plot(s["k"], vals, marker=".", label=name)
    ax.set_ylim(bottom=0)
    _finish(ax, "time [ms]")
    return _png(fig), f"Backend: {traj.backend}."
