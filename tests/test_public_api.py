"""The documented Python API (README, design.md) works as written, and the CLI stays lazy."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
from click.testing import CliRunner


def test_documented_api_calls_work_even_after_the_submodules_are_imported():
    import amcp_drake as amcp
    import amcp_drake.certificate.certify  # noqa: F401  - importing the submodules must not shadow the functions
    import amcp_drake.offline.design  # noqa: F401
    import amcp_drake.online.simulate  # noqa: F401

    spec = amcp.examples.lorenzen2019_spec()
    offline = amcp.design(spec.problem, spec.design, backend="drake")
    ctrl = amcp.AdaptiveMPC(spec.problem, offline, backend="drake")
    traj = amcp.simulate(ctrl, x0=[2, 3], theta_star=[0.8, 0.2, -0.5], steps=4, disturbance="uniform", seed=0,
                         mu_state_bound=3.0)
    cert = amcp.certify(traj)
    assert cert.passed
    assert np.allclose(traj.x[0], [2, 3])


def test_help_does_not_import_drake_or_cvxpy():
    code = ("import sys; from amcp_drake.cli import main\n"
            "try:\n    main(['--help'])\nexcept SystemExit:\n    pass\n"
            "print('pydrake' in sys.modules, 'cvxpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "False False"


def test_run_with_the_vertex_formulation_and_certify_it(tmp_path):
    from amcp_drake.cli import main

    result = CliRunner().invoke(main, ["run", "--steps", "5", "--formulation", "vertex", "--save",
                                       str(tmp_path / "t.json")])
    assert result.exit_code == 0, result.output
    cert = CliRunner().invoke(main, ["certify", "--trajectory", str(tmp_path / "t.json"), "--out", str(tmp_path / "o")])
    assert cert.exit_code == 0, cert.output
    assert "tube_propagation" in cert.output
    data = json.loads((tmp_path / "o" / "certificate.json").read_text())
    multipliers = {"multipliers_nonneg", "multipliers_15c", "multipliers_15d"}
    assert data["run"]["formulation"] == "vertex"  # no Λ to check: listed as not applicable, never as claims
    assert not multipliers & {c["id"] for c in data["claims"]}
    assert {c["id"] for c in data["run"]["not_claimed"] if c["reason"].startswith("not applicable")} == multipliers
