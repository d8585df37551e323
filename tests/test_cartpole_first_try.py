"""The 4-state cart-pole of examples/own-system (a continuous-time model, bounds by name, no design
section) on the first try from the command line: ``amcp design FILE --out d.json`` finds an X0 of at
most 64 facets that passes every design check, and ``amcp certify FILE --design d.json --steps 10``,
without any ``--formulation`` flag, certifies the run with that design and designs nothing (the design
functions are counted, not timed)."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.cli.main import main
from amcp_drake.model.problem_io import load_spec
from amcp_drake.offline import auto as offline_auto
from amcp_drake.offline import design as offline_design

CARTPOLE = Path(__file__).resolve().parents[1] / "examples" / "own-system" / "cartpole.json"


def _counted(function, name: str, calls: list):
    def wrapper(*args, **kwargs):
        calls.append(name)
        return function(*args, **kwargs)

    return wrapper


@pytest.mark.slow
def test_cartpole_designs_within_64_facets_and_certifies_without_a_formulation_flag(tmp_path, monkeypatch):
    data = json.loads(CARTPOLE.read_text())
    assert data["system"]["continuous"] is True and "bounds" in data and "design" not in data

    calls: list[str] = []  # every entry point of the offline design, counted
    for module, name in ((offline_design, "design"), (offline_design, "design_fixed"),
                         (offline_design, "_design_as_written"), (offline_design, "design_auto"),
                         (offline_auto, "design_auto")):
        monkeypatch.setattr(module, name, _counted(getattr(module, name), name, calls))

    design_json = tmp_path / "d.json"
    designed = CliRunner().invoke(main, ["design", str(CARTPOLE), "--json", "--out", str(design_json)])
    assert designed.exit_code == 0, designed.output
    assert {"design", "design_auto", "_design_as_written"} <= set(calls)  # the counters see a design
    calls.clear()
    report = json.loads(designed.stdout)
    assert report["passed"] is True and all(c["status"] == "pass" for c in report["checks"])
    H_x = np.asarray(report["design"]["H_x"])
    assert H_x.shape[1] == 4 and len(H_x) <= 64

    assert json.loads(design_json.read_text())["design"]["H_x"] == report["design"]["H_x"]

    out = tmp_path / "out"
    args = ["certify", str(CARTPOLE), "--design", str(design_json), "--steps", "10", "--out", str(out)]
    assert not any(a.startswith("--formulation") for a in args)
    certified = CliRunner().invoke(main, args)
    assert certified.exit_code == 0, certified.output
    assert calls == []  # nothing was designed: the design file was used as it is
    assert "CERTIFIED" in certified.stdout
    certificate = json.loads((out / "certificate.json").read_text())
    assert certificate["verdict"] == "pass" and certificate["counts"]["fail"] == 0
    assert certificate["run"]["steps"] == 10
    trajectory = json.loads(gzip.decompress((out / "trajectory.json.gz").read_bytes()))
    # the run's X0 is the design file's
    np.testing.assert_array_equal(np.asarray(trajectory["design"]["H_x"]), H_x)
    # and it holds the file's cart-pole: 4 named states, discretised with the file's sample time
    spec = load_spec(CARTPOLE)
    assert certificate["problem"]["n"] == spec.problem.n == 4 and certificate["problem"]["dt"] == 0.1
