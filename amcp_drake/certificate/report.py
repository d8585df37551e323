"""The certificate bundle: certificate.json, a self-contained report.html, trajectory.json.gz.

Plots are drawn with matplotlib's object API (``matplotlib.figure.Figure`` on the Agg canvas; no
pyplot, so no global figure state) and inlined as base64 PNG ``<img>`` elements with fixed ids;
the page is rendered with jinja2 from ``templates/report.html`` and loads nothing from the network.

:func:`write_outputs` writes the bundle atomically: all three files are first written into a
hidden staging directory inside ``out_dir``; only when every file is complete are they moved into
place with ``os.replace`` (atomic per file, same filesystem), and once that commit has started it
is completed even on Ctrl-C. A failure or interrupt before the commit removes the staging
directory and leaves ``out_dir`` as it was (a directory created for this call is removed again).
Other files in ``out_dir`` (e.g. ``compare.json`` of ``amcp compare``) are left alone.

A process killed while writing (SIGKILL: no handler runs) leaves its ``.certify-staging-<hex>``
behind. Each staging directory holds a lock file (``fcntl.flock``) for as long as its writer lives; the
kernel releases the lock when the process dies, so :func:`remove_stale_staging` (called by ``amcp
certify`` before it starts and by :func:`write_outputs`) removes exactly the staging directories whose
writer is gone, and never one that a concurrent ``amcp certify`` into the same folder is writing.
"""

from __future__ import annotations

import base64
import fcntl
import io
import json
import os
import re
import shutil
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.certificate.certify import Certificate, claim_to_dict
from amcp_drake.model.problem_io import check_output_dir
from amcp_drake.online.simulate import Trajectory

CERTIFICATE_FILE = "certificate.json"
REPORT_FILE = "report.html"
TRAJECTORY_FILE = "trajectory.json.gz"
OUTPUT_FILES = (CERTIFICATE_FILE, REPORT_FILE, TRAJECTORY_FILE)
#: Tubes X_{l|k} drawn in full (all l) for this many steps k, evenly spread over the run.
PREDICTED_TUBES = 3
#: Resolution of the inline PNGs (dots per inch; figures are 7-9 inches wide).
PNG_DPI = 90

#: (id, alt text) of every plot the report can contain, in page order.
PLOTS = (
    ("plot-states", "State trajectory x_k with state constraints"),
    ("plot-tubes", "Tube cross-sections X_0|k and predicted tubes in the state plane"),
    ("plot-input", "Input u_k with input bounds"),
    ("plot-theta-widths", "Width of the set estimate Theta_k per parameter"),
    ("plot-theta-projections", "2-D projections of Theta_0 and Theta_final"),
    ("plot-theta-hat", "Point estimate theta_hat_k against theta_star"),
    ("plot-lemma5", "Lemma 5 running sums, both sides"),
    ("plot-solve-times", "Per-step solve times"),
)


#: Name of the staging directories (``.certify-staging-`` + 32 hex digits) and of their lock file.
STAGING_PATTERN = re.compile(r"\.certify-staging-[0-9a-f]{32}")
STAGING_LOCK = ".lock"
#: A staging directory without a lock file is removed only when older than this (it may have been
#: created a moment ago by a writer that has not yet taken its lock).
STAGING_UNLOCKED_GRACE_S = 60.0


# -- output directory ------------------------------------------------------------------------------
def check_out_dir(out_dir: str | os.PathLike) -> Path:
    """Refuse an output path that is empty, exists but is not a directory, lies below a file or cannot
    be written (e.g. in /proc). Raises ProblemError (exit code 2)."""
    return check_output_dir("--out", out_dir)


def remove_stale_staging(out_dir: str | os.PathLike) -> list[Path]:
    """Remove the ``.certify-staging-<hex>`` directories in ``out_dir`` left by killed writers (their
    lock is free); return the removed paths."""
    out = Path(out_dir)
    removed: list[Path] = []
    if not out.is_dir():
        return removed
    for entry in out.iterdir():
        if STAGING_PATTERN.fullmatch(entry.name) and entry.is_dir() and not entry.is_symlink() \
                and not _staging_in_use(entry):
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed


def _staging_in_use(staging: Path) -> bool:
    """True when a live process holds the staging folder's lock (or, without a lock file, when the
    folder is younger than STAGING_UNLOCKED_GRACE_S: its writer may not have taken the lock yet)."""
    try:
        with open(staging / STAGING_LOCK, "rb") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            return False  # closing the file releases the lock taken here
    except FileNotFoundError:
        return time.time() - staging.stat().st_mtime < STAGING_UNLOCKED_GRACE_S
    except OSError:
        return True  # unreadable: leave it alone


