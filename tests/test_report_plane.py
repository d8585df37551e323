"""The tube plot in any plane of two states, as SVG, with the problem's names and units on its axes.

A three-state problem (decoupled; every state bounded alone; states named p [m], v [m/s], phi [rad]) is
run for a few steps. Checked here: the default plane is the pair whose rows of Z the sections X_0|k, X_1|k
come closest to (recomputed here with the support of X0 from scipy's LP, not from the vertices the plotting
code enumerates); a chosen plane (``--plane``) appears in the report as an SVG whose axis labels name the
chosen states, and whose first cross-section spans z ± α·(support of X0) along them; legends lie outside
the data area; the functions of ``amcp.plots`` draw into a given Axes and return its Figure; and headless
Chromium paints the report's SVG tube plot (a screenshot, compared with the same report without that plot).
"""

from __future__ import annotations

import base64
import json
import re
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.optimize import linprog

from amcp_drake.certificate import plots
from amcp_drake.certificate.certify import certify
from amcp_drake.certificate.report import render_report, write_outputs
from amcp_drake.certificate.report_plots import SVG_URI_PREFIX
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec
from tests.browser import NO_CHROMIUM, find_chromium, headless
from tests.guards import GUARD_SECONDS

SVG = "{http://www.w3.org/2000/svg}"
BOUNDS = {"p": 2.0, "v": 1.0, "phi": 0.5}
LABELS = ("p [m]", "v [m/s]", "phi [rad]")


def three_state_spec() -> ProblemSpec:
    """x_i⁺ = 0.5 θ_i x_i + u_i + w_i (θ ∈ [−1, 1]³, |w_i| <= 0.05), |p| <= 2, |v| <= 1, |phi| <= 0.5, |u_i| <= 5;
    K = 0, P = 2 I (0.25 P + I − P < 0), X0 a box."""
    problem = Problem.from_matrices(
        np.zeros((3, 3)), np.eye(3), A=[np.diag(row) for row in 0.5 * np.eye(3)], B=np.zeros((3, 3, 3)),
        states=[("p", "m"), ("v", "m/s"), ("phi", "rad")], inputs=["F1", "F2", "F3"], W_box=[0.05] * 3,
        Theta_box=[(-1, 1)] * 3, x_bounds={k: (-b, b) for k, b in BOUNDS.items()},
        u_bounds={f"F{i}": (-5, 5) for i in (1, 2, 3)}, Q=np.eye(3), R=np.eye(3), N=2, name="three")
    return ProblemSpec(problem=problem, design=DesignOptions(x0_facets=6, K=np.zeros((3, 3)), P=2.0 * np.eye(3)))


@pytest.fixture(scope="module")
def run():
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = three_state_spec()
    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake")
    traj = simulate(ctrl, [0.6, 0.3, 0.2], [0.6, -0.4, 0.2], 4, "uniform", seed=0)
    cert = certify(traj, spec)
    assert cert.verdict == "pass"
    return traj, cert


def _support(H: np.ndarray, direction: np.ndarray) -> float:
    """max dᵀx over {H x <= 1}, by scipy's LP."""
    res = linprog(-direction, A_ub=H, b_ub=np.ones(len(H)), bounds=[(None, None)] * H.shape[1], method="highs")
    assert res.status == 0
    return float(-res.fun)


def _row_use(traj) -> dict[str, float]:
    """max of |x_i| / bound_i over the states and the sections X_0|k, X_1|k (support of X0 by LP), per state."""
    d = traj.design
    use = {}
    for i, (name, bound) in enumerate(BOUNDS.items()):
        e = np.eye(3)[i]
        r_plus, r_minus = _support(d.H_x, e), _support(d.H_x, -e)
        values = [abs(x[i]) for x in traj.x]
        for rec in traj.records:
            if rec.z is None:
                continue
            for z, alpha in zip(rec.z[:2], rec.alpha[:2]):  # X_0|k and X_1|k
                values += [z[i] + alpha * r_plus, -(z[i] - alpha * r_minus)]
        use[name] = max(values) / bound
    return use


def test_the_default_plane_is_the_pair_whose_rows_the_tubes_come_closest_to(run):
    traj, _ = run
    use = _row_use(traj)
    names = list(BOUNDS)
    top_two = sorted(sorted(names, key=lambda n: -use[n])[:2], key=names.index)
    assert plots.tightest_plane(traj) == tuple(names.index(n) for n in top_two)
    np.testing.assert_allclose(plots.state_row_scores(traj), [use[n] for n in names], rtol=1e-9)


