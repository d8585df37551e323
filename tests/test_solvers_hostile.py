"""`amcp solvers` and the CLI's path and limit options with files and values written by someone else:
corpus ids used as file names, text pasted into generated scripts, reproducer folders that hold foreign
or edited scripts, references that do not check, writes that fail (a full disk emulated by an
``OSError(ENOSPC)`` from the lowest write), empty paths and non-finite or overflowing limits.

Every case exits 2 with a message naming the field or option (no traceback) and leaves nothing
half-written; nothing of a file is ever executed."""

from __future__ import annotations

import ast
import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import click
import numpy as np
import pytest
import scipy.sparse as sp
from click.testing import CliRunner

from amcp_drake.cli import main
from amcp_drake.model import problem_io
from amcp_drake.model.errors import ProblemFileError
from amcp_drake.studies.solver_matrix import reproducers as repro
from amcp_drake.studies.solver_matrix.corpus import CorpusProblem, is_valid_id, load_problem
from amcp_drake.studies.solver_matrix.reference import check_reference
from amcp_drake.studies.solver_matrix.runner import Cell, MatrixRun
from amcp_drake.studies.solver_matrix.staging import STAGING_PREFIX, staged
from tests.guards import GUARD_SECONDS

STUB = "py:tests.solver_stubs:correct"


def lp(problem_id: str = "x-geq-1", reference: dict | None = None) -> CorpusProblem:
    """minimise x s.t. x >= 1: optimum x = 1, objective 1 (by hand)."""
    return CorpusProblem(id=problem_id, kind="support_lp", P=None, q=np.array([1.0]), r=0.0, A=sp.csr_matrix([[1.0]]),
                         lower=np.array([1.0]), upper=np.array([np.inf]), lb=np.array([-np.inf]), ub=np.array([np.inf]),
                         reference=reference if reference is not None else {"status": "optimal", "x": [1.0], "objective": 1.0})


def corpus_dir(folder: Path, data: dict) -> Path:
    corpus = folder / "corpus"
    corpus.mkdir()
    (corpus / "p.json").write_text(json.dumps(data))
    return corpus


def invoke(args: list[str]):
    return CliRunner().invoke(main, args, catch_exceptions=False)


def files_below(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


def assert_refused(result, names: str) -> None:
    assert result.exit_code == 2, result.output
    assert "Traceback" not in result.output
    assert names in result.output, result.output


# -- corpus ids ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["/../../x/X", "../X", "a/b", "a\\b", ".hidden", "-rf", "", "a" * 65, "a b",
                                   "x\x00", "x\n", "é", 'a"""b', "a'''b", 7, None])
def test_an_id_outside_the_safe_characters_is_refused_naming_id(tmp_path, value):
    data = lp().to_dict()
    data["id"] = value
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ProblemFileError) as exc:
        load_problem(path)
    assert exc.value.field.endswith(": id")


@pytest.mark.parametrize(("value", "valid"), [("a" * 64, True), ("a" * 65, False), ("a.b-c_D9", True), ("9", True),
                                              ("_x", True), (".x", False), ("-x", False), ("x.", True)])
def test_the_id_pattern_at_its_edges(value, valid):
    assert is_valid_id(value) is valid


def test_a_traversal_id_writes_nothing_anywhere(tmp_path, monkeypatch):
    """An id `/../../x/X` is refused on load: exit 2 naming the field, before anything is run or written."""
    work = tmp_path / "deep" / "er"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    data = lp().to_dict()
    data["id"] = "/../../x/X"
    corpus = corpus_dir(work, data)
    before = files_below(tmp_path)
    result = invoke(["solvers", "--corpus", str(corpus), "--solvers", STUB, "--out", str(work / "out")])
    assert_refused(result, "id: expected 1 to 64 characters")
    assert files_below(tmp_path) == before


def test_reproducer_names_are_derived_from_validated_parts():
    assert repro.reproducer_name("drake:clarabel", "wrong", "p-1") == "drake-clarabel-wrong-p-1.py"
    assert repro.reproducer_name("cvxpy:OSQP", "crash", "p-1", "tight") == "cvxpy-osqp-crash-p-1-tight.py"
    for solver, verdict, pid in [("drake:clarabel", "wrong", "../x"), ("cvxpy:../../x", "wrong", "p"),
                                 ("py:mod:f", "wrong", "p"), ("drake:clarabel", "../w", "p")]:
        with pytest.raises((ValueError, ProblemFileError)):
            repro.reproducer_name(solver, verdict, pid)


