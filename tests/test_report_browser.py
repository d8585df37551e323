"""report.html: self-contained, every plot and every claim row present, and it loads in a real browser.

The browser test runs headless Chromium (``--dump-dom``) on the written report and checks the DOM it
built. It is skipped, with the reason shown by ``pytest -ra``, when Chromium is not installed
(Debian/Ubuntu: ``apt-get install -y chromium``).
"""

from __future__ import annotations

import base64
import dataclasses
import json
import shutil
import struct
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from amcp_drake.certificate.certify import certify
from amcp_drake.certificate.report import PLOTS, render_report, write_outputs
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.online.simulate import Trajectory

STEPS = 6
CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome")


class Elements(HTMLParser):
    """Every start tag with its attributes, plus the text of elements with an id."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str]]] = []
        self.text: dict[str, str] = {}
        self._open: list[str | None] = []

    def handle_starttag(self, tag, attrs):
        attrs = {k: v or "" for k, v in attrs}
        self.tags.append((tag, attrs))
        if tag not in ("img", "meta", "br", "link", "input"):
            self._open.append(attrs.get("id"))
            if attrs.get("id"):
                self.text[attrs["id"]] = ""

    def handle_endtag(self, tag):
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
    """An Example 1 run (6 steps), its certificate and the written bundle."""
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = lorenzen2019_spec()
    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend="drake")
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, STEPS, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)
    cert = certify(traj, spec)
    out = write_outputs(tmp_path_factory.mktemp("report") / "out", traj, cert)
    return {"traj": traj, "cert": cert, "out": out, "html": (out / "report.html").read_text(encoding="utf-8")}


def _png_size(data_uri: str) -> tuple[int, int]:
    assert data_uri.startswith("data:image/png;base64,")
    raw = base64.b64decode(data_uri.split(",", 1)[1], validate=True)
    assert raw[:8] == b"\x89PNG\r\n\x1a\n" and raw[12:16] == b"IHDR"
    return struct.unpack(">II", raw[16:24])


def test_report_is_self_contained(bundle):
    doc = parse(bundle["html"])
    assert not [t for t, _ in doc.tags if t in ("link", "script", "iframe", "object", "embed")]
    for tag, attrs in doc.tags:
        for key in ("src", "href"):
            if key in attrs:
                assert attrs[key].startswith("data:"), (tag, attrs[key][:80])
    assert "http://" not in bundle["html"] and "https://" not in bundle["html"]


def test_every_plot_is_an_inline_png(bundle):
    doc = parse(bundle["html"])
    for plot_id, alt in PLOTS:
        found = doc.by_id(plot_id)
        assert found is not None, plot_id
        tag, attrs = found
        assert tag == "img" and attrs["alt"] == alt
        width, height = _png_size(attrs["src"])
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


def _chromium() -> str | None:
    for name in CHROMIUM_CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    return None


def test_report_renders_in_headless_chromium(bundle, tmp_path):
    chromium = _chromium()
    if chromium is None:
        pytest.skip("Chromium is not installed (apt-get install -y chromium); the browser check did not run")
    report = Path(bundle["out"]) / "report.html"
    cmd = [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--no-first-run", f"--user-data-dir={tmp_path / 'profile'}",
           "--dump-dom", report.resolve().as_uri()]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    doc = parse(done.stdout)
    # every plot, by id and alt text, as an image the browser kept in the DOM
    for plot_id, alt in PLOTS:
        found = doc.by_id(plot_id)
        assert found is not None, f"{plot_id} missing from the browser DOM"
        assert found[0] == "img" and found[1]["alt"] == alt
        _png_size(found[1]["src"])
    # every claim row, in the certificate's order, with its status
    claims = json.loads((Path(bundle["out"]) / "certificate.json").read_text())["claims"]
    rows = [a for t, a in doc.tags if t == "tr" and "data-claim-id" in a]
    assert [a["data-claim-id"] for a in rows] == [c["id"] for c in claims]
    assert [a["data-status"] for a in rows] == [c["status"] for c in claims]
    for c in claims:
        assert doc.by_id(f"claim-{c['id']}") is not None
    assert doc.text["verdict"].strip() == bundle["cert"].verdict == "pass"


def test_run_summary_shows_the_recorded_options(bundle):
    """The summary prints recorded values (a template that looked up a dict *method* once printed
    '<built-in method update ...>' here)."""
    summary = parse(bundle["html"]).text["run-summary"]
    assert "built-in" not in summary and "fixed / onto Theta" in summary
    assert f"{STEPS} applied inputs, {STEPS + 1} step records" in summary
