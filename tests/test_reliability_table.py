"""Bad input and hostile conditions, second table: files that are JSON but hostile (``null``, a zero W,
zero or badly scaled rows of Θ), tampered trajectories, devices given as files, options that disable a
limit, unreachable schedulers and full disks. Same contract as tests/test_bad_input_table.py: exit 2
through the CLI entry point with a message naming the field or option, nothing written below the test
folder; a row may instead expect exit 0 with the same output as a reference command.

Each row: (id, build, args, exit code, regex, extras). ``extras`` may hold ``patch`` (a function of
pytest's monkeypatch applied before the command, e.g. a writer failing with ENOSPC) and ``same_as`` (argv
of a reference command whose stdout must equal this one's, timings masked). No row asserts a wall time: a
device or an oversized file is refused by what was read (the message names the file and the limit).

The rows that start real processes (two resumes of one campaign store, SIGTERM during certify and
during a campaign) follow the table.
"""

from __future__ import annotations

import contextlib
import errno
import gzip
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from click.testing import CliRunner

from amcp_drake.cli import main
from tests.guards import GUARD_SECONDS
from tests.recorded_runs import TRAJECTORY_DATA, trajectory
from tests.test_bad_input_table import example, files, good_traj, problem, set_, text, traj


def theta_scaled(factor: float):
    def change(data: dict) -> None:
        data["Theta"]["H"] = [[factor * v for v in row] for row in data["Theta"]["H"]]
        data["Theta"]["h"] = [factor * v for v in data["Theta"]["h"]]

    return change


def zero_theta_row(offset: float):
    def change(data: dict) -> None:
        data["Theta"]["H"].append([0.0, 0.0, 0.0])
        data["Theta"]["h"].append(offset)

    return change


def enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def disk_full_on_write(monkeypatch) -> None:
    """Every file write of the certificate bundle fails as on a full disk (ENOSPC)."""
    import amcp_drake.certificate.report as report
    import amcp_drake.model.problem_io as problem_io

    monkeypatch.setattr(report.Path, "write_text", enospc)
    monkeypatch.setattr(problem_io.os, "fdopen", enospc)


def disk_full_in_sqlite(monkeypatch) -> None:
    """The store's first write fails as SQLite reports a full disk."""
    from amcp_drake.studies import campaign_store

    def full(self, *args, **kwargs):
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(campaign_store.CampaignStore, "record_settings", full)


def disk_full_on_report(monkeypatch) -> None:
    import amcp_drake.model.problem_io as problem_io

    monkeypatch.setattr(problem_io.os, "fdopen", enospc)


def a_store(folder: Path) -> Path:
    """A campaign store with its settings recorded and no problem (as an interrupted campaign leaves it)."""
    from amcp_drake.studies.campaign import campaign_settings
    from amcp_drake.studies.campaign_store import CampaignStore

    path = folder / "c.sqlite"
    store = CampaignStore(path)
    store.record_settings(campaign_settings(0, 1, ("drake",), 2))
    store.close()
    return path


def chain_problem(n: int, design: dict) -> Callable[[Path], dict]:
    """A problem file at dimension ``n`` with the given design section: a chain x_i⁺ = x_i + 0.2 x_(i+1)
    with an input on every state, ‖w‖∞ <= 0.005, Θ a box on two entries (A[0,1], B[n-1,n-1]), 4 steps."""

    def build(folder: Path) -> dict:
        import numpy as np

        eye, A1, B2 = np.eye(n), np.zeros((n, n)), np.zeros((n, n))
        A1[0, 1], B2[-1, -1] = 0.2, 0.5
        data = {"format": "amcp-problem", "version": 1, "name": f"chain{n}",
                "system": {"A0": (eye + 0.2 * np.eye(n, k=1)).tolist(), "B0": (0.5 * eye).tolist(),
                           "A": [A1.tolist(), np.zeros((n, n)).tolist()], "B": [np.zeros((n, n)).tolist(), B2.tolist()]},
                "W": {"H": np.vstack([eye / 0.005, -eye / 0.005]).tolist()},
                "Theta": {"H": [[1, 0], [-1, 0], [0, 1], [0, -1]], "h": [0.1] * 4},
                "Z": {"F": np.vstack([eye / 5, -eye / 5, np.zeros((2 * n, n))]).tolist(),
                      "G": np.vstack([np.zeros((2 * n, n)), eye, -eye]).tolist()},
                "cost": {"Q": eye.tolist(), "R": eye.tolist(), "N": 5}, "theta_hat0": [0.0, 0.0],
                "design": design,
                "scenario": {"x0": [0.5] + [0.0] * (n - 1), "theta_star": [0.05, -0.05], "steps": 4,
                             "disturbance": "uniform", "seed": 0}}
        path = folder / "p.json"
        path.write_text(json.dumps(data))
        return {"file": path}

    return build