# -- nothing of a corpus becomes code -------------------------------------------------------------------

INJECTED = "import pathlib; pathlib.Path({marker!r}).write_text('pwned')  # "


@pytest.mark.parametrize("quote", ['"""', "'''"])
def test_a_quote_in_an_id_is_refused_on_load(tmp_path, quote):
    data = lp().to_dict()
    data["id"] = f"x{quote}\n{INJECTED.format(marker=str(tmp_path / 'pwned'))}\n{quote}"
    result = invoke(["solvers", "--corpus", str(corpus_dir(tmp_path, data)), "--solvers", STUB, "--out", str(tmp_path / "o")])
    assert_refused(result, ": id: expected")
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize("quote", ['"""', "'''"])
def test_text_with_quotes_is_only_data_in_the_generated_script(tmp_path, quote):
    """Even a problem that bypassed the id check (built in Python) and a detail of the run carrying both
    quote styles end up as string literals: the script's statements are those of a clean script, and
    running it never runs the text."""
    pytest.importorskip("cvxpy")
    marker = tmp_path / "pwned"
    evil = f"{quote}\n{INJECTED.format(marker=str(marker))}\n{quote}"
    pr = lp(f"x{evil}")
    text = repro.script_text(pr, "cvxpy:CLARABEL", "default", "wrong", f"detail {evil}")
    clean = repro.script_text(lp(), "cvxpy:CLARABEL", "default", "wrong", "detail")

    def shape(source: str) -> list[str]:
        """The statements with every string constant blanked: equal shapes = the text added no code."""
        tree = ast.parse(source)
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                node.value = ""
        return [ast.dump(stmt) for stmt in tree.body]

    assert shape(text) == shape(clean)
    tree = ast.parse(text)
    assert evil in ast.get_docstring(tree, clean=False)
    data_literal = next(n for n in tree.body if isinstance(n, ast.Assign) and n.targets[0].id == "DATA").value.args[0].value
    assert json.loads(data_literal)["id"] == pr.id
    script = tmp_path / "script.py"
    script.write_text(text)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=GUARD_SECONDS, cwd=tmp_path)
    assert done.returncode == repro.DOES_NOT, done.stdout + done.stderr
    assert not marker.exists()


# -- --recheck runs only what the tool wrote --------------------------------------------------------------

def written_folder(folder: Path) -> str:
    """A reproducer folder as amcp solvers writes it (one script, cvxpy's Clarabel on x >= 1)."""
    repro.write_reproducer_folder(folder, [(lp(), "cvxpy:CLARABEL", "default", "wrong", "seen")])
    return repro.reproducer_name("cvxpy:CLARABEL", "wrong", "x-geq-1")


def evil_script(marker: Path) -> str:
    return f"import pathlib, sys\npathlib.Path({str(marker)!r}).write_text('ran')\nsys.exit(3)\n"


def test_recheck_refuses_foreign_edited_linked_hidden_and_folder_entries(tmp_path):
    pytest.importorskip("cvxpy")
    folder = tmp_path / "repro"
    folder.mkdir()
    good = written_folder(folder)
    marker = tmp_path / "ran"
    (folder / "foreign.py").write_text(evil_script(marker))
    (folder / ".hidden.py").write_text(evil_script(marker))
    (folder / "dir.py").mkdir()
    (folder / "dir.py" / "__main__.py").write_text(evil_script(marker))
    (tmp_path / "outside.py").write_text(evil_script(marker))
    (folder / "link.py").symlink_to(tmp_path / "outside.py")
    results = {r.script: r for r in repro.recheck(folder, time_limit=GUARD_SECONDS)}
    assert results[good].outcome == "no longer reproduces"
    for name, reason in [("foreign.py", "not in manifest.json"), (".hidden.py", "hidden"), ("dir.py", "a folder"),
                         ("link.py", "symbolic link")]:
        assert results[name].outcome == "refused" and reason in results[name].last_line, results[name]
        assert results[name].returncode is None
    assert not marker.exists()


