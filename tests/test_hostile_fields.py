"""Fields of other people's files that try to mislead: a backend label nobody knows (or 10 MB of one), and
control characters in a problem name that a terminal would interpret. The integer fields that refuse ``1.0``
are rows of tests/test_bad_input_table.py."""

from __future__ import annotations

import gzip
import json
from importlib import resources

import pytest
from click.testing import CliRunner

from amcp_drake.backends import REGISTRY
from amcp_drake.cli import main
from amcp_drake.cli.common import terminal_safe
from amcp_drake.model.trajectory_schema import trajectory_schema
from tests.recorded_runs import trajectory

#: A problem name that clears the screen, returns the cursor to the line start and rings the bell.
HOSTILE_NAME = "evil\x1b[2J\rX\x07"


def test_the_backend_labels_are_the_known_backends():
    """The trajectory schema's backend labels (of the run and of the design) are exactly the registry's."""
    schema = trajectory_schema()
    assert sorted(schema["properties"]["backend"]["enum"]) == sorted(REGISTRY)
    assert sorted(schema["properties"]["design"]["properties"]["backend"]["enum"]) == sorted(REGISTRY)


def test_a_10_mb_backend_label_is_refused_without_echoing_it(tmp_path):
    """A trajectory whose backend is 10 MB of text: exit 2 naming the field, the message a few hundred bytes."""
    data = trajectory()
    data["backend"] = "y" * 10_000_000
    path = tmp_path / "t.json.gz"
    path.write_bytes(gzip.compress(json.dumps(data).encode()))
    result = CliRunner().invoke(main, ["certify", "--trajectory", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output[:500]
    assert "backend: expected one of \"cvxpy\", \"drake\"" in result.output
    assert "10,000,000 characters" in result.output
    assert len(result.output) < 1000
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("text, shown", [
    ("\x1b[2J", "\\x1b[2J"), ("a\rb", "a\\rb"), ("\x07\x00\x7f\x9b", "\\x07\\x00\\x7f\\x9b"),
    ("line 1\nline\t2", "line 1\nline\t2"), ("θ* ∈ Θ", "θ* ∈ Θ"),
])
def test_terminal_safe_escapes_control_characters_only(text, shown):
    assert terminal_safe(text) == shown


def hostile_problem(tmp_path) -> str:
    data = json.loads((resources.files("amcp_drake") / "data" / "lorenzen2019.json").read_text())
    data["name"] = HOSTILE_NAME
    data["scenario"]["steps"] = 2
    path = tmp_path / "hostile.json"
    path.write_text(json.dumps(data))
    return str(path)


@pytest.mark.parametrize("command", [["design"], ["run"], ["certify", "--out", "{out}"]])
def test_a_problem_name_cannot_drive_the_terminal(command, tmp_path):
    """design, run and certify on a problem named "evil ESC[2J CR X BEL": no control character reaches the output
    (click keeps ANSI sequences when it writes to a terminal, as ``color=True`` emulates), and the name the commands
    print is shown with its escapes visible."""
    args = [a.format(out=tmp_path / "out") for a in command]
    result = CliRunner().invoke(main, [args[0], hostile_problem(tmp_path), *args[1:]], color=True)
    assert result.exit_code == 0, result.output
    assert "\x1b" not in result.output and "\x07" not in result.output, repr(result.output[:300])
    assert "\r" not in result.stdout  # (stderr's progress bar rewrites its own line with CR)
    if command[0] != "certify":  # certify prints no problem name
        assert "evil\\x1b[2J\\rX\\x07" in result.output
