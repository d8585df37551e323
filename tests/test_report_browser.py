"""report.html: self-contained, every plot and every claim row present under the paper result it
checks, the robust baseline beside the run equal to a baseline run computed here, and it loads in a
real browser.

The browser test runs headless Chromium (``--dump-dom``) on the written report and checks the DOM it
built. It is skipped, with the reason shown by ``pytest -ra``, when Chromium is not installed
(Debian/Ubuntu: ``apt-get install -y chromium``).
"""

from __future__ import annotations

import base64
import dataclasses
import json
import re
import subprocess
import xml.etree.ElementTree as ET
from html.parser import HTMLParser
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from amcp_drake.certificate.certify import certify, schema
from amcp_drake.certificate.report import render_report, write_outputs
from amcp_drake.certificate.report_plots import PLOTS
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.online.simulate import Trajectory
from tests.browser import NO_CHROMIUM, find_chromium, headless
from tests.guards import GUARD_SECONDS

STEPS = 6
#: Which claims each section of the report must hold, written out from the paper (not from the code's map).
EXPECTED_SECTIONS = {
    "theorem14-i": ["recursive_feasibility"],
    "theorem14-ii": ["theta_star_in_Theta_k", "theta_hat_in_Theta"],
    "theorem14-iii": ["state_input_constraints"],
    "lemma3": ["Theta0_contains_Theta", "Theta_k_nested", "Theta_k_lower_inclusion"],
    "lemma5": ["lms_update", "lemma5"],
    "proposition9": ["tube_contains_state", "tube_contains_next_state", "tube_propagation", "tube_constraints",
                     "tube_alpha_nonneg", "terminal_set", "multipliers_nonneg", "multipliers_15c", "multipliers_15d"],
    "qp20": ["cost_value", "qp_optimality"],
    "assumptions": ["theta_star_in_Theta", "w_in_W", "model_consistent", "data_consistency", "control_law",
                    "mu_precondition"],
    "design": ["design.terminal_cost_16", "design.assumption_8", "design.x0_contractive",
               "design.x0_robustly_invariant", "design.w_bar_f_bar_recomputed", "design.x_f_non_empty",
               "design.x_f_invariant", "design.x_f_in_z", "design.mu_condition_11", "design.x0_vertices"],
}
SVG = "{http://www.w3.org/2000/svg}"