def test_recheck_refuses_an_edited_script_and_a_forged_manifest_entry(tmp_path):
    folder = tmp_path / "repro"
    folder.mkdir()
    good = written_folder(folder)
    marker = tmp_path / "ran"
    script = folder / good
    script.write_text(script.read_text() + f"\n{INJECTED.format(marker=str(marker))}\n")
    manifest = json.loads((folder / repro.MANIFEST_NAME).read_text())
    # a forged entry: the foreign script listed under its true hash, once as a built-in and once as a problem
    (folder / repro.NONFINITE_NAME).write_text(evil_script(marker))
    forged = {"builtin": "nonfinite", "sha256": repro._sha256(evil_script(marker).encode())}
    (folder / "forged.py").write_text(evil_script(marker))
    manifest["files"][repro.NONFINITE_NAME] = forged
    manifest["files"]["forged.py"] = {**manifest["files"][good], "sha256": forged["sha256"]}
    (folder / repro.MANIFEST_NAME).write_text(json.dumps(manifest))
    results = {r.script: r for r in repro.recheck(folder)}
    assert {name: r.outcome for name, r in results.items()} == {good: "refused", repro.NONFINITE_NAME: "refused",
                                                                 "forged.py": "refused"}
    assert "SHA-256" in results[good].last_line and "SHA-256" in results[repro.NONFINITE_NAME].last_line
    assert "file name" in results["forged.py"].last_line
    assert not marker.exists()


def test_recheck_refuses_an_entry_whose_reference_does_not_verify(tmp_path):
    """A manifest entry (and its script, consistently rewritten) with the optimum lowered from 1 to 0.5."""
    folder = tmp_path / "repro"
    folder.mkdir()
    repro.write_reproducer_folder(folder, [(lp(reference={"status": "optimal", "x": [1.0], "objective": 0.5}),
                                            "cvxpy:CLARABEL", "default", "wrong", "seen")])
    (result,) = repro.recheck(folder)
    assert result.outcome == "refused" and "reference.objective" in result.last_line


def test_recheck_without_a_manifest_exits_2(tmp_path):
    marker = tmp_path / "ran"
    (tmp_path / "x.py").write_text(evil_script(marker))
    result = invoke(["solvers", "--recheck", str(tmp_path)])
    assert_refused(result, "manifest.json")
    assert not marker.exists()


@pytest.mark.parametrize(("manifest", "field"), [
    ("not json", "manifest.json"), ("[]", "format"), ('{"format": "amcp-reproducers", "version": 2, "files": {}}', "format"),
    ('{"format": "amcp-reproducers", "version": 1, "files": []}', "files"),
    ('{"format": "amcp-reproducers", "version": 1, "files": {"a.py": 1}}', "files"),
])
def test_a_malformed_manifest_exits_2_naming_it(tmp_path, manifest, field):
    marker = tmp_path / "ran"
    (tmp_path / "a.py").write_text(evil_script(marker))
    (tmp_path / "manifest.json").write_text(manifest)
    assert_refused(invoke(["solvers", "--recheck", str(tmp_path)]), field)
    assert not marker.exists()


@pytest.mark.parametrize(("rc", "verdict", "outcome"), [
    (3, "wrong", "reproduces"), (0, "wrong", "no longer reproduces"), (4, "wrong", "cannot run"),
    (1, "wrong", "error"), (2, "wrong", "error"), (5, "wrong", "error"), (None, "wrong", "timeout"),
    (-signal.SIGABRT, "crash", "reproduces"), (-signal.SIGSEGV, "crash", "reproduces"),
    (-signal.SIGABRT, "wrong", "error"), (-signal.SIGKILL, "crash", "error"), (1, "crash", "error"),
])
def test_only_the_documented_endings_count(rc, verdict, outcome):
    assert repro.outcome_of(rc, verdict) == outcome


def test_a_syntax_error_or_an_exception_is_an_error_not_a_reproduction():
    for text in ("def (:\n", "raise RuntimeError('boom')\n"):
        rc, _ = repro.run_isolated(text, "s.py", 60)
        assert rc == 1 and repro.outcome_of(rc, "wrong") == "error"