def sparse_file(name: str, size: int) -> Callable[[Path], Path]:
    """A file of ``size`` bytes that takes no disk space (a hole)."""

    def make(folder: Path) -> Path:
        path = folder / name
        with open(path, "wb") as handle:
            handle.truncate(size)
        return path

    return make



#: (id, build, args, exit code, regex, extras)
ROWS: list[tuple] = [
    # 1: a problem file whose whole content is null
    ("null-problem-design", text("p.json", "null"), ["design", "{file}"], 2,
     r"file: expected a JSON object at top level; received null", {}),
    ("null-problem-run", text("p.json", "null"), ["run", "{file}"], 2, r"file: expected a JSON object", {}),
    ("null-problem-certify", text("p.json", "null"), ["certify", "{file}", "--out", "{folder}/out"], 2,
     r"file: expected a JSON object", {}),
    # 2: a zero W
    ("W.H-all-zero", problem(set_("W.H", [[0, 0], [0, 0]])), ["design", "{file}"], 2,
     r"W\.H: expected W = \{w \| H_w w <= 1\} bounded; received an unbounded set", {}),
    # 3: a zero row of Θ (h >= 0: the row holds everywhere and is dropped; h < 0: Θ is empty)
    ("Theta-zero-row-offset-0", problem(zero_theta_row(0.0)), ["design", "{file}"], 0,
     r"note: Theta: removed the zero row 6 \(0 <= 0 holds everywhere\)", {"same_as": ["design", "--example",
                                                                                     "lorenzen2019"]}),
    ("Theta-zero-row-offset-negative", problem(zero_theta_row(-1e-12)), ["design", "{file}"], 2,
     r"Theta\.h\[6\]: expected .*>= 0 .*zero row.*; received -1e-12.*empty", {}),
    # 4, 5: Θ of Example 1 with every row scaled (the same set)
    ("Theta-rows-times-1e-9", problem(theta_scaled(1e-9)), ["design", "{file}"], 0, r"all design checks pass",
     {"same_as": ["design", "--example", "lorenzen2019"]}),
    ("Theta-rows-times-1e9", problem(theta_scaled(1e9)), ["design", "{file}"], 0, r"all design checks pass",
     {"same_as": ["design", "--example", "lorenzen2019"]}),
    # 6: numbers given as strings in a trajectory
    ("trajectory-theta_star-string", traj(set_("theta_star.0", "-0.15")),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2,
     r"theta_star\[0\]: expected a number; received \"-0\.15\"", {}),
    ("trajectory-h_theta-string", traj(set_("records.10.h_theta.1", "0.3")),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2,
     r"records\[10\]\.h_theta\[1\]: expected a number; received \"0\.3\"", {}),
    # 7: stop_reason inconsistent with the records
    ("trajectory-stop-reason-infeasible", traj(set_("stop_reason", "infeasible")),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"stop_reason: expected .*completed", {}),
    ("trajectory-completed-but-failed-step", traj(set_("records.5.status", "infeasible")),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2,
     r"records\[5\]\.status: expected \"optimal\" or \"optimal_inaccurate\" \(stop_reason \"completed\"", {}),
    # 8: an integer field given as a float
    ("trajectory-k-float", traj(set_("records.10.k", 10.0)), ["certify", "--trajectory", "{file}", "--out",
                                                             "{folder}/out"], 2,
     r"records\[10\]\.k: expected an integer; received 10\.0", {}),
    ("trajectory-k-out-of-order", traj(set_("records.10.k", 11)), ["certify", "--trajectory", "{file}", "--out",
                                                                  "{folder}/out"], 2,
     r"records\[10\]\.k: expected 10 .*; received 11", {}),
    # 9: an entry out of the documented range
    ("trajectory-theta_hat-1e308", traj(set_("records.10.theta_hat", [1e308, 0])),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2,
     r"records\[10\]\.theta_hat\[0\]: expected .*magnitude.*1e\+308", {}),
    # 10: a device given as an input file (the read stops early: exit 2 at once)
    ("trajectory-dev-zero", files(), ["certify", "--trajectory", "/dev/zero", "--out", "{folder}/out"], 2,
     r"/dev/zero", {}),
    ("trajectory-dev-urandom", files(), ["certify", "--trajectory", "/dev/urandom", "--out", "{folder}/out"], 2,
     r"/dev/urandom", {}),
    ("problem-dev-zero", files(), ["design", "/dev/zero"], 2, r"/dev/zero", {}),
    ("points-dev-zero", files(), ["coverage", "--points", "/dev/zero"], 2, r"--points.*/dev/zero",
     {}),
    ("problem-over-size-limit", text("p.json", " " * (64 * 2**20 + 1)), ["design", "{file}"], 2,
     r"file: expected at most 67,108,864 bytes", {}),
    ("corpus-over-size-limit", files(c=sparse_file("c.json", 100 * 2**20)), ["solvers", "--corpus", "{c}"], 2,
     r"file: expected at most 67,108,864 bytes \(the size limit of a corpus file.*104,857,600 bytes",
     {}),
    ("corpus-gzip-over-size-limit", text("c.json.gz", gzip.compress(b" " * (64 * 2**20 + 1))),
     ["solvers", "--corpus", "{file}"], 2, r"c\.json\.gz: expected at most 67,108,864 bytes of JSON after decompression",
     {}),
    # 11: --max-memory that would disable the limit
    ("run-max-memory-nan", problem(lambda d: None), ["run", "{file}", "--max-memory", "nan"], 2,
     r"'--max-memory'.*nan", {}),
    ("run-max-memory-inf", problem(lambda d: None), ["run", "{file}", "--max-memory", "inf"], 2,
     r"'--max-memory'.*inf", {}),
    ("run-max-memory-negative", problem(lambda d: None), ["run", "{file}", "--max-memory", "-5"], 2,
     r"'--max-memory'.*-5", {}),
    # 12: schedulers that cannot be used
    ("campaign-scheduler-unreachable", files(), ["campaign", "--systems", "1", "--scheduler", "tcp://127.0.0.1:1",
                                                 "--store", "{folder}/c.sqlite"], 2,
     r"--scheduler: expected a reachable Dask scheduler.*tcp://127\.0\.0\.1:1", {}),
    ("campaign-scheduler-not-a-url", files(), ["campaign", "--systems", "1", "--scheduler", "not a url",
                                               "--store", "{folder}/c.sqlite"], 2,
     r"--scheduler: expected an address .*tcp://host:port.*'not a url'", {}),
    # 13: a full disk under certify --out
    ("certify-out-disk-full", files(t=good_traj), ["certify", "--trajectory", "{t}", "--out", "{folder}/D"], 2,
     r"--out: .*No space left on device.*nothing was written", {"patch": disk_full_on_write}),
    # 14: a full disk under the campaign store, and under --report
    ("campaign-store-disk-full", files(), ["campaign", "--systems", "1", "--backends", "drake", "--steps", "2",
                                           "--store", "{folder}/c.sqlite"], 2,
     r"--store: .*database or disk is full", {"patch": disk_full_in_sqlite}),
    ("campaign-report-disk-full", files(s=a_store), ["campaign", "--store", "{s}", "--report", "{folder}/r.html"], 2,
     r"--report: .*No space left on device.*nothing was written", {"patch": disk_full_on_report}),
    # 18: the certificate of a run whose design sets x0_facets = 12 at n = 6 checks the design that ran
    ("certify-n6-x0_facets-12", chain_problem(6, {"x0_facets": 12, "x0_template": "mrpi"}),
     ["certify", "{file}", "--out", "{folder}/../D"], 0, r"design\.x0_vertices +pass.*CERTIFIED: all \d+ claims hold", {}),
]


