"""The 5-mass chain (n = 10, m = 5, p = 4; the generator of the built-in mass_chain3/4) designs at default
settings (the automatic mode, no design section) and certifies 10 closed-loop steps with Drake."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from amcp_drake.cli import main
from amcp_drake.studies.chains import mass_chain


@pytest.mark.slow
def test_the_five_mass_chain_designs_at_default_settings_and_certifies_ten_steps_with_drake(tmp_path):
    data = mass_chain(5, steps=10)
    assert "design" not in data
    path = tmp_path / "mass_chain5.json"
    path.write_text(json.dumps(data))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["certify", str(path), "--backend", "drake", "--steps", "10", "--out", str(out)],
                                catch_exceptions=False)
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "pass", cert["counts"]
    assert result.exit_code == 0, result.output