def test_a_reproducer_runs_with_a_minimal_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("AMCP_TEST_SECRET", "do-not-pass")
    rc, output = repro.run_isolated("import json, os, sys\nprint(json.dumps(dict(os.environ)))\nprint(os.getcwd())\n",
                                    "env.py", 60)
    assert rc == 0, output
    lines = output.splitlines()
    env, cwd = json.loads(lines[0]), lines[1]
    allowed = {"PATH", "PYTHONPATH", "HOME", "TMPDIR", "LC_ALL", "PYTHONDONTWRITEBYTECODE", "PYTHONNOUSERSITE",
               "LC_CTYPE"}   # LC_CTYPE: set by Python itself when it coerces the C locale
    assert set(env) <= allowed, set(env) - allowed
    assert env["HOME"] == cwd != os.environ.get("HOME") and not Path(cwd).exists()   # a private folder, removed


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.parametrize("limit", [GUARD_SECONDS, 2.0])   # no limit that a loaded machine reaches; a 2 s limit on a hang
def test_processes_a_reproducer_starts_are_killed_when_it_ends_or_times_out(tmp_path, limit):
    """The script starts a 300 s sleeper and exits (or, at the 2 s limit, hangs): after run_isolated the
    sleeper is gone."""
    pid_file = tmp_path / "pid"
    text = (f"import subprocess, sys, time, pathlib\np = subprocess.Popen(['sleep', '300'])\n"
            f"pathlib.Path({str(pid_file)!r}).write_text(str(p.pid))\n"
            + ("sys.exit(0)\n" if limit > 10 else "time.sleep(300)\n"))
    rc, _ = repro.run_isolated(text, "spawn.py", limit)
    assert rc == (0 if limit > 10 else None)
    pid = int(pid_file.read_text())
    deadline = time.monotonic() + GUARD_SECONDS   # only a guard: a killed sleeper is gone at once
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(pid)


# -- references verified again on load --------------------------------------------------------------------

@pytest.mark.parametrize(("reference", "field"), [
    ({"status": "optimal", "x": [1.0], "objective": 0.5}, "reference.objective"),     # lowered
    ({"status": "optimal", "x": [1.0], "objective": 1.0 - 4e-9}, "reference.objective"),   # 2x CONSISTENCY_TOL (1 + |f|)
    ({"status": "optimal", "x": [2.0], "objective": 2.0}, "reference.objective"),     # raised, consistent, suboptimal
    ({"status": "optimal", "x": [1.0 + 4e-7], "objective": 1.0 + 4e-7}, "reference.objective"),  # 2x KKT_TOL (1 + |f*|)
    ({"status": "optimal", "x": [0.5], "objective": 0.5}, "reference.x"),             # infeasible
    ({"status": "optimal", "x": [1.0]}, "reference.objective"),                       # missing
    ({"status": "optimal", "x": [1.0], "objective": "1.0"}, "reference.objective"),   # a string
    ({"status": "optimal", "x": [1.0], "objective": True}, "reference.objective"),
    ({"status": "optimal", "objective": 1.0}, "reference.x"),
    ({"status": "infeasible"}, "reference.status"),
    ({"status": "solved"}, "reference.status"),
    ({}, "reference.status"),
])
def test_a_reference_that_does_not_check_refuses_the_corpus(tmp_path, reference, field):
    data = lp().to_dict()
    data["reference"] = reference
    out = tmp_path / "out"
    result = invoke(["solvers", "--corpus", str(corpus_dir(tmp_path, data)), "--solvers", STUB, "--out", str(out)])
    assert_refused(result, field)
    assert not out.exists()


def test_a_reference_just_inside_the_consistency_tolerance_is_taken():
    check_reference(lp(reference={"status": "optimal", "x": [1.0], "objective": 1.0 - 1e-9}))   # CONSISTENCY_TOL (1 + |f|) / 2
    check_reference(lp(reference={"status": "optimal", "x": [1.0 + 1e-7], "objective": 1.0 + 1e-7}))  # KKT_TOL (1 + |f*|) / 2


