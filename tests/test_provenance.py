"""certificate.json's ``provenance``: the SHA-256 of the files it is about (computed here with hashlib from
the bytes on disk), the library versions (from the installed metadata), the command line, platform and
commit; a changed byte of the trajectory no longer matches."""

from __future__ import annotations

import hashlib
import json
import subprocess
from importlib import metadata, resources
from pathlib import Path

import jsonschema
import pytest
from click.testing import CliRunner

from amcp_drake.certificate.certify import schema
from amcp_drake.certificate.provenance import check_files
from amcp_drake.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def bundle(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("prov") / "out"
    result = CliRunner().invoke(main, ["certify", "--example", "lorenzen2019", "--steps", "3", "--out", str(out)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    return out


def test_the_certificate_records_the_hashes_of_its_trajectory_and_problem_files(bundle):
    cert = json.loads((bundle / "certificate.json").read_text())
    jsonschema.validate(cert, schema())
    files = cert["provenance"]["files"]
    assert files["trajectory"] == {"name": "trajectory.json.gz", "sha256": _sha256(bundle / "trajectory.json.gz")}
    packaged = Path(str(resources.files("amcp_drake") / "data" / "lorenzen2019.json"))
    assert files["problem"] == {"name": "lorenzen2019.json", "sha256": _sha256(packaged)}
    assert check_files(cert, bundle) == {"trajectory": True}


def test_one_changed_byte_of_the_trajectory_no_longer_matches(bundle, tmp_path):
    cert = json.loads((bundle / "certificate.json").read_text())
    data = bytearray((bundle / "trajectory.json.gz").read_bytes())
    data[len(data) // 2] ^= 0x01
    (tmp_path / "trajectory.json.gz").write_bytes(bytes(data))
    assert check_files(cert, tmp_path) == {"trajectory": False}
    assert _sha256(tmp_path / "trajectory.json.gz") != cert["provenance"]["files"]["trajectory"]["sha256"]


def test_the_certificate_records_versions_command_line_platform_and_commit(bundle):
    prov = json.loads((bundle / "certificate.json").read_text())["provenance"]
    for group, names in (("producer", ("drake", "clarabel", "cvxpy")), ("checker", ("numpy", "scipy"))):
        for name in names:
            assert prov["libraries"][group][name] == metadata.version(name)
    assert prov["amcp_drake"] == metadata.version("amcp-drake")
    assert prov["command_line"][0] == "amcp"
    assert prov["python"].count(".") == 2 and prov["platform"]
    if (ROOT / ".git").exists():
        head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
        assert prov["git_commit"] == head
    else:
        assert prov["git_commit"] is None


def test_a_given_trajectory_file_is_hashed_as_an_input(bundle, tmp_path):
    out = tmp_path / "again"
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(bundle / "trajectory.json.gz"), "--out", str(out)],
                                catch_exceptions=False)
    assert result.exit_code == 0, result.output
    files = json.loads((out / "certificate.json").read_text())["provenance"]["files"]
    assert files["input_trajectory"]["sha256"] == _sha256(bundle / "trajectory.json.gz")


def test_the_command_line_is_stored_verbatim_as_data(tmp_path):
    """Arguments are recorded as strings, never interpreted (a quote or a shell character stays as given)."""
    from amcp_drake.certificate.provenance import provenance

    (tmp_path / "t.json").write_bytes(b"{}")
    argv = ["amcp", "certify", "--out", "x'; rm -rf / #", '"""']
    prov = provenance({"trajectory": tmp_path / "t.json"}, argv)
    assert prov["command_line"] == argv
    assert prov["files"]["trajectory"]["sha256"] == hashlib.sha256(b"{}").hexdigest()


def test_the_report_shows_the_provenance_escaped(bundle):
    page = (bundle / "report.html").read_text(encoding="utf-8")
    sha = json.loads((bundle / "certificate.json").read_text())["provenance"]["files"]["trajectory"]["sha256"]
    assert 'id="provenance"' in page and sha in page
