"""``pip install .`` gives a working ``amcp``: the project is built as a wheel from the files git tracks, the
wheel is installed into a fresh virtual environment, and the installed command certifies Example 1 from a
folder outside the repository. The fresh environment sees the tested dependencies of this environment
(a ``.pth`` file naming its site-packages) instead of downloading them again; the project itself, its
package data (templates, schemas, examples) and its entry point come from the wheel only (checked)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

from tests.guards import GUARD_SECONDS

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=GUARD_SECONDS, **kw)


@pytest.mark.slow
def test_the_wheel_installs_into_a_fresh_venv_and_certifies(tmp_path):
    if not (ROOT / ".git").exists() or shutil.which("git") is None:
        pytest.skip("not a git checkout: the wheel is built from the files git tracks")
    src = tmp_path / "src"
    files = _run(["git", "-C", ROOT, "ls-files", "-z"]).stdout.split("\0")
    for name in filter(None, files):
        if (ROOT / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, src / name)
    built = _run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation", ".", "-w",
                  tmp_path / "dist"], cwd=src)
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("amcp_drake-*.whl")

    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(env_dir)
    python = env_dir / "bin" / "python"
    purelib = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    (purelib / "amcp_tested_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    installed = _run([python, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index", wheel])
    assert installed.returncode == 0, installed.stderr[-3000:]

    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    where = _run([python, "-c", "import amcp_drake, amcp_reference, amcp_properties; print(amcp_drake.__file__)"],
                 cwd=tmp_path, env=env)
    assert where.returncode == 0, where.stderr[-3000:]
    assert Path(where.stdout.strip()).is_relative_to(purelib), where.stdout
    out = tmp_path / "out"
    done = _run([env_dir / "bin" / "amcp", "certify", "--example", "lorenzen2019", "--steps", "3", "--out", out],
                cwd=tmp_path, env=env)
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-2000:])
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "pass" and (out / "report.html").is_file()