# -- failed writes leave nothing ----------------------------------------------------------------------------

class _FullDisk:
    """Stands in for ``os`` in :mod:`amcp_drake.model.problem_io`: the ``fail_at``-th file opened for
    writing gets half its bytes, then ``OSError(ENOSPC)``."""

    def __init__(self, fail_at: int, code: int = errno.ENOSPC) -> None:
        self.count, self.fail_at, self.code = 0, fail_at, code

    def __getattr__(self, name):
        return getattr(os, name)

    def fdopen(self, fd, mode="r", *args, **kwargs):
        handle = os.fdopen(fd, mode, *args, **kwargs)
        self.count += 1
        if self.count < self.fail_at:
            return handle
        code = self.code

        class Failing:
            def __enter__(self):
                return self

            def __exit__(self, *exc):
                handle.close()

            def write(self, data):
                handle.write(data[: len(data) // 2])
                handle.flush()
                raise OSError(code, os.strerror(code))

        return Failing()


def matrix_with_findings() -> MatrixRun:
    pr = lp()
    return MatrixRun("default", 5.0, ["drake:clarabel", "cvxpy:OSQP"], [pr],
                     [Cell(pr.id, "drake:clarabel", "correct"), Cell(pr.id, "cvxpy:OSQP", "wrong", detail="off")])


@pytest.mark.parametrize("fail_at", [1, 2, 3])
def test_reproducers_on_a_full_disk_leave_no_file_and_no_folder(tmp_path, monkeypatch, fail_at):
    monkeypatch.setattr(problem_io, "os", _FullDisk(fail_at))
    out = tmp_path / "out"
    with pytest.raises(OSError) as exc, staged(out) as stage:
        repro.write_reproducers(matrix_with_findings(), stage / "reproducers")
    assert exc.value.errno == errno.ENOSPC
    assert not out.exists()


def test_staged_files_reach_their_folder_whole(tmp_path):
    out = tmp_path / "out"
    (out / "reproducers").mkdir(parents=True)
    (out / "other.txt").write_text("kept")
    with staged(out) as stage:
        written = repro.write_reproducers(matrix_with_findings(), stage / "reproducers")
    assert {p.name for p in (out / "reproducers").iterdir()} == {r.path.name for r in written} | {repro.MANIFEST_NAME}
    assert (out / "other.txt").read_text() == "kept" and not list(out.glob(f"{STAGING_PREFIX}*"))


def test_the_matrix_on_a_full_disk_exits_2_and_writes_nothing(tmp_path, monkeypatch):
    corpus = corpus_dir(tmp_path, lp().to_dict())
    monkeypatch.setattr(problem_io, "os", _FullDisk(1))
    out = tmp_path / "a" / "out"
    result = invoke(["solvers", "--corpus", str(corpus), "--solvers", STUB, "--out", str(out), "--time-limit", "30"])
    assert_refused(result, "--out")
    assert "ENOSPC" in result.output
    assert not (tmp_path / "a").exists()


def test_an_existing_out_folder_is_left_as_it_was_on_a_full_disk(tmp_path, monkeypatch):
    corpus = corpus_dir(tmp_path, lp().to_dict())
    out = tmp_path / "out"
    out.mkdir()
    (out / "solvers.json").write_text("{}")
    monkeypatch.setattr(problem_io, "os", _FullDisk(2, errno.EROFS))
    result = invoke(["solvers", "--corpus", str(corpus), "--solvers", STUB, "--out", str(out), "--time-limit", "30"])
    assert_refused(result, "EROFS")
    assert files_below(out) == {"solvers.json"} and (out / "solvers.json").read_text() == "{}"


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS])
def test_an_export_on_a_full_disk_leaves_nothing(tmp_path, monkeypatch, code):
    """One recorded projection (12) is verified and written, then the index hits ENOSPC."""
    from amcp_drake.studies.solver_matrix.export import Source, export_corpus

    def run(rec):
        from amcp_drake.backends.drake_ import DrakeBackend

        DrakeBackend().project(np.array([2.0, 0.0]), np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]),
                               np.ones(4))

    out = tmp_path / "corpus"
    with staged(tmp_path / "whole") as stage:   # without the failure: the problem and the index
        index = export_corpus(stage, [Source("one projection", run, slug="one", keep_all=True)])
    assert len(index["problems"]) == 1 and files_below(tmp_path / "whole") == {"index.json", index["problems"][0]["file"]}
    monkeypatch.setattr(problem_io, "os", _FullDisk(2, code))
    with pytest.raises(OSError), staged(out) as stage:
        export_corpus(stage, [Source("one projection", run, slug="one", keep_all=True)])
    assert not out.exists()