class Elements(HTMLParser):
    """Every start tag with its attributes, plus the text of elements with an id."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.text: dict[str, str] = {}
        self.section_of: dict[str, str] = {}  # claim id -> data-result of the enclosing <section>
        self.sections: list[str] = []
        self._open: list[str | None] = []
        self._section: str | None = None

    def handle_starttag(self, tag, attrs):
        attrs = {k: v or "" for k, v in attrs}
        self.tags.append((tag, attrs))
        if tag == "section" and "data-result" in attrs:
            self._section = attrs["data-result"]
            self.sections.append(self._section)
        if tag == "tr" and "data-claim-id" in attrs and self._section is not None:
            self.section_of[attrs["data-claim-id"]] = self._section
        if tag not in ("img", "meta", "br", "link", "input"):
            self._open.append(attrs.get("id"))
            if attrs.get("id"):
                self.text[attrs["id"]] = ""

    def handle_endtag(self, tag):
        if tag == "section":
            self._section = None
        if self._open and tag not in ("img", "meta", "br", "link", "input"):
            self._open.pop()

    def handle_data(self, data):
        for element_id in self._open:
            if element_id:
                self.text[element_id] += data

    def by_id(self, element_id: str) -> tuple[str, dict[str, str]] | None:
        return next(((t, a) for t, a in self.tags if a.get("id") == element_id), None)


def parse(html: str) -> Elements:
    parser = Elements()
    parser.feed(html)
    return parser


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    """An Example 1 run (6 steps), its certificate with the robust baseline beside it (as ``amcp certify``
    adds it) and the written bundle."""
    from dataclasses import replace

    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate
    from amcp_drake.studies.baseline import robust_beside

    spec = lorenzen2019_spec()
    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake")
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, STEPS, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)
    plain = certify(traj, spec)
    cert = replace(plain, figures={**plain.figures, "robust_baseline": robust_beside(traj)})
    out = write_outputs(tmp_path_factory.mktemp("report") / "out", traj, cert)
    return {"traj": traj, "cert": cert, "plain": plain, "out": out,
            "html": (out / "report.html").read_text(encoding="utf-8")}


def check_claim_sections(doc: Elements, claims: list[dict]) -> None:
    """Every claim row exactly once, under the paper result it checks (EXPECTED_SECTIONS, in that order),
    with its status and its id shown in its first cell."""
    rows = [a for t, a in doc.tags if t == "tr" and "data-claim-id" in a]
    assert sorted(a["data-claim-id"] for a in rows) == sorted(c["id"] for c in claims)
    assert {a["data-claim-id"]: a["data-status"] for a in rows} == {c["id"]: c["status"] for c in claims}
    assert doc.sections == list(EXPECTED_SECTIONS)
    for key, ids in EXPECTED_SECTIONS.items():
        assert [i for i in (a["data-claim-id"] for a in rows) if doc.section_of[i] == key] == ids, key
    for c in claims:
        assert doc.text[f"claim-{c['id']}"].strip().startswith(c["id"])


def _svg_size(data_uri: str) -> tuple[float, float]:
    """(width, height) in pt of an SVG data URI, after parsing it as SVG with a viewBox of that size and
    at least ten drawn paths (an empty or truncated figure fails)."""
    prefix = "data:image/svg+xml;base64,"
    assert data_uri.startswith(prefix)
    root = ET.fromstring(base64.b64decode(data_uri[len(prefix):], validate=True))
    assert root.tag == f"{SVG}svg"
    width, height = (float(root.get(key).removesuffix("pt")) for key in ("width", "height"))
    assert [float(v) for v in root.get("viewBox").split()] == [0.0, 0.0, width, height]
    assert len(list(root.iter(f"{SVG}path"))) >= 10
    return width, height


def test_report_is_self_contained(bundle):
    doc = parse(bundle["html"])
    assert not [t for t, _ in doc.tags if t in ("link", "script", "iframe", "object", "embed")]
    for tag, attrs in doc.tags:
        for key in ("src", "href"):
            if key in attrs:  # inline data, or a link to an element of the page itself
                target = attrs[key]
                assert target.startswith("data:") or (target.startswith("#") and doc.by_id(target[1:])), \
                    (tag, target[:80])
    assert "http://" not in bundle["html"] and "https://" not in bundle["html"]


def test_every_plot_is_an_inline_svg(bundle):
    doc = parse(bundle["html"])
    for plot_id, alt in PLOTS:
        found = doc.by_id(plot_id)
        assert found is not None, plot_id
        tag, attrs = found
        assert tag == "img" and attrs["alt"] == alt
        width, height = _svg_size(attrs["src"])  # pt (1/72 in): a 300 x 150 px PNG at 90 dpi is 240 x 120 pt
        assert width >= 300 and height >= 150, (plot_id, width, height)


def test_failed_and_not_run_claims_are_marked(bundle):
    """A certificate with a failed claim and a claim not run: rows carry the status, the verdict says fail."""
    traj = Trajectory.from_dict(json.loads(json.dumps(bundle["traj"].to_dict())))
    traj.mu_state_bound = None  # (11) cannot run without the box
    traj.design = dataclasses.replace(traj.design, mu_state_bound=None)  # which the design records too
    lam = traj.records[2].Lambda.copy()
    lam[0, 0, 0, 0] = -1.0
    traj.records[2].Lambda = lam
    cert = certify(traj)
    doc = parse(render_report(traj, cert))
    assert doc.text["verdict"].strip() == "fail"
    rows = {a["data-claim-id"]: a for t, a in doc.tags if t == "tr" and "data-claim-id" in a}
    assert rows["multipliers_nonneg"]["class"] == "fail"
    assert rows["design.mu_condition_11"]["data-status"] == "not_run"
    assert rows["lemma5"]["class"] == "pass"


def test_report_renders_in_headless_chromium(bundle, tmp_path):
    chromium = find_chromium()
    if chromium is None:
        pytest.skip(NO_CHROMIUM)
    report = Path(bundle["out"]) / "report.html"
    cmd = headless(chromium, tmp_path / "profile", "--dump-dom", report.resolve().as_uri())
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert done.returncode == 0, done.stderr[-2000:]
    doc = parse(done.stdout)
    # every plot, by id and alt text, as an image the browser kept in the DOM
    for plot_id, alt in PLOTS:
        found = doc.by_id(plot_id)
        assert found is not None, f"{plot_id} missing from the browser DOM"
        assert found[0] == "img" and found[1]["alt"] == alt
        _svg_size(found[1]["src"])
    claims = json.loads((Path(bundle["out"]) / "certificate.json").read_text())["claims"]
    check_claim_sections(doc, claims)
    assert doc.text["verdict"].strip() == bundle["cert"].verdict == "pass"
    assert "robust-baseline" in doc.text and "baseline-table" in doc.text


def test_run_summary_shows_the_recorded_options(bundle):
    """The summary prints recorded values (a template that looked up a dict *method* once printed
    '<built-in method update ...>' here)."""
    summary = parse(bundle["html"]).text["run-summary"]
    assert "built-in" not in summary and "fixed complexity (9) [--update fixed]" in summary
    assert "onto Θ (12) [--projection Theta]" in summary
    assert f"{STEPS} applied inputs, {STEPS + 1} step records" in summary


def test_claims_are_grouped_by_the_paper_results(bundle):
    doc = parse(bundle["html"])
    check_claim_sections(doc, [claim for claim in bundle["cert"].to_dict()["claims"]])
    overview = doc.text["claims-overview"]
    for title in ("Theorem 14 (i)", "Theorem 14 (ii)", "Theorem 14 (iii)", "Lemma 3", "Lemma 5", "Proposition 9",
                  "Assumptions", "Design"):
        assert title in overview


def _numbers(doc: Elements, table_id: str, key: str) -> dict[str, list[float]]:
    """The data-value numbers of each row (by its ``key`` attribute) of the table ``table_id``."""
    out: dict[str, list[float]] = {}
    inside, row = False, None
    for tag, attrs in doc.tags:
        if tag == "table":
            inside = attrs.get("id") == table_id
        elif inside and tag == "tr":
            row = attrs.get(key)
        elif inside and tag == "td" and row is not None and "data-value" in attrs:
            out.setdefault(row, []).append(float(attrs["data-value"]))
    return out


def test_the_baseline_section_equals_a_robust_run_computed_here(bundle):
    """The robust baseline (Θ_k ≡ Θ, θ̂_k ≡ θ̂0) rerun here on the recorded disturbance: its closed-loop cost,
    mean one-step tube (vertices of Θ by Qhull, w̄ from the design) and final state are the report's."""
    from amcp_drake.model import polytope
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    traj = bundle["traj"]
    pr, d = traj.problem, traj.design
    robust = simulate(AdaptiveMPC(pr, d, backend="drake", options=OnlineOptions(update="none")), traj.x[0],
                      traj.theta_star, len(traj.u), traj.w.copy())
    assert np.array_equal(robust.w, traj.w)

    def cost(x, u):
        return sum(float(x[k] @ pr.Q @ x[k] + u[k] @ pr.R @ u[k]) for k in range(len(u)))

    def mean_tube(t, H, h, theta_hat):
        verts = polytope.vertices(H, h)
        sizes = []
        for k in range(len(t.u)):
            D = pr.regressor(t.x[k], t.u[k])
            sizes.append(max(max(float(row @ D @ (v - theta_hat)) for v in verts) + wb
                             for row, wb in zip(d.H_x, d.w_bar)))
        return float(np.mean(sizes))

    theta0 = pr.theta_hat0
    expected_robust = [cost(robust.x, robust.u), mean_tube(robust, pr.H_theta, d.h_theta0, theta0),
                       float(np.linalg.norm(robust.x[-1]))]
    numbers = _numbers(parse(bundle["html"]), "baseline-table", "data-quantity")
    got_adaptive = [numbers[q][0] for q in ("cost", "tube", "final_state_norm")]
    got_robust = [numbers[q][1] for q in ("cost", "tube", "final_state_norm")]
    np.testing.assert_allclose(got_robust, expected_robust, rtol=1e-9)
    assert got_adaptive[0] == pytest.approx(cost(traj.x, traj.u), rel=1e-12)
    assert got_adaptive[2] == pytest.approx(float(np.linalg.norm(traj.x[-1])), rel=1e-12)
    # the adaptive tube at each step uses that step's Θ_k and θ̂_k
    sizes = []
    for r in traj.records[: len(traj.u)]:
        verts = polytope.vertices(r.H_theta, r.h_theta)
        D = pr.regressor(traj.x[r.k], traj.u[r.k])
        sizes.append(max(max(float(row @ D @ (v - r.theta_hat)) for v in verts) + wb for row, wb in zip(d.H_x, d.w_bar)))
    assert got_adaptive[1] == pytest.approx(float(np.mean(sizes)), rel=1e-9)