def _snapshot(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def _masked(output: str) -> str:
    return re.sub(r"\[\d+(\.\d+)? s\]", "[t]", output)


@pytest.mark.parametrize("row", ROWS, ids=[row[0] for row in ROWS])
def test_hostile_input(row, tmp_path, monkeypatch):
    case, build, args, code, pattern, extras = row
    folder = tmp_path / "in"
    folder.mkdir()
    names = {"folder": str(folder), **{k: str(v) for k, v in build(folder).items()}}
    argv = [a.format(**names) for a in args]
    monkeypatch.chdir(folder)
    before = _snapshot(folder)
    if "patch" in extras:
        extras["patch"](monkeypatch)
    result = CliRunner().invoke(main, argv)
    output = result.output
    assert result.exit_code == code, f"{case}: exit {result.exit_code}\n{output}\n{result.exception!r}"
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in output
    assert re.search(pattern, output, re.DOTALL), f"{case}: {pattern!r} not in\n{output}"
    created = _snapshot(folder) - before
    assert not created, f"{case}: wrote {sorted(created)}"
    if "same_as" in extras:
        reference = CliRunner().invoke(main, extras["same_as"])
        assert reference.exit_code == 0
        assert _masked(result.stdout) == _masked(reference.stdout)


# -- real processes ------------------------------------------------------------------------------------
def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), "PYTHONUNBUFFERED": "1"}