@pytest.mark.parametrize("folder", ["/proc/amcp-corpus", "/proc/self/amcp-corpus"])
@pytest.mark.parametrize("option", ["--export-corpus", "--out"])
def test_export_or_matrix_into_proc_exits_2_before_anything_runs(folder, option):
    assert_refused(invoke(["solvers", "--solvers", STUB, option, folder]), option)


def test_run_save_on_a_full_disk_exits_2_and_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(problem_io, "os", _FullDisk(1))
    result = invoke(["run", "--steps", "2", "--save", str(tmp_path / "t" / "run.json.gz")])
    assert_refused(result, "--save")
    assert files_below(tmp_path) == set()


# -- empty paths and limits, on every command --------------------------------------------------------------

def _commands():
    ctx = click.Context(main)
    return [(name, main.get_command(ctx, name)) for name in main.list_commands(ctx)]


PATH_OPTIONS = [(name, param.opts[0]) for name, cmd in _commands() for param in cmd.params
                if isinstance(param, click.Option) and isinstance(param.type, click.Path)]


def test_the_path_options_found_include_the_known_ones():
    assert {("solvers", o) for o in ("--out", "--corpus", "--recheck", "--export-corpus", "--hard-cases", "--examples")} | {
        ("run", "--save"), ("certify", "--out"), ("certify", "--trajectory"), ("coverage", "--points"),
        ("bench", "--out"), ("campaign", "--store"), ("campaign", "--report"), ("compare", "--out")} <= set(PATH_OPTIONS)


@pytest.mark.parametrize(("command", "option"), PATH_OPTIONS)
def test_an_empty_path_is_refused_for_every_path_option(tmp_path, monkeypatch, command, option):
    monkeypatch.chdir(tmp_path)
    result = invoke([command, option, ""])
    assert_refused(result, option)
    assert files_below(tmp_path) == set()


LIMIT_OPTIONS = [(name, param.opts[0]) for name, cmd in _commands() for param in cmd.params
                 if isinstance(param, click.Option) and param.opts[0] in ("--time-limit", "--max-memory")]


def test_the_limit_options_found_include_the_known_ones():
    assert {("solvers", "--time-limit"), ("run", "--max-memory"), ("design", "--max-memory")} <= set(LIMIT_OPTIONS)


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e308", "0", "-1"])
@pytest.mark.parametrize(("command", "option"), LIMIT_OPTIONS)
def test_a_non_finite_overflowing_or_non_positive_limit_is_refused(tmp_path, monkeypatch, command, option, value):
    monkeypatch.chdir(tmp_path)
    result = invoke([command, option, value])
    assert_refused(result, option)
    assert files_below(tmp_path) == set()