def test_the_feasible_radii_of_the_baseline_are_feasible_and_tight(bundle):
    """Each reported radius r along a ray: the QP (20) is feasible at r·d and infeasible at r·(1 + 2·tol)·d
    (the bisection's relative accuracy is tol), for Θ and for Θ_T; and the adaptive radius is >= the robust."""
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.model.status import SolveStatus
    from amcp_drake.online.controller import AdaptiveMPC

    traj = bundle["traj"]
    b = bundle["cert"].figures["robust_baseline"]
    tol = b["ray_rel_tol"]
    assert tol <= 0.05
    ctrl = AdaptiveMPC(traj.problem, traj.design, backend="drake", options=OnlineOptions(update="none"))
    last = traj.records[-1]

    def feasible(x, h) -> bool:
        return ctrl.mpc.solve(np.asarray(x, float), h, traj.problem.theta_hat0, None).status is SolveStatus.OPTIMAL

    assert len(b["rays"]) >= 4
    for ray in b["rays"]:
        d = np.array(ray["unit"])
        assert np.linalg.norm(d) == pytest.approx(1.0)
        for key, h in (("robust", traj.design.h_theta0), ("adaptive", last.h_theta)):
            r = ray[key]
            assert r is not None and r > 0
            assert feasible(r * d, h), (ray["direction"], key)
            if not ray[f"{key}_capped"]:
                assert not feasible(r * (1 + 2 * tol) * d, h), (ray["direction"], key)
        assert ray["adaptive"] >= ray["robust"] * (1 - tol)


