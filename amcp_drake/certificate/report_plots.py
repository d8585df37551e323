"""The plots of report.html, each an SVG data URI and a caption note.

The figures are drawn by the public plotting functions (:mod:`amcp_drake.certificate.plots`, also
``amcp.plots``) and embedded as ``data:image/svg+xml;base64`` images (vector graphics, self-contained,
no id shared between figures). The SVG is made reproducible: fixed id salt, no date; text is drawn as
paths (the glyphs travel with the figure, so it looks the same without the fonts installed) and each
text's string is kept beside it as an SVG comment.
"""

from __future__ import annotations

import base64
import io

from amcp_drake.certificate import plots
from amcp_drake.certificate.certify import Certificate
from amcp_drake.online.simulate import Trajectory

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
#: The prefix of every plot's ``src``.
SVG_URI_PREFIX = "data:image/svg+xml;base64,"


def draw(plot_id: str, traj: Trajectory, cert: Certificate, plane: tuple[int, int] | None = None) -> tuple[str | None, str]:
    """(SVG data URI or None, caption note) for one plot id; ``plane``: the two states (0-based) of the tube
    plot (default :func:`amcp_drake.certificate.plots.tightest_plane`)."""
    if plot_id == "plot-tubes":
        return _plot_tubes(traj, cert, plane)
    drawer = {
        "plot-states": _plot_states, "plot-input": _plot_input,
        "plot-theta-widths": _plot_widths, "plot-theta-projections": _plot_projections,
        "plot-theta-hat": _plot_theta_hat, "plot-lemma5": _plot_lemma5, "plot-baseline": _plot_baseline,
        "plot-solve-times": _plot_times,
    }[plot_id]
    return drawer(traj, cert)


def _svg(fig) -> str:
    """The figure as a reproducible SVG data URI."""
    import matplotlib
    from matplotlib.backends.backend_svg import FigureCanvasSVG

    FigureCanvasSVG(fig)
    buf = io.BytesIO()
    with matplotlib.rc_context({"svg.hashsalt": "amcp-report", "svg.fonttype": "path"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    return SVG_URI_PREFIX + base64.b64encode(buf.getvalue()).decode("ascii")


def _plot_states(traj: Trajectory, cert: Certificate):
    return (_svg(plots.states(traj)),
            "Dashed: constraints of Z that bound a single state (mixed rows of Z are not drawn).")


def _plot_input(traj: Trajectory, cert: Certificate):
    return _svg(plots.inputs(traj)), "Dashed: input bounds of Z (rows of Z without state terms)."


def _plot_tubes(traj: Trajectory, cert: Certificate, plane: tuple[int, int] | None):
    pr = traj.problem
    if pr.n < 2:
        return None, "Tube cross-sections are drawn in a state plane: this problem has n = 1."
    solved = [r for r in traj.records if r.z is not None and r.alpha is not None]
    if not solved:
        return None, "No solved step: there is no tube to draw."
    chosen = plane is not None
    plane = plane if chosen else plots.tightest_plane(traj)
    first = solved[0]
    N = len(first.z) - 1
    stages = plots.tube_stages(N)
    steps = plots.run_tube_steps([r.k for r in solved])
    a, b = (pr.state_label(i) for i in plane)
    why = "chosen with --plane" if chosen else "the two states whose constraints the sets X_0|k, X_1|k come closest to"
    if pr.n == 2:
        where = ""
    else:
        scores = plots.state_row_scores(traj)
        use = ", ".join(f"{pr.state_label(i)} {scores[i]:.2f}" for i in range(pr.n) if scores[i] == scores[i])
        where = (f"Projections onto the plane ({a}, {b}) of the n = {pr.n} dimensional sets ({why}"
                 + ("" if chosen or not use else f"; largest use of a state row of Z, 1 = active: {use}") + "). ")
    return _svg(plots.tubes(traj, plane)), (
        where + f"Left: cross-sections X_l|{first.k} = z_l|{first.k} ⊕ α_l|{first.k} X0 of the tube predicted at "
        f"k = {first.k}, stages l = {', '.join(map(str, stages))} of N = {N}. Right: at steps "
        f"k = {', '.join(map(str, steps))}, X_0|k (solid, containing x_k: circle) and X_1|k (dashed, containing the "
        f"next state x_(k+1): cross). Red line and hatching: the boundary of Z for its rows on {a} and {b} only "
        "(other rows are not drawn).")


def _plot_widths(traj: Trajectory, cert: Certificate):
    return _svg(plots.theta_widths(cert)), (
        "max θ_i − min θ_i over Θ_k (from its vertices), and the diameter max ‖θ − θ'‖ over Θ_k, which Proposition "
        "23 drives to 0 under persistent excitation.")


def _plot_projections(traj: Trajectory, cert: Certificate):
    first, last = traj.records[0], traj.records[-1]
    if traj.problem.p == 1:
        s = cert.series
        lo, hi = s["theta_lower"], s["theta_upper"]
        return _svg(plots.theta_interval(traj, cert)), (
            f"p = 1: Θ_k is an interval; its bounds against k, from [{float(lo[0][0]):.4g}, {float(hi[0][0]):.4g}] "
            f"to [{float(lo[-1][0]):.4g}, {float(hi[-1][0]):.4g}].")
    try:
        fig = plots.theta_projections(traj)
    except ValueError as exc:
        return None, f"Θ_k vertices could not be enumerated: {exc}"
    with_star = "" if traj.measured else "θ* and "
    return _svg(fig), (f"Projections of Θ_{first.k} and Θ_{last.k} onto each pair of parameters, with {with_star}the "
                       f"last point estimate θ̂_{last.k}.")


def _plot_theta_hat(traj: Trajectory, cert: Certificate):
    src = _svg(plots.theta_hat(traj, cert))
    if traj.measured:
        return src, "Dots: θ̂_k (a measured run: the true parameter θ* is unknown)."
    return src, "Dots: θ̂_k; dashed, same colour: the true parameter θ*_i."


def _plot_lemma5(traj: Trajectory, cert: Certificate):
    if traj.measured:
        return None, "A measured run: Lemma 5's sums need θ* and the disturbances w_k, which are unknown."
    if not cert.series["lemma5_lhs"]:
        return None, "No transition recorded: Lemma 5 has no terms."
    return _svg(plots.lemma5(cert)), "Lemma 5 claims the first curve never exceeds the second."


def _plot_baseline(traj: Trajectory, cert: Certificate):
    b = cert.figures.get("robust_baseline")
    if not b or "adaptive" not in b:
        return None, "The robust baseline was not run (see the section above)."
    return _svg(plots.baseline(cert)), (
        "Left: ‖x_k‖ of both closed loops. Right: the parametric part of the one-step tube, what the set estimate Θ_k "
        "costs the tube at the applied input (the robust baseline keeps Θ_k = Θ).")


def _plot_times(traj: Trajectory, cert: Certificate):
    return _svg(plots.solve_times(cert)), f"Backend: {traj.backend}."
