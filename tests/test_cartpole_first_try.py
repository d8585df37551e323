"""The 4-state cart-pole of examples/own-system (a continuous-time model, bounds by name, no design
section) on the first try from the command line: ``amcp design FILE`` finds an X0 of at most 64 facets
that passes every design check, and ``amcp certify FILE --steps 10``, without any ``--formulation``
flag, certifies the run with that design."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.cli.main import main
from amcp_drake.model.problem_io import load_spec

CARTPOLE = Path(__file__).resolve().parents[1] / "examples" / "own-system" / "cartpole.json"


@pytest.mark.slow
def test_cartpole_designs_within_64_facets_and_certifies_without_a_formulation_flag(tmp_path):
    data = json.loads(CARTPOLE.read_text())
    assert data["system"]["continuous"] is True and "bounds" in data and "design" not in data

    designed = CliRunner().invoke(main, ["design", str(CARTPOLE), "--json"])
    assert designed.exit_code == 0, designed.output
    report = json.loads(designed.stdout)
    assert report["passed"] is True and all(c["status"] == "pass" for c in report["checks"])
    H_x = np.asarray(report["design"]["H_x"])
    assert H_x.shape[1] == 4 and len(H_x) <= 64

    out = tmp_path / "out"
    args = ["certify", str(CARTPOLE), "--steps", "10", "--out", str(out)]
    assert not any(a.startswith("--formulation") for a in args)
    certified = CliRunner().invoke(main, args)
    assert certified.exit_code == 0, certified.output
    assert "CERTIFIED" in certified.stdout
    certificate = json.loads((out / "certificate.json").read_text())
    assert certificate["verdict"] == "pass" and certificate["counts"]["fail"] == 0
    assert certificate["run"]["steps"] == 10
    trajectory = json.loads(gzip.decompress((out / "trajectory.json.gz").read_bytes()))
    # the run's X0 is the design above: the same rows (the design is deterministic)
    np.testing.assert_allclose(np.asarray(trajectory["design"]["H_x"]), H_x, rtol=1e-9, atol=0)
    # and it holds the file's cart-pole: 4 named states, discretised with the file's sample time
    spec = load_spec(CARTPOLE)
    assert certificate["problem"]["n"] == spec.problem.n == 4 and certificate["problem"]["dt"] == 0.1