def write_outputs(out_dir: str | os.PathLike, traj: Trajectory, cert: Certificate) -> Path:
    """Write certificate.json, report.html and trajectory.json.gz into ``out_dir`` atomically."""
    out = check_out_dir(out_dir)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(out)
    staging = out / f".certify-staging-{uuid.uuid4().hex}"
    lock = None
    try:  # a failure (a full disk) or an interrupt before the commit leaves nothing behind
        staging.mkdir()
        lock = open(staging / STAGING_LOCK, "wb")
        fcntl.flock(lock, fcntl.LOCK_EX)  # held while this process writes (the kernel drops it on a kill)
        (staging / CERTIFICATE_FILE).write_text(json.dumps(cert.to_dict(), indent=1, allow_nan=False))
        (staging / REPORT_FILE).write_text(render_report(traj, cert), encoding="utf-8")
        traj.save(staging / TRAJECTORY_FILE)
    except BaseException:
        if lock is not None:
            lock.close()
        shutil.rmtree(staging, ignore_errors=True)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    with lock:
        _commit(staging, out)
    return out


def _commit(staging: Path, out: Path) -> None:
    """Move the staged files into ``out``; an interrupt in between does not stop the remaining moves."""
    pending = list(OUTPUT_FILES)
    try:
        while pending:
            os.replace(staging / pending[0], out / pending[0])
            pending.pop(0)
    finally:
        for name in pending:  # only reached on an interrupt mid-commit: finish it, then re-raise
            if (staging / name).exists():
                os.replace(staging / name, out / name)
        shutil.rmtree(staging, ignore_errors=True)