def _svg_root(data_uri: str) -> ET.Element:
    """The parsed SVG of a data URI (comments kept: matplotlib writes each text's string beside its glyphs)."""
    assert data_uri.startswith(SVG_URI_PREFIX)
    raw = base64.b64decode(data_uri[len(SVG_URI_PREFIX):], validate=True)
    root = ET.fromstring(raw, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    assert root.tag == f"{SVG}svg"
    return root


def _axis_labels(root: ET.Element) -> list[str]:
    """The label text of each axis (x, y of the first panel, then of the next ...): the comment of the
    text group that is a direct child of a ``matplotlib.axis_N`` group (tick labels sit in tick groups)."""
    out = []
    for g in root.iter(f"{SVG}g"):
        if g.get("id", "").startswith("matplotlib.axis_"):
            for child in g:
                if child.tag == f"{SVG}g" and child.get("id", "").startswith("text_"):
                    out += [c.text.strip() for c in child.iter() if c.tag is ET.Comment]
    return out


def _img_src(html: str, plot_id: str) -> str:
    found = re.search(rf'<img id="{plot_id}"[^>]*src="([^"]+)"', html)
    assert found, plot_id
    return found.group(1)


@pytest.mark.parametrize("plane", [(0, 2), (2, 1)])
def test_the_report_holds_an_svg_tube_plot_of_the_chosen_plane(run, plane):
    traj, cert = run
    root = _svg_root(_img_src(render_report(traj, cert, plane), "plot-tubes"))
    a, b = (LABELS[i] for i in plane)
    assert _axis_labels(root) == [a, b, a, b]  # both panels, horizontal axis first


def test_without_a_plane_the_report_draws_the_default_one(run):
    traj, cert = run
    i, j = plots.tightest_plane(traj)
    root = _svg_root(_img_src(render_report(traj, cert), "plot-tubes"))
    assert _axis_labels(root) == [LABELS[i], LABELS[j]] * 2


def test_every_report_plot_is_an_svg_of_a_useful_size(run):
    traj, cert = run
    html = render_report(traj, cert)
    for plot_id, _ in (p for p in __import__("amcp_drake.certificate.report_plots", fromlist=["PLOTS"]).PLOTS
                       if p[0] not in ("plot-baseline", "plot-lemma5")):
        root = _svg_root(_img_src(html, plot_id))
        width, height = (float(root.get(k).removesuffix("pt")) for k in ("width", "height"))
        assert width >= 300 and height >= 150, (plot_id, width, height)
        assert len(list(root.iter(f"{SVG}path"))) >= 10, plot_id


def test_the_first_section_spans_z_plus_minus_alpha_times_the_support_of_x0(run):
    traj, _ = run
    plane = (0, 2)
    fig = plots.predicted_tube(traj, plane)
    (line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "$X_{0|0}$"]
    rec, H = traj.records[0], traj.design.H_x
    for axis, i in enumerate(plane):
        data = np.asarray(line.get_data()[axis])
        e = np.eye(3)[i]
        lo = rec.z[0][i] - rec.alpha[0] * _support(H, -e)
        hi = rec.z[0][i] + rec.alpha[0] * _support(H, e)
        assert data.min() == pytest.approx(lo, abs=1e-9) and data.max() == pytest.approx(hi, abs=1e-9)


def test_legends_lie_outside_the_data_area_and_inside_the_figure(run):
    traj, cert = run
    figures = [plots.states(traj), plots.inputs(traj), plots.tubes(traj, (0, 2)), plots.theta_widths(cert),
               plots.theta_projections(traj), plots.theta_hat(traj, cert), plots.lemma5(cert), plots.solve_times(cert)]
    for fig in figures:
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig).draw()
        legends = 0
        for ax in fig.axes:
            legend = ax.get_legend()
            if legend is None:
                continue
            legends += 1
            box, data = legend.get_window_extent(), ax.get_window_extent()
            assert not box.overlaps(data), (fig.axes.index(ax), box, data)
            assert box.x1 <= fig.bbox.x1 + 1 and box.y0 >= fig.bbox.y0 - 1, (box, fig.bbox)
        assert legends >= 1


