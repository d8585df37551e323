"""The documentation site renders its mathematics without a network: the site is built here with MkDocs,
and headless Chromium loads the paper page from the file system; every ``$…$``/``$$…$$`` fragment
(an ``arithmatex`` span of pymdownx.arithmatex) must come back as a MathJax SVG, none as raw TeX.

Skipped, with the reason shown by ``pytest -ra``, when Chromium is not installed (CI installs it:
``.ci/run``)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.browser import NO_CHROMIUM, find_chromium, headless
from tests.guards import GUARD_SECONDS

ROOT = Path(__file__).resolve().parents[1]
PAGE = "explanation/paper.html"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)], cwd=ROOT,
                          capture_output=True, text=True, env=env, timeout=GUARD_SECONDS)
    assert done.returncode == 0, done.stderr[-3000:]
    return out


def test_the_paper_page_marks_every_formula_for_mathjax_and_ships_mathjax(site):
    html = (site / PAGE).read_text(encoding="utf-8")
    assert len(re.findall(r'class="arithmatex"', html)) >= 100
    for script in ("javascripts/mathjax-config.js", "javascripts/mathjax/tex-svg.js"):
        assert f'src="../{script}"' in html
        assert (site / script).is_file()
    assert "cdn" not in re.findall(r'<script[^>]*src="([^"]*)"', html).__str__().lower()


def test_the_paper_page_renders_its_formulas_in_headless_chromium(site, tmp_path):
    chromium = find_chromium()
    if chromium is None:
        pytest.skip(NO_CHROMIUM)
    page = (site / PAGE).resolve().as_uri()
    base = headless(chromium, tmp_path / "profile", "--run-all-compositor-stages-before-draw", "--virtual-time-budget=30000")
    done = subprocess.run([*base, "--dump-dom", page], capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert done.returncode == 0, done.stderr[-2000:]
    dom = done.stdout
    spans = len(re.findall(r'class="arithmatex"', dom))
    rendered = len(re.findall(r"<mjx-container[^>]*jax=\"SVG\"", dom))
    assert spans >= 100 and rendered == spans, (spans, rendered)
    assert "<svg" in dom and "\\(" not in re.sub(r"<[^>]+>", "", dom.split("<article", 1)[-1])
    shot = tmp_path / "paper.png"
    done = subprocess.run([*base, "--window-size=1200,1600", f"--screenshot={shot}", page], capture_output=True,
                          text=True, timeout=GUARD_SECONDS)
    assert done.returncode == 0 and shot.is_file() and shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