def _amcp(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "amcp_drake", *args], env=_env(), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True, **kwargs)


def _finish(proc: subprocess.Popen, seconds: float = GUARD_SECONDS) -> tuple[int, str, str]:
    try:
        out, err = proc.communicate(timeout=seconds)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        raise AssertionError(f"did not end within {seconds} s:\n{out}\n{err}") from None
    return proc.returncode, out, err


def _completions(store: Path) -> list[tuple[int, int]]:
    db = sqlite3.connect(f"{store.resolve().as_uri()}?mode=ro", uri=True)
    try:
        return sorted(db.execute("SELECT campaign_seed, idx FROM completions"))
    finally:
        db.close()


def test_two_resumes_of_one_store_at_once_never_duplicate_work_or_rows(tmp_path):
    """Two ``amcp campaign --resume`` processes started together on one store: the store is held by one
    of them (the other exits 2 naming the store and its holder, or finds the work done); every
    problem is completed exactly once."""
    from amcp_drake.studies.campaign import campaign_settings
    from amcp_drake.studies.campaign_store import CampaignStore

    store_path = tmp_path / "c.sqlite"
    store = CampaignStore(store_path)
    store.record_settings(campaign_settings(0, 2, ("drake",), 2))
    store.close()
    args = ("campaign", "--systems", "2", "--backends", "drake", "--steps", "2", "--workers", "1", "--store",
            str(store_path), "--resume")
    procs = [_amcp(*args, cwd=tmp_path) for _ in range(2)]
    results = [_finish(proc) for proc in procs]
    codes = sorted(code for code, _, _ in results)
    assert codes[0] in (0, 1), results  # one ran the campaign (1: a drawn problem failed a claim)
    if codes[1] == 2:
        refused = next(err for code, _, err in results if code == 2)
        assert re.search(r"--store: .*in use by another amcp campaign", refused), refused
        assert "Traceback" not in refused
    assert _completions(store_path) == [(0, 0), (0, 1)]


def _wait_for(predicate, proc: subprocess.Popen, seconds: float = GUARD_SECONDS) -> None:
    deadline = time.monotonic() + seconds
    while not predicate():
        assert proc.poll() is None, f"ended early: {proc.communicate()}"
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


def test_sigterm_during_certify_removes_the_staging_folder_and_says_so(tmp_path):
    """SIGTERM while ``amcp certify`` writes its bundle: the staging folder is removed, D holds nothing,
    and one line says what happened (no traceback)."""
    out = tmp_path / "D"
    proc = _amcp("certify", "--trajectory", str(TRAJECTORY_DATA), "--out", str(out))
    try:
        _wait_for(lambda: out.is_dir() and any(out.glob(".certify-staging-*")), proc)
        proc.send_signal(signal.SIGTERM)
        code, stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert code == 128 + signal.SIGTERM, (code, stderr)
    assert "Traceback" not in stderr
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert lines and re.fullmatch(r"interrupted \(SIGTERM\): .*nothing written.*", lines[-1]), stderr
    assert not list(out.glob(".certify-staging-*"))
    assert not list(out.glob("*"))


@pytest.mark.parametrize("signum, group", [(signal.SIGTERM, False), (signal.SIGINT, True)], ids=["SIGTERM", "Ctrl-C"])
def test_signal_during_a_campaign_stops_the_workers_and_says_how_to_resume(tmp_path, signum, group):
    """SIGTERM to the process, or SIGINT to its whole process group (what Ctrl-C in a terminal does, so the
    Dask worker processes get it too), while a campaign runs (after its first problem is stored): exit
    128 + signal, no traceback from the process or its workers, one line naming the resume command;
    the store holds whole problems only and a resume completes the rest without running any twice."""
    store_path = tmp_path / "c.sqlite"
    args = ("campaign", "--systems", "6", "--backends", "drake", "--steps", "2", "--workers", "1", "--store",
            str(store_path))

    def stored() -> bool:
        try:
            return bool(_completions(store_path))
        except sqlite3.Error:
            return False

    proc = _amcp(*args, cwd=tmp_path)
    try:
        _wait_for(stored, proc)
        if group:
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        code, stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert code == 128 + signum, (code, stderr)
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr and "Aborted" not in stderr, stderr
    lines = [line for line in stderr.splitlines() if line.strip() and "campaign:" not in line]  # the progress bar
    assert len(lines) == 1, stderr
    assert re.fullmatch(rf"interrupted \({signal.Signals(signum).name}\): \d+ of 6 problems stored in .*c\.sqlite; "
                        r"resume with: amcp campaign .*--resume", lines[0]), stderr
    first = _completions(store_path)
    assert 1 <= len(first) < 6 and len(set(first)) == len(first)
    code, stdout, stderr = _finish(_amcp(*args, "--resume", cwd=tmp_path))
    assert code in (0, 1), stderr
    assert _completions(store_path) == [(0, i) for i in range(6)]


