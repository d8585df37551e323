"""examples/tutorial.py runs from top to bottom, outside the repository, with nothing but the installed
package: it exits 0 (its certificate says CERTIFIED and the backends agree) and writes the bundle."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.guards import GUARD_SECONDS

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_tutorial_runs_and_certifies(tmp_path):
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "tutorial.py"), str(out)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=GUARD_SECONDS, env=dict(os.environ))
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-2000:])
    lines = [line for line in done.stdout.splitlines() if line[:2] in {f"{i}." for i in range(1, 6)}]
    assert [line[:2] for line in lines] == ["1.", "2.", "3.", "4.", "5."]
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "pass" and cert["problem"]["name"] == "oscillator"