def test_a_new_run_replaces_its_own_earlier_reproducers_and_keeps_other_files(tmp_path):
    """reproducers/ holds an earlier run's script (listed, unchanged) and a user's file: a new run with a
    Drake configuration writes its own and removes only the earlier script."""
    corpus = corpus_dir(tmp_path, lp().to_dict())
    folder = tmp_path / "out" / "reproducers"
    folder.mkdir(parents=True)
    repro.write_reproducer_folder(folder, [(lp(), "cvxpy:CLARABEL", "default", "wrong", "earlier")])
    (folder / "notes.txt").write_text("mine")
    result = invoke(["solvers", "--corpus", str(corpus), "--solvers", "drake:clarabel", "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert files_below(folder) == {repro.NONFINITE_NAME, repro.MANIFEST_NAME, "notes.txt"}
    assert set(json.loads((folder / repro.MANIFEST_NAME).read_text())["files"]) == {repro.NONFINITE_NAME}


def test_recheck_prints_file_names_without_terminal_escapes(tmp_path):
    written_folder(tmp_path)
    (tmp_path / "\x1b]0;title\x07x.py").write_text("print('hi')\n")
    result = invoke(["solvers", "--recheck", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "\x1b" not in result.output and "\x07" not in result.output
    assert "\\x1b]0;title\\x07x.py" in result.output and "refused" in result.output


def test_verifying_an_lp_reference_prints_nothing(tmp_path):
    """The exact LP check builds a HiGHS model, whose constructor prints a banner once per process."""
    code = ("import numpy as np, scipy.sparse as sp\n"
            "from tests.test_solvers_hostile import lp\n"
            "from amcp_drake.studies.solver_matrix.reference import check_reference\n"
            "check_reference(lp())\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=GUARD_SECONDS,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout == ""


def lmi_problem(s: int) -> CorpusProblem:
    """minimise x s.t. x·I_s ⪰ 0: optimum x = 0 (by hand), one LMI block of size s."""
    G = sp.csr_matrix(np.eye(s).reshape(-1, order="F")[:, None])
    return CorpusProblem(id=f"lmi-{s}", kind="gain_sdp", P=None, q=np.array([1.0]), r=0.0, A=sp.csr_matrix((0, 1)),
                         lower=np.zeros(0), upper=np.zeros(0), lb=np.array([-np.inf]), ub=np.array([np.inf]),
                         lmis=[(s, G, np.zeros(s * s))], reference={"status": "optimal", "x": [0.0], "objective": 0.0})


def test_a_problem_too_large_to_verify_on_load_is_refused_before_solving(monkeypatch):
    from amcp_drake.studies.solver_matrix import reference
    from amcp_drake.studies.solver_matrix.reference import MAX_CHECK_LMI, MAX_CHECK_SIZE

    check_reference(lmi_problem(MAX_CHECK_LMI))   # at the limit: verified

    def no_solve(pr):
        raise AssertionError("a problem above the limit was solved")

    monkeypatch.setattr(reference, "verify_reference", no_solve)
    with pytest.raises(ProblemFileError, match="LMI block 201"):
        check_reference(lmi_problem(MAX_CHECK_LMI + 1))
    n = MAX_CHECK_SIZE // 2 + 1   # n nonzeros of A plus n variables: just above the limit
    big = CorpusProblem(id="big", kind="support_lp", P=None, q=np.ones(n), r=0.0, A=sp.identity(n, format="csr"),
                        lower=np.zeros(n), upper=np.full(n, np.inf), lb=np.full(n, -np.inf), ub=np.full(n, np.inf),
                        reference={"status": "optimal", "x": [0.0] * n, "objective": 0.0})
    with pytest.raises(ProblemFileError, match="nonzeros"):
        check_reference(big)


def test_a_folder_of_an_earlier_template_is_written_again_from_its_manifest(tmp_path):
    """A script under an old name with an old text (its manifest consistent with it) is refused by recheck;
    rewrite_folder writes it again from the entry's data, removes the old name, keeps other files."""
    good = written_folder(tmp_path)
    manifest = json.loads((tmp_path / repro.MANIFEST_NAME).read_text())
    old_text = (tmp_path / good).read_text().replace("sys.exit(3)", "sys.exit(1)")
    (tmp_path / good).unlink()
    (tmp_path / "old-name.py").write_text(old_text)
    manifest["files"] = {"old-name.py": {**manifest["files"][good], "sha256": repro._sha256(old_text.encode())}}
    (tmp_path / repro.MANIFEST_NAME).write_text(json.dumps(manifest))
    (tmp_path / "notes.txt").write_text("mine")
    assert [r.outcome for r in repro.vet(tmp_path, repro.read_manifest(tmp_path))[1]] == ["refused", "refused"]
    repro.rewrite_folder(tmp_path)
    runnable, refused = repro.vet(tmp_path, repro.read_manifest(tmp_path))
    assert [name for name, _, _ in runnable] == [good] and [r.script for r in refused] == ["notes.txt"]
    assert files_below(tmp_path) == {good, repro.MANIFEST_NAME, "notes.txt"}