def test_trajectories_in_tests_data_are_valid_against_the_schema():
    """Every recorded trajectory of tests/data loads (the schema and the consistency checks accept what
    amcp writes)."""
    from amcp_drake.online.simulate import Trajectory

    found = sorted(Path(__file__).parent.joinpath("data").rglob("*trajectory*.json.gz"))
    assert len(found) >= 5
    for path in found:
        assert Trajectory.load(path).records


def test_a_saved_trajectory_loads_back(tmp_path, example_spec):
    """A trajectory written by amcp (here a failed final step is not involved) is read back with the same
    numbers: the schema accepts its own output."""
    import numpy as np

    from amcp_drake.online.simulate import Trajectory

    loaded = Trajectory.load(TRAJECTORY_DATA)
    path = loaded.save(tmp_path / "t.json")
    again = Trajectory.load(path)
    assert np.array_equal(again.x, loaded.x) and len(again.records) == len(loaded.records)
    assert json.loads(path.read_text())["stop_reason"] == "completed"


def test_answers_field_of_a_record_is_accepted_with_its_documented_shape(tmp_path):
    """A record may carry ``answers``: a list of {problem, outcome, kind, check}; another outcome is refused."""

    from amcp_drake.model.errors import TrajectoryError
    from amcp_drake.online.simulate import Trajectory

    data = trajectory()
    data["records"][3]["answers"] = [{"problem": "tube_qp", "outcome": "resolved", "kind": "plain", "check": "kkt"}]
    data["records"][4]["answers"] = None  # provenance unknown (what amcp writes for a record without it)
    path = tmp_path / "t.json"
    path.write_text(json.dumps(data))
    loaded = Trajectory.load(path)
    assert loaded.records[3].answers == data["records"][3]["answers"] and loaded.records[4].answers is None
    for key, value in (("outcome", "maybe"), ("problem", "qp")):
        data["records"][3]["answers"][0] = {"problem": "tube_qp", "outcome": "resolved", "kind": "", "check": "",
                                            key: value}
        path.write_text(json.dumps(data))
        with pytest.raises(TrajectoryError, match=rf"records\[3\]\.answers\[0\]\.{key}: expected one of"):
            Trajectory.load(path)


def test_the_schema_lists_the_answer_problems_and_outcomes_the_controller_writes():
    from amcp_drake.model.trajectory_schema import trajectory_schema
    from amcp_drake.online import answers

    entry = trajectory_schema()["$defs"]["answer"]["properties"]
    assert tuple(entry["problem"]["enum"]) == answers.PROBLEMS
    assert tuple(entry["outcome"]["enum"]) == answers.OUTCOMES


def test_problem_example_file_unchanged_by_row_scaling():
    """Example 1's own rows are unit rows: loading it scales nothing (no note)."""
    from amcp_drake.model.examples import get_example

    assert get_example("lorenzen2019").notes == ()
    assert example()["Theta"]["h"] == [1, 1, 1, 1, 1, 1]


def test_sigterm_during_verify_stops_its_pytest_child_and_says_so(tmp_path):
    """SIGTERM while ``amcp verify`` waits for its property-suite child: exit 143 with one line, and no
    process of its group is left (the child pytest is stopped too)."""
    proc = _amcp("verify", "--backend", "drake", cwd=tmp_path)
    try:
        assert proc.stdout.readline().startswith("running: ")
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        code, stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert code == 128 + signal.SIGTERM, (code, stderr)
    assert "Traceback" not in stderr
    assert re.search(r"^interrupted \(SIGTERM\): the property suite was stopped", stderr, re.MULTILINE), stderr
    deadline = time.monotonic() + GUARD_SECONDS
    while True:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        assert time.monotonic() < deadline, "a process of the group is still running"
        time.sleep(0.1)