def test_the_baseline_leaves_the_verdict_and_the_claims_alone(bundle):
    with_baseline, without = bundle["cert"].to_dict(), bundle["plain"].to_dict()
    assert with_baseline["verdict"] == without["verdict"] and with_baseline["counts"] == without["counts"]
    assert [(c["id"], c["status"], c["margin"]) for c in with_baseline["claims"]] == \
        [(c["id"], c["status"], c["margin"]) for c in without["claims"]]
    assert "robust_baseline" not in without["figures"]
    jsonschema.validate(json.loads((Path(bundle["out"]) / "certificate.json").read_text()), schema())
    # without it, the report says why instead of showing numbers
    doc = parse(render_report(bundle["traj"], bundle["plain"]))
    assert "baseline-table" not in doc.text and "Not run" in doc.text["baseline-missing"]


def test_a_robust_run_says_it_is_the_baseline(bundle):
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    traj = bundle["traj"]
    ctrl = AdaptiveMPC(traj.problem, traj.design, backend="drake", options=OnlineOptions(update="none"))
    robust = simulate(ctrl, traj.x[0], traj.theta_star, 3, traj.w[:3].copy())
    doc = parse(render_report(robust, certify(robust)))
    assert "robust baseline itself" in doc.text["baseline-missing"]


def _captured(monkeypatch, plot_id: str, traj, cert):
    """The matplotlib Figure a plot draws (its SVG encoder replaced by a capture)."""
    import amcp_drake.certificate.report_plots as plots

    figures = []
    monkeypatch.setattr(plots, "_svg", lambda fig: figures.append(fig) or "data:image/svg+xml;base64,")
    src, note = plots.draw(plot_id, traj, cert)
    assert src is not None and len(figures) == 1, note
    return figures[0], note


def test_theta_star_lines_have_legend_entries(bundle, monkeypatch):
    fig, _ = _captured(monkeypatch, "plot-theta-hat", bundle["traj"], bundle["cert"])
    labels = [t.get_text() for ax in fig.axes for t in ax.get_legend().get_texts()]
    p = bundle["traj"].problem.p
    for i in range(1, p + 1):
        assert f"$\\theta^*_{{{i}}}$" in labels and f"$\\hat\\theta_{{{i}}}$" in labels


def test_tube_plot_draws_outlines_of_a_few_stages_and_the_boundary_of_Z(bundle, monkeypatch):
    """Outlines, not filled polygons; the predicted tube at a few stages only; the state row x2 >= -0.3 of
    Example 1's Z drawn in both panels and named in the legend."""
    from matplotlib.patches import Polygon

    from amcp_drake.certificate.plots import tube_stages

    fig, _ = _captured(monkeypatch, "plot-tubes", bundle["traj"], bundle["cert"])
    left, right = fig.axes
    N = bundle["traj"].problem.N
    assert [p for ax in fig.axes for p in ax.patches if isinstance(p, Polygon)] == []
    stages = tube_stages(N)
    assert 3 <= len(stages) <= 8 and stages[0] == 0 and stages[-1] == N
    outlines = [line for line in left.get_lines() if line.get_label().startswith("$X_{")]
    assert len(outlines) == len(stages)
    for ax in (left, right):
        assert ax.collections, "the boundary of Z is not drawn"
        assert "boundary of Z, excluded side" in [t.get_text() for t in ax.get_legend().get_texts()]


