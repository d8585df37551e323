"""One verdict: the Python API sequence of docs/api-snippet.md (load the problem, design, simulate,
``amcp.certify(traj)``) gives the same verdict and the same claims as ``amcp certify`` on the same run."""

from __future__ import annotations

import json
import re
from pathlib import Path

from click.testing import CliRunner

from amcp_drake.cli import main

ROOT = Path(__file__).resolve().parents[1]
STEPS = 20


def _snippet() -> str:
    """The ```python block of docs/api-snippet.md, with the README's 50 steps shortened to STEPS."""
    text = (ROOT / "docs" / "api-snippet.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1, "docs/api-snippet.md must hold exactly one ```python block"
    code = blocks[0]
    assert "steps=50" in code and "amcp.certify(traj)" in code
    return code.replace("steps=50", f"steps={STEPS}")


def test_the_api_snippet_and_amcp_certify_give_the_same_verdict_and_claims(tmp_path):
    namespace: dict = {}
    exec(compile(_snippet(), "docs/api-snippet.md", "exec"), namespace)  # noqa: S102 - the documented snippet
    api = namespace["cert"].to_dict()

    out = tmp_path / "cli"
    result = CliRunner().invoke(main, ["certify", "--steps", str(STEPS), "--seed", "0", "--out", str(out),
                                       "--formulation", "plain"],  # the API's AdaptiveMPC default
                                catch_exceptions=False)
    cli = json.loads((out / "certificate.json").read_text())

    assert api["verdict"] == cli["verdict"] == "pass", (api["counts"], cli["counts"])
    assert result.exit_code == 0, result.output
    assert api["counts"] == cli["counts"]
    assert [(c["id"], c["status"]) for c in api["claims"]] == [(c["id"], c["status"]) for c in cli["claims"]]
    assert [c["id"] for c in api["run"]["not_claimed"]] == [c["id"] for c in cli["run"]["not_claimed"]]
    for a, c in zip(api["claims"], cli["claims"]):  # the same run: the same margins
        assert (a["margin"] is None) == (c["margin"] is None), a["id"]
        if a["margin"] is not None:
            assert abs(a["margin"] - c["margin"]) <= 1e-9 * max(1.0, abs(c["margin"])), (a["id"], a["margin"], c["margin"])
    assert api["backend_conformance"] == cli["backend_conformance"] == "pass"
    assert api["run"]["mu_state_bound"] == cli["run"]["mu_state_bound"]