def test_the_compiled_schema_check_accepts_what_amcp_writes_and_agrees_with_jsonschema():
    """The one-pass predicate that accepts valid trajectories (jsonschema runs only on invalid ones) is
    used (not None), accepts every trajectory of tests/data, and rejects what jsonschema rejects."""

    import jsonschema

    from amcp_drake.model.trajectory_schema import _fast_check, trajectory_schema

    fast = _fast_check()
    assert fast is not None
    reference = jsonschema.Draft202012Validator(trajectory_schema())
    good = trajectory()
    assert fast(good) and reference.is_valid(good)
    for path, value in (("records.3.k", -1), ("records.3.status", "fine"), ("theta_star.1", "0.2"),
                        ("records.3.Lambda.0.0.0.0", True), ("design.mu", 2e15), ("records.3.pe_bounds", [1.0]),
                        ("options.window", 0), ("stop_reason", "done"), ("records.3.times.total", "1"),
                        ("records.3.answers", [{"problem": "qp", "outcome": "first", "kind": "", "check": ""}]),
                        ("records.3.answers", {})):
        data = json.loads(json.dumps(good))
        set_(path, value)(data)
        assert not reference.is_valid(data), path
        assert not fast(data), path


def test_an_endless_pipe_under_a_memory_limit_exits_2_naming_the_file(tmp_path):
    """``amcp certify --trajectory /dev/stdin`` fed by ``yes`` (text without end) in a process whose address
    space is limited to 1.5 GB: exit 2 naming the file (the size limit, or memory running out before it),
    no traceback, nothing written."""
    import resource

    def limit_memory() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (1536 * 2**20, 1536 * 2**20))

    out = tmp_path / "D"
    source = subprocess.Popen(["yes"], stdout=subprocess.PIPE)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "amcp_drake", "certify", "--trajectory", "/dev/stdin", "--out",
                                 str(out)], env=_env(), stdin=source.stdout, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True, preexec_fn=limit_memory)
        source.stdout.close()
        code, stdout, stderr = _finish(proc)
    finally:
        source.kill()
        source.wait()
    assert code == 2, (code, stderr)
    assert "Traceback" not in stderr and "MemoryError\n" not in stderr
    assert re.search(r"^error: file: expected (at most 2,147,483,648 bytes|a trajectory file that fits in the memory "
                     r"available).*/dev/stdin", stderr, re.MULTILINE), stderr
    assert not out.exists()


