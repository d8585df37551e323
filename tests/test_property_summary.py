"""The property suite's end-of-session summary (properties/amcp_properties/session_summary.py): the
counts of several processes add up, and under pytest-xdist (``make test`` runs ``pytest -n 2``) the
controller prints the workers' summary once."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from amcp_properties.coverage import CoverageRecorder
from amcp_properties.profiles import SIZES
from amcp_properties.strategies import GeneratorStats
from tests.guards import GUARD_SECONDS

ROOT = Path(__file__).resolve().parents[1]


def _state(examples: int, completed: int, measured: int, label: str) -> dict:
    return {"examples": {"t[drake]": examples}, "flags": {"t[drake]": {"completed": completed}},
            "measured": {"t[drake]": {"completed": measured}}, "labels": {"t[drake]": {label: examples}},
            "answers": {"drake": {"tube_qp": {"answered": examples}}}}


def test_two_recorders_add_up_to_the_counts_of_both():
    """3 examples (1 of 2 measured runs completed) and 5 examples (4 of 4): 8 examples, 5 of 6 = 0.833."""
    recorder = CoverageRecorder()
    recorder.add_state(_state(3, 1, 2, "n=2"))
    recorder.add_state(_state(5, 4, 4, "n=3"))
    summary = recorder.summary()["t[drake]"]
    assert summary["examples"] == 8
    assert abs(summary["fractions"]["completed"] - 5 / 6) < 1e-12
    assert summary["labels"] == {"n=2": 3, "n=3": 5}
    assert recorder.to_state()["answers"] == {"drake": {"tube_qp": {"answered": 8}}}


def test_a_recorder_state_round_trips():
    recorder = CoverageRecorder()
    recorder.add_state(_state(3, 1, 2, "n=2"))
    again = CoverageRecorder()
    again.add_state(recorder.to_state())
    assert again.summary() == recorder.summary()


def test_generator_counts_add_up_and_a_problem_drawn_twice_counts_once():
    first, second = GeneratorStats(), GeneratorStats()
    first.add("design attempts")
    first.add("rejected: TemplateError")
    first.outcome("a", "accepted")
    first.outcome("b", "rejected: TemplateError")
    second.add("design attempts")
    second.outcome("a", "accepted")
    total = GeneratorStats()
    total.add_state(first.to_state())
    total.add_state(second.to_state())
    assert total.attempts == 2 and total.rejections == 1
    assert len(total.distinct) == 2 and total.distinct_rejection_rate() == 0.5


@pytest.mark.slow
def test_under_xdist_the_property_tests_share_one_worker_and_the_controller_prints_one_summary():
    """Assumption 11's property on both backends in two xdist workers (as ``make test`` runs them): both
    tests run in the same worker (the property suite's xdist group: the summary names no second worker
    process), and the controller prints one summary section whose rows count the profile's number of
    examples (nothing lost between worker and controller). The nested run has no short timeout (it took
    1.5 min on an idle machine and longer under load): only the suite's one guard (tests/guards.py)."""
    env = {**os.environ, "AMCP_PROFILE": "ci"}
    env.pop("AMCP_COVERAGE_FILE", None)
    proc = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-p", "no:cacheprovider",
                           "-q", "properties/amcp_properties/test_assumption11.py"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = proc.stdout
    assert out.count("amcp property coverage (profile ci)") == 1, out
    rows = [line.split() for line in out.splitlines() if line.startswith("test_assumption11_")]
    assert len(rows) == 2 and all(row[1] == str(SIZES["ci"].design) for row in rows), out
    runs = [line for line in out.splitlines() if line.startswith("closed-loop runs:")]
    assert len(runs) == 1 and "worker processes" not in runs[0], out
    assert "generator:" in out