# -- HTML ------------------------------------------------------------------------------------------
def render_report(traj: Trajectory, cert: Certificate) -> str:
    """The self-contained HTML report (template ``templates/report.html``)."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("amcp_drake.certificate", "templates"),
                             autoescape=jinja2.select_autoescape(["html"]), undefined=jinja2.StrictUndefined)
    plots = [dict(id=pid, alt=alt, src=src, note=note) for pid, alt, (src, note) in
             ((pid, alt, _draw(pid, traj, cert)) for pid, alt in PLOTS)]
    claims = [claim_to_dict(c) for c in cert.claims]
    return env.get_template("report.html").render(cert=cert.to_dict(), claims=claims, plots=plots,
                                                  fmt=_fmt, vec=_vec)


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(value)
    value = float(value)
    if not np.isfinite(value):
        return str(value)
    return f"{value:.{digits}e}" if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e4) else f"{value:.{digits}g}"


def _vec(values) -> str:
    return "[" + ", ".join(_fmt(v, 4) for v in np.ravel(values)) + "]"


# -- plots ----------------------------------------------------------------------------------------
def _png(fig) -> str:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=PNG_DPI)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _figure(width: float = 8.0, height: float = 3.2):
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), layout="constrained")


def _dotted_columns(ax, k, values: np.ndarray, label: str) -> list:
    """One dotted line per column of the per-step matrix ``values`` against k, labelled ``label`` + index."""
    return [ax.plot(k, values[:, i], marker=".", label=f"{label}{i + 1}")[0] for i in range(values.shape[1])]


def _finish(ax, ylabel: str | None, xlabel: str = "step k", ncol: int = 1) -> None:
    """The axis labels, legend and grid every time-series plot of the report shares."""
    ax.set_xlabel(xlabel)
    if ylabel is not None:
        ax.set_ylabel(ylabel)
    ax.legend(fontsize="small", ncol=ncol)
    ax.grid(alpha=0.3)


def _draw(plot_id: str, traj: Trajectory, cert: Certificate) -> tuple[str | None, str]:
    """(PNG data URI or None, caption note) for one plot id."""
    drawer = {
        "plot-states": _plot_states, "plot-tubes": _plot_tubes, "plot-input": _plot_input,
        "plot-theta-widths": _plot_widths, "plot-theta-projections": _plot_projections,
        "plot-theta-hat": _plot_theta_hat, "plot-lemma5": _plot_lemma5, "plot-solve-times": _plot_times,
    }[plot_id]
    return drawer(traj, cert)


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


def _plot_states(traj: Trajectory, cert: Certificate):
    return (_plot_signal(traj, on_state=True),
            "Dashed: constraints of Z that bound a single state (mixed rows of Z are not drawn).")


def _plot_input(traj: Trajectory, cert: Certificate):
    return _plot_signal(traj, on_state=False), "Dashed: input bounds of Z (rows of Z without state terms)."


def _plot_signal(traj: Trajectory, on_state: bool) -> str:
    """x_k (dots) or u_k (held over the step) against k, each with the rows of Z that bound it alone."""
    pr = traj.problem
    values, symbol, width = (traj.x, "x", pr.n) if on_state else (traj.u, "u", pr.m)
    bounds = _single_bounds(pr.F, pr.G, on_state)
    fig = _figure()
    ax = fig.add_subplot()
    k = np.arange(len(values))
    for j in range(width):
        if on_state:
            line, = ax.plot(k, values[:, j], marker=".", label=f"{symbol}{j + 1}")
        else:
            line, = ax.step(k, values[:, j], where="post", label=f"{symbol}{j + 1}")
        for idx, bound in bounds:
            if idx == j:
                ax.axhline(bound, ls="--", color=line.get_color(), lw=1,
                           label=f"constraint on x{j + 1}" if on_state else None)
    _include_bounds(ax, values, [b for _, b in bounds])
    _finish(ax, "state" if on_state else "input", ncol=2 if on_state else 1)
    return _png(fig)


def _include_bounds(ax, values: np.ndarray, bounds: list[float]) -> None:
    """y-limits that show the data and every constraint line (axhline does not autoscale)."""
    points = np.concatenate([np.ravel(values), bounds]) if len(bounds) else np.ravel(values)
    if points.size == 0:
        return
    lo, hi = float(np.min(points)), float(np.max(points))
    pad = 0.05 * max(hi - lo, 1e-9)
    ax.set_ylim(lo - pad, hi + pad)


def _polygon(vertices: np.ndarray) -> np.ndarray:
    centre = vertices.mean(axis=0)
    order = np.argsort(np.arctan2(vertices[:, 1] - centre[1], vertices[:, 0] - centre[0]))
    closed = vertices[order]
    return np.vstack([closed, closed[:1]])


def _plot_tubes(traj: Trajectory, cert: Certificate):
    pr, d = traj.problem, traj.design
    if pr.n != 2:
        return None, f"Tube cross-sections are drawn for n = 2 only (this problem has n = {pr.n})."
    from amcp_drake.model import polytope

    X0v = polytope.vertices(d.H_x, np.ones(len(d.H_x)))
    fig = _figure(8.0, 6.0)
    ax = fig.add_subplot()
    solved = [r for r in traj.records if r.z is not None and r.alpha is not None]
    for r in solved:
        poly = _polygon(r.z[0] + r.alpha[0] * X0v)
        ax.plot(poly[:, 0], poly[:, 1], color="tab:blue", lw=0.8, alpha=0.5)
    picks = sorted({solved[int(i)].k for i in np.linspace(0, len(solved) - 1, min(PREDICTED_TUBES, len(solved)))}) \
        if solved else []
    colors = ["tab:orange", "tab:green", "tab:purple", "tab:brown"]
    for c, k in zip(colors, picks):
        r = traj.records[k]
        for l in range(len(r.z)):
            poly = _polygon(r.z[l] + r.alpha[l] * X0v)
            ax.fill(poly[:, 0], poly[:, 1], color=c, alpha=0.12)
            ax.plot(poly[:, 0], poly[:, 1], color=c, lw=1, label=f"X_l|{k}, l = 0..{len(r.z) - 1}" if l == 0 else None)
    ax.plot(traj.x[:, 0], traj.x[:, 1], "k.-", lw=1, label="x_k")
    xlim, ylim = ax.get_xlim(), ax.get_ylim()
    for row, grow in zip(pr.F, pr.G):
        if np.any(grow) or not np.any(row):
            continue
        # F_i x = 1 within the current view; shade the violating side F_i x > 1
        xs = np.linspace(*xlim, 200)
        ys = np.linspace(*ylim, 200)
        XX, YY = np.meshgrid(xs, ys)
        ax.contourf(XX, YY, row[0] * XX + row[1] * YY, levels=[1.0, np.inf], colors=["tab:red"], alpha=0.15)
        ax.contour(XX, YY, row[0] * XX + row[1] * YY, levels=[1.0], colors=["tab:red"], linestyles="--", linewidths=1)
    ax.set_xlim(xlim)
    ax.set_ylim(ylim)
    ax.set_xlabel("x1")
    ax.set_ylabel("x2")
    ax.legend(fontsize="small", loc="best")
    ax.grid(alpha=0.3)
    return _png(fig), ("Blue: X_0|k at every solved step; filled: the full predicted tube X_l|k at a few steps; "
                       "red: states excluded by Z (rows of Z without input terms).")


def _plot_widths(traj: Trajectory, cert: Certificate):
    s = cert.series
    widths = np.array(s["theta_width"], float)
    fig = _figure()
    ax = fig.add_subplot()
    _dotted_columns(ax, s["k"], widths, "θ")
    ax.plot(s["k"], s["theta_diameter"], "k--", lw=1, label="diameter")
    ax.set_ylim(bottom=0)
    _finish(ax, "width of Θ_k")
    return _png(fig), "max θ_i − min θ_i over Θ_k (from its vertices), and the diameter max ‖θ − θ'‖ (Prop. 23)."


def _hull2d(points: np.ndarray) -> np.ndarray:
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
        ring = points[hull.vertices]
        return np.vstack([ring, ring[:1]])
    except (QhullError, ValueError):
        return points[np.lexsort(points.T[::-1])]


def _plot_projections(traj: Trajectory, cert: Certificate):
    from amcp_drake.model import polytope

    pr = traj.problem
    first, last = traj.records[0], traj.records[-1]
    try:
        v0 = polytope.vertices(first.H_theta, first.h_theta)
        v1 = polytope.vertices(last.H_theta, last.h_theta)
    except ValueError as exc:
        return None, f"Θ_k vertices could not be enumerated: {exc}"
    pairs = [(i, j) for i in range(pr.p) for j in range(i + 1, pr.p)][:6] or [(0, 0)]
    fig = _figure(3.2 * len(pairs) + 0.5, 3.4)
    for idx, (i, j) in enumerate(pairs):
        ax = fig.add_subplot(1, len(pairs), idx + 1)
        if i == j:  # p = 1: intervals on a line
            for y, v, name in ((0.1, v0, "Θ_0"), (0.0, v1, f"Θ_{last.k}")):
                ax.plot([v.min(), v.max()], [y, y], lw=4, label=name)
            ax.plot(traj.theta_star_at(last.k)[0], 0.05, "r*", ms=10, label="θ*")
            ax.set_yticks([])
        else:
            for v, name, style in ((v0, "Θ_0", "-"), (v1, f"Θ_{last.k}", "-")):
                ring = _hull2d(v[:, [i, j]])
                ax.fill(ring[:, 0], ring[:, 1], alpha=0.2)
                ax.plot(ring[:, 0], ring[:, 1], style, lw=1.2, label=name)
            ax.plot(traj.theta_star_at(last.k)[i], traj.theta_star_at(last.k)[j], "r*", ms=10, label="θ*")
            ax.plot(last.theta_hat[i], last.theta_hat[j], "kx", ms=8, label=f"θ̂_{last.k}")
            ax.set_xlabel(f"θ{i + 1}")
            ax.set_ylabel(f"θ{j + 1}")
        ax.grid(alpha=0.3)
        if idx == 0:
            ax.legend(fontsize="x-small")
    return _png(fig), "Projections of the first and last set estimates onto each pair of parameters."


def _plot_theta_hat(traj: Trajectory, cert: Certificate):
    s = cert.series
    th = np.array(s["theta_hat"], float)
    fig = _figure()
    ax = fig.add_subplot()
    for i, line in enumerate(_dotted_columns(ax, s["k"], th, "θ̂")):
        if np.ndim(traj.theta_star) == 2:
            ax.plot(range(len(traj.theta_star)), np.asarray(traj.theta_star)[:, i], ls="--", lw=1, color=line.get_color())
        else:
            ax.axhline(traj.theta_star[i], ls="--", lw=1, color=line.get_color())
    _finish(ax, "parameter", ncol=3)
    return _png(fig), "Dashed: the true parameter θ*."


def _plot_lemma5(traj: Trajectory, cert: Certificate):
    s = cert.series
    if not s["lemma5_lhs"]:
        return None, "No transition recorded: Lemma 5 has no terms."
    m = np.arange(len(s["lemma5_lhs"]))
    fig = _figure()
    ax = fig.add_subplot()
    ax.plot(m, s["lemma5_lhs"], marker=".", label="(1/μ)‖θ̂_(m+1) − θ*‖² + Σ‖x̃_(1|k)‖²")
    ax.plot(m, s["lemma5_rhs"], marker=".", label="(1/μ)‖θ̂_0 − θ*‖² + Σ‖w_k‖²")
    _finish(ax, None, xlabel="m")
    return _png(fig), "Lemma 5 claims the first curve never exceeds the second."


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