# -- full disks: a real tmpfs (needs root, as CI runs), and a file-size limit (any user) ----------------
@contextlib.contextmanager
def _tmpfs(folder: Path, size: str):
    """A tmpfs of ``size`` mounted at ``folder`` for the block (root only: CI runs as root; elsewhere the
    test is skipped visibly, and the RLIMIT_FSIZE tests below still run)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root (CI runs as root); test_*_file_size_limit simulate a full disk")
    folder.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(folder)],
                             capture_output=True, text=True)
    assert mounted.returncode == 0, f"root could not mount a tmpfs: {mounted.stderr}"
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=True)


def _fill(folder: Path) -> Path:
    """Write zeros into ``folder`` until its file system is full (ENOSPC); returns the file."""
    path = folder / "fill"
    with open(path, "wb", buffering=0) as handle:
        try:
            while True:
                handle.write(b"\0" * 4096)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC, exc
    return path


def test_certify_out_on_a_full_tmpfs_exits_2_naming_out_and_writes_nothing(tmp_path):
    """``amcp certify --out`` on a 200 KB tmpfs (the bundle needs about 430 KB): exit 2 naming --out and
    ENOSPC, no traceback, nothing left on the file system (the staging folder is removed)."""
    with _tmpfs(tmp_path / "disk", "200k") as disk:
        code, stdout, stderr = _finish(_amcp("certify", "--trajectory", str(TRAJECTORY_DATA), "--out",
                                             str(disk / "D")))
        left = sorted(str(p.relative_to(disk)) for p in disk.rglob("*"))
    assert code == 2, (code, stderr)
    assert "Traceback" not in stderr
    assert re.search(r"^error: --out: .*No space left on device \(ENOSPC\); nothing was written", stderr,
                     re.MULTILINE), stderr
    assert left == []


@pytest.mark.slow
def test_campaign_on_a_disk_that_fills_up_exits_2_and_resumes_without_running_a_problem_twice(tmp_path):
    """A campaign whose tmpfs is filled to the brim after its first problem is stored: exit 2 naming
    --store (no traceback, whole problems only in the store); ``--report`` onto that full disk: exit 2
    naming --report, nothing written; once space is freed, ``--resume`` completes every problem exactly once."""
    with _tmpfs(tmp_path / "disk", "2m") as disk:
        store_path = disk / "c.sqlite"
        args = ("campaign", "--systems", "6", "--backends", "drake", "--steps", "2", "--workers", "1", "--store",
                str(store_path))

        def stored() -> bool:
            try:
                return bool(_completions(store_path))
            except sqlite3.Error:
                return False

        proc = _amcp(*args, cwd=tmp_path)
        try:
            _wait_for(stored, proc)
            fill = _fill(disk)
            code, stdout, stderr = _finish(proc)
        finally:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
        assert code == 2, (code, stderr)
        assert "Traceback" not in stderr
        assert re.search(r"^error: --store: .*(database or disk is full|disk I/O error).*--resume", stderr,
                         re.MULTILINE), stderr
        first = _completions(store_path)
        assert 1 <= len(first) < 6 and len(set(first)) == len(first)
        code, stdout, stderr = _finish(_amcp("campaign", "--store", str(store_path), "--report",
                                             str(disk / "r.html"), cwd=tmp_path))
        assert code == 2 and "Traceback" not in stderr, (code, stderr)
        assert re.search(r"^error: --report: .*No space left on device.*nothing was written", stderr, re.MULTILINE)
        assert sorted(p.name for p in disk.iterdir() if not p.name.startswith("c.sqlite")) == ["fill"]
        fill.unlink()
        code, stdout, stderr = _finish(_amcp(*args, "--resume", cwd=tmp_path))
        assert code in (0, 1), stderr
        assert _completions(store_path) == [(0, i) for i in range(6)]


def _file_size_limit(limit: int):
    def apply() -> None:
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    return apply


def test_certify_out_under_a_file_size_limit_exits_2_naming_out_and_writes_nothing(tmp_path):
    """A full disk simulated without root: RLIMIT_FSIZE of 200 KB in the child (a write beyond it fails
    with EFBIG, "File too large", where a full disk gives ENOSPC; Python ignores SIGXFSZ): exit 2 naming
    --out and the cause, nothing left in the folder."""
    out = tmp_path / "D"
    proc = subprocess.Popen([sys.executable, "-m", "amcp_drake", "certify", "--trajectory", str(TRAJECTORY_DATA),
                             "--out", str(out)], env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_file_size_limit(200 * 1024))
    code, stdout, stderr = _finish(proc)
    assert code == 2, (code, stderr)
    assert "Traceback" not in stderr
    assert re.search(r"^error: --out: .*File too large \(EFBIG\); nothing was written", stderr, re.MULTILINE), stderr
    assert not out.exists() or not list(out.rglob("*"))


def test_a_store_whose_checkpoint_a_full_disk_stopped_is_resumable(tmp_path):
    """What a full disk leaves of a store in WAL mode: the checkpoint rewrote page 1 (which records the
    whole database size) but could not extend the file, so the pages past its end are only in the
    write-ahead log. SQLite reads them from there; the store is accepted, every problem is read back,
    quick_check passes, and a writer finishes the checkpoint."""
    import shutil

    from amcp_drake.studies.campaign import campaign_settings
    from amcp_drake.studies.campaign_store import CampaignStore, inspect_store

    original = tmp_path / "a.sqlite"
    store = CampaignStore(original)
    store.record_settings(campaign_settings(0, 3, ("drake",), 2))
    store.db.execute("PRAGMA wal_autocheckpoint = 0")
    for i in range(3):
        store.add({"campaign_seed": 0, "idx": i, "status": "pass",
                   "claims": {"drake": {f"claim{j}": {"status": "pass", "margin": 1.0} for j in range(40)}}})
    left = tmp_path / "b.sqlite"
    shutil.copyfile(original, left)
    shutil.copyfile(tmp_path / "a.sqlite-wal", tmp_path / "b.sqlite-wal")
    store.db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    page_one = original.read_bytes()[:4096]
    pages = int.from_bytes(page_one[28:32], "big")
    store.close()
    assert pages > 1
    with open(left, "r+b") as handle:
        handle.write(page_one)
        handle.truncate(4096)
    assert inspect_store(left).kind == "store"
    resumed = CampaignStore(left, exclusive=True)
    try:
        assert resumed.done(0) == {0, 1, 2}
        assert [r[0] for r in resumed.db.execute("PRAGMA quick_check")] == ["ok"]
    finally:
        resumed.close()
    assert left.stat().st_size == pages * 4096


def test_a_truncated_store_without_a_write_ahead_log_is_still_refused(tmp_path):
    """The same truncated file with no write-ahead log beside it holds nothing past its end: refused."""
    from amcp_drake.model.errors import CampaignStoreError
    from amcp_drake.studies.campaign import campaign_settings
    from amcp_drake.studies.campaign_store import CampaignStore, inspect_store

    path = tmp_path / "c.sqlite"
    store = CampaignStore(path)
    store.record_settings(campaign_settings(0, 3, ("drake",), 2))
    for i in range(3):
        store.add({"campaign_seed": 0, "idx": i, "status": "pass",
                   "claims": {"drake": {f"claim{j}": {"status": "pass", "margin": 1.0} for j in range(40)}}})
    store.close()
    assert not (tmp_path / "c.sqlite-wal").exists()
    with open(path, "r+b") as handle:
        handle.truncate(4096)
    with pytest.raises(CampaignStoreError, match=r"truncated \(its header records \d+ pages"):
        inspect_store(path)


def test_a_long_design_prints_progress_while_it_runs(tmp_path):
    """``amcp design --progress-every 0.5`` of Example 1 with an mrpi template of 160 facets (seconds of work;
    the memory limit raised for the design's own stages): a progress line ("  ... design: <stage> (<t> s CPU)") reaches stderr while the design is still working, shown
    without a clock: a SIGTERM sent when the first one arrives stops the design before its checks are printed
    (a design that printed its progress only at its end would have finished by then). The interval itself is
    tested with a fake clock in tests/test_scale_design.py."""
    data = example()
    data["design"].update({"x0_template": "mrpi", "x0_facets": 160})
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    proc = _amcp("design", str(path), "--max-memory", "8192", "--progress-every", "0.5")
    try:
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if re.match(r"\s*\.\.\. design: .*\(\d+ s CPU\)$", line.rstrip()):
                proc.send_signal(signal.SIGTERM)
                break
        code, stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert code != 0 and "all design checks pass" not in stdout, (code, "".join(seen) + stderr, stdout)
    assert "Traceback" not in stderr


@pytest.mark.parametrize("value", ["0", "nan", "inf"])
def test_a_progress_interval_that_is_not_a_positive_finite_number_exits_2_naming_the_option(value):
    code, _, stderr = _finish(_amcp("design", "--example", "lorenzen2019", "--progress-every", value))
    assert code == 2 and "--progress-every" in stderr and "Traceback" not in stderr, stderr


def test_a_campaign_beside_another_dask_process_prints_no_port_warning(tmp_path):
    """Port 8787 (Dask's default HTTP port) held by another process: a campaign runs with nothing on
    stderr but its progress bar (its scheduler listens on a free loopback port, no dashboard)."""
    import socket

    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    except OSError:
        pass  # held by another process already: the same situation
    try:
        code, stdout, stderr = _finish(_amcp("campaign", "--systems", "1", "--backends", "drake", "--steps", "2",
                                             "--workers", "1", "--store", str(tmp_path / "c.sqlite"), cwd=tmp_path))
    finally:
        holder.close()
    assert code in (0, 1), stderr
    assert [line for line in stderr.replace("\r", "\n").splitlines() if line.strip() and "campaign:" not in line] == []


@pytest.mark.parametrize("command", ["run", "coverage"])
def test_sigterm_during_run_and_coverage_ends_with_one_line_and_writes_nothing(tmp_path, command):
    """SIGTERM while ``amcp run --save`` steps through the closed loop, or while ``amcp coverage``
    computes its first region: exit 143, the last line of stderr says what was (not) written, no
    traceback, and neither the trajectory nor any coverage file exists."""
    out = tmp_path / "out"
    if command == "run":
        proc = _amcp("run", "--save", str(out / "t.json"), cwd=tmp_path)
        started = lambda: proc.stdout.readline().lstrip().startswith("1 ")  # noqa: E731 - step 1 printed
    else:
        proc = _amcp("coverage", "--out", str(out), cwd=tmp_path)
        started = lambda: "robust Θ:" in proc.stderr.read(64)  # noqa: E731 - its progress bar
    try:
        deadline = time.monotonic() + GUARD_SECONDS
        while not started():
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        proc.send_signal(signal.SIGTERM)
        code, stdout, stderr = _finish(proc)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert code == 128 + signal.SIGTERM, (code, stderr)
    assert "Traceback" not in stderr
    last = [line for line in stderr.replace("\r", "\n").splitlines() if line.strip()][-1]
    expected = {"run": r"interrupted \(SIGTERM\): the run stopped; nothing saved to .*t\.json; run the command again",
                "coverage": r"interrupted \(SIGTERM\): nothing new written to .*out \(each file is written whole or "
                            r"not at all\); run the command again"}[command]
    assert re.fullmatch(expected, last), stderr
    assert not out.exists() or not list(out.rglob("*"))