def test_p_equal_1_projection_plot_shows_the_interval_over_k(monkeypatch):
    """kothare1996 has p = 1: the plot is Θ_k = [lo_k, hi_k] against k, with the bounds of the first and
    last Θ_k (computed here from the records' rows) in its caption, θ* and θ̂_k in the legend."""
    import re

    from amcp_drake.model.examples import kothare1996_spec
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = kothare1996_spec()
    assert spec.problem.p == 1
    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake")
    traj = simulate(ctrl, spec.scenario.x0, spec.scenario.theta_star, 4, "uniform", seed=0,
                    mu_state_bound=spec.design.mu_state_bound)
    cert = certify(traj, spec)

    def interval(r):
        H, h = np.ravel(r.H_theta), np.asarray(r.h_theta)
        return min(h[H > 0] / H[H > 0]) if np.any(H < 0) else None, max(h[H < 0] / H[H < 0])

    fig, note = _captured(monkeypatch, "plot-theta-projections", traj, cert)
    found = [tuple(map(float, m)) for m in re.findall(r"\[([-\d.e+]+), ([-\d.e+]+)\]", note)]
    for (lo, hi), r in zip(found, (traj.records[0], traj.records[-1])):
        hi_expected, lo_expected = interval(r)
        assert lo == pytest.approx(lo_expected, rel=1e-3) and hi == pytest.approx(hi_expected, rel=1e-3)
    assert len(found) == 2
    (ax,) = fig.axes
    assert ax.get_xlabel() == "step $k$" and ax.get_ylabel() == "$\\theta_1$"
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert labels == ["$\\Theta_k$ (interval)", "$\\theta^*$", "$\\hat\\theta_k$"]
    # and it renders to a real SVG in the report
    monkeypatch.undo()
    doc = parse(render_report(traj, cert))
    assert _svg_size(doc.by_id("plot-theta-projections")[1]["src"])[0] >= 300


def test_user_facing_text_uses_the_paper_notation(bundle):
    """Alt texts and captions say Θ_k, θ̂, θ*, never the ASCII spellings Theta_k, theta_hat, theta_star."""
    html = bundle["html"]
    doc = parse(html)
    texts = [a["alt"] for t, a in doc.tags if t == "img"] + re.findall(r"<figcaption>(.*?)</figcaption>", html, re.S)
    assert len(texts) >= 2 * len(PLOTS) - 1
    for text in texts:
        for ascii_name in ("Theta", "theta_hat", "theta_star", "theta_k"):
            assert ascii_name not in text, (ascii_name, text[:120])


@pytest.mark.parametrize("text, html", [
    ("x_(k+1) ∈ X_1|k", "x<sub>k+1</sub> ∈ X<sub>1|k</sub>"),
    ("Θ_{k+1} ⊆ Θ_k", "Θ<sub>k+1</sub> ⊆ Θ<sub>k</sub>"),
    ("w_bar, f_bar recomputed", "w\u0304, f\u0304 recomputed"),
    ("Λ^j h_θk <= 1", "Λ<sup>j</sup> h<sub>θk</sub> &lt;= 1"),
    ("max_k,i [h]_i", "max<sub>k,i</sub> [h]<sub>i</sub>"),
    ("μ‖D(x_k,u_k)‖²", "μ‖D(x<sub>k</sub>,u<sub>k</sub>)‖²"),
    ("cost certainty_equivalence", "cost certainty_equivalence"),
    ("<script>", "&lt;script&gt;"),
])
def test_claim_texts_are_set_with_html_subscripts(text, html):
    from amcp_drake.certificate.report_groups import math_html

    assert str(math_html(text)) == html


def test_the_baseline_names_each_ray_as_it_starts_and_how_feasibility_was_decided(bundle):
    """One progress line per ray, in order, before its search; the record names the method (the LP for
    θ* constant and no PE constraint), and the QP decides the same radii to the bisection's accuracy."""
    from amcp_drake.studies.baseline import robust_beside

    traj = bundle["traj"]
    lines: list[str] = []
    by_qp = robust_beside(traj, progress=lines.append, by_lp=False)
    b = bundle["cert"].figures["robust_baseline"]
    assert b["ray_method"] == "LP (TubeLP)" and by_qp["ray_method"] == "QP (20)"
    names = [ray["direction"] for ray in b["rays"]]
    assert lines == [f"  ... robust baseline: feasible radius along {name} ({i}/{len(names)})"
                     for i, name in enumerate(names, start=1)]
    tol = b["ray_rel_tol"]
    for lp_ray, qp_ray in zip(b["rays"], by_qp["rays"]):
        for key in ("robust", "adaptive"):
            assert abs(lp_ray[key] - qp_ray[key]) <= tol * max(lp_ray[key], qp_ray[key]), (lp_ray, qp_ray)
