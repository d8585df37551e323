"""The architecture of docs/architecture.md, checked at run time.

The import contracts themselves (layers, forbidden imports, no cycles) are static and live in
``pyproject.toml`` (``lint-imports``, run by ``make test`` before pytest). What a static contract cannot
show is what a call actually loads: these tests run in a fresh interpreter and look at ``sys.modules``.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.guards import GUARD_SECONDS

FORBIDDEN_IN_CERTIFY = ("pydrake", "cvxpy", "clarabel", "amcp_reference", "amcp_drake.backends.drake_")


def _run(code: str) -> str:
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.strip()


def test_certify_of_a_saved_run_loads_no_backend_and_no_modelling_layer(example_run, tmp_path):
    """A certificate re-checks a recorded run with numpy/scipy only: certifying a trajectory file
    must not import Drake, cvxpy, Clarabel or either backend (design.md, "Certificates are
    independent of the solver that produced the run")."""
    path = example_run.save(tmp_path / "run.json.gz")
    loaded = _run(
        "import sys, amcp_drake as amcp\n"
        f"cert = amcp.certify(amcp.Trajectory.load({str(path)!r}))\n"
        "assert cert.claims, 'no claims checked'\n"
        "print('verdict=' + cert.verdict)\n"
        f"print('loaded=' + ','.join(sorted(m for m in sys.modules if m.startswith({FORBIDDEN_IN_CERTIFY!r}))))")
    verdict, modules = (line.split("=", 1)[1] for line in loaded.splitlines()[-2:])
    assert verdict == "pass"
    assert modules == "", f"certify() loaded {modules}"


@pytest.mark.parametrize("layer", ["model", "offline", "backends", "online"])
def test_the_algorithm_layers_load_nothing_above_them(layer):
    """Importing a lower layer (with all its modules) loads no certificate, study, CLI or test package."""
    above = ("amcp_drake.certificate", "amcp_drake.studies", "amcp_drake.cli", "amcp_drake.comparison",
             "amcp_drake.systems",
             "amcp_properties", "hypothesis")
    out = _run(
        "import importlib, pkgutil, sys\n"
        f"pkg = importlib.import_module('amcp_drake.{layer}')\n"
        "for m in pkgutil.iter_modules(pkg.__path__):\n"
        f"    importlib.import_module('amcp_drake.{layer}.' + m.name)\n"
        f"print('loaded=' + ','.join(sorted(m for m in sys.modules if m.startswith({above!r}))))")
    assert out.splitlines()[-1] == "loaded=", f"amcp_drake.{layer} {out.splitlines()[-1]}"