def test_plot_functions_draw_into_a_given_axes_and_return_its_figure(run):
    from matplotlib.figure import Figure

    traj, cert = run
    fig = Figure()
    left, right = fig.subplots(1, 2)
    assert plots.states(traj, ax=right) is fig
    assert not left.get_lines() and len(right.get_lines()) >= 3
    fig2 = Figure()
    pair = fig2.subplots(1, 2)
    assert plots.tubes(traj, plane=(1, 2), axes=pair) is fig2
    assert [ax.get_xlabel() for ax in pair] == [LABELS[1]] * 2
    new = plots.theta_hat(traj, cert)
    assert isinstance(new, Figure) and new is not fig and len(new.axes) == 1
    with pytest.raises(ValueError, match="plane"):
        plots.tubes(traj, plane=(1, 1))


def test_amcp_plots_is_the_public_module():
    import amcp_drake as amcp

    assert amcp.plots is plots and "plots" in dir(amcp)


# -- the CLI --------------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def saved(run, tmp_path_factory):
    traj, _ = run
    path = tmp_path_factory.mktemp("traj") / "trajectory.json.gz"
    traj.save(path)
    return path


@pytest.mark.parametrize("plane, labels", [("phi,p", (LABELS[2], LABELS[0])), ("1,2", (LABELS[0], LABELS[1]))])
def test_certify_plane_by_name_or_index(saved, tmp_path, plane, labels):
    from amcp_drake.cli import main

    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["certify", "--trajectory", str(saved), "--plane", plane, "--out", str(out)])
    assert res.exit_code == 0, res.output
    root = _svg_root(_img_src((out / "report.html").read_text(encoding="utf-8"), "plot-tubes"))
    assert _axis_labels(root) == list(labels) * 2


@pytest.mark.parametrize("plane", ["1,1", "p,q", "1,2,3", "0,2", "4,1", "p"])
def test_certify_bad_plane_exits_2_and_writes_nothing(saved, tmp_path, plane):
    from amcp_drake.cli import main

    out = tmp_path / "out"
    res = CliRunner().invoke(main, ["certify", "--trajectory", str(saved), "--plane", plane, "--out", str(out)])
    assert res.exit_code == 2, res.output
    assert "--plane" in res.output and "Traceback" not in res.output
    assert not out.exists()


# -- the browser ----------------------------------------------------------------------------------------------
def _red_pixels(png: Path) -> int:
    """Pixels close to matplotlib's tab:red (#d62728), the boundary of Z in the tube plot."""
    from PIL import Image

    rgb = np.asarray(Image.open(png).convert("RGB"), dtype=int)
    return int(np.sum(np.all(np.abs(rgb - np.array([214, 39, 40])) <= 30, axis=-1)))


def test_headless_chromium_paints_the_svg_tube_plot_of_a_chosen_plane(run, tmp_path):
    """A screenshot of the whole report (tube plot in the plane p, phi) shows the red boundary of Z; the same
    report with that image emptied shows far fewer red pixels (so they come from the tube plot's SVG)."""
    chromium = find_chromium()
    if chromium is None:
        pytest.skip(NO_CHROMIUM)
    traj, cert = run
    out = write_outputs(tmp_path / "out", traj, cert, plane=(0, 2))
    html = (out / "report.html").read_text(encoding="utf-8")
    empty = SVG_URI_PREFIX + base64.b64encode(b'<svg xmlns="http://www.w3.org/2000/svg" width="864pt" '
                                              b'height="360pt"></svg>').decode()
    control = tmp_path / "control.html"
    control.write_text(html.replace(_img_src(html, "plot-tubes"), empty), encoding="utf-8")
    counts = []
    for page in (out / "report.html", control):
        shot = tmp_path / f"{page.stem}.png"
        cmd = headless(chromium, tmp_path / "profile", "--hide-scrollbars", "--window-size=1200,16000",
                       f"--screenshot={shot}", page.resolve().as_uri())
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=GUARD_SECONDS)
        assert done.returncode == 0 and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", done.stderr[-2000:]
        counts.append(_red_pixels(shot))
    painted, without = counts
    assert painted - without >= 200, counts
    assert json.loads((out / "certificate.json").read_text())["verdict"] == "pass"


def test_the_svg_figures_are_reproducible(run):
    """The same run gives byte-identical figures (fixed id salt, no date), so two reports can be compared."""
    traj, cert = run
    first, second = render_report(traj, cert, (0, 2)), render_report(traj, cert, (0, 2))
    for plot_id in ("plot-tubes", "plot-states", "plot-theta-hat"):
        assert _img_src(first, plot_id) == _img_src(second, plot_id), plot_id
    assert _img_src(first, "plot-tubes") != _img_src(render_report(traj, cert, (0, 1)), "plot-tubes")
