"""Campaigns on Dask: a LocalCluster run, kill + resume with nothing lost or run
twice and resume with other settings refused, stores that are damaged or foreign refused and never
written (--report says what it could read), and a scheduler and workers started as separate
processes on loopback."""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.studies.campaign_store import CampaignStore
from tests.guards import GUARD_SECONDS

pytest.importorskip("distributed")
pytest.importorskip("amcp_properties")

BIN = Path(sys.executable).parent
AMCP = [sys.executable, "-m", "amcp_drake", "campaign"]


def _stored(path: Path) -> set[int]:
    if not path.exists():
        return set()
    try:
        with sqlite3.connect(path, timeout=5) as db:
            return {r[0] for r in db.execute("SELECT idx FROM problems")}
    except sqlite3.OperationalError:
        return set()


@pytest.mark.slow
def test_local_cluster_campaign_stores_every_problem_and_answers_the_summary(tmp_path):
    from amcp_drake.cli.campaign import report_html, summary_text
    from amcp_drake.studies.campaign import run_campaign

    store_path = tmp_path / "c.sqlite"
    counts = run_campaign(store_path, systems=6, backends=("drake",), seed=3, workers=2, steps=6, progress=False)
    assert counts == {"submitted": 6, "stored": 6, "skipped": 0}
    store = CampaignStore(store_path)
    assert store.done(3) == set(range(6))
    table = {(c, b): (p, f, n) for c, b, p, f, n in store.claim_table()}
    assert table[("θ* ∈ Θ_k", "drake")][0] + table[("θ* ∈ Θ_k", "drake")][1] == 6
    text = summary_text(store)
    assert "problems stored: 6" in text and "coverage" in text
    for key in ("theta_k_lower_dim", "theta_star_vertex", "theta_star_facet"):  # hard-case coverage
        assert key in text, key
    for key in ("resolve_every_row", "resolve_clarabel_retry", "resolve_answer_check_fallback"):  # extra solves
        assert key in text, key
    assert "resolve_plain_fallback" not in text  # the campaign runs the plain form: no vertex-form fallback
    assert "<table id='claims'>" in report_html(store)
    # a second run without --resume is refused, with --resume nothing is re-run
    from amcp_drake.model.errors import ProblemError

    store.close()
    with pytest.raises(ProblemError, match="--resume"):
        run_campaign(store_path, systems=6, backends=("drake",), seed=3, steps=6, progress=False)
    again = run_campaign(store_path, systems=6, backends=("drake",), seed=3, steps=6, resume=True, progress=False)
    assert again == {"submitted": 0, "stored": 0, "skipped": 6}


def test_problem_draws_are_reproducible_per_index():
    from amcp_drake.studies.campaign import draw_case

    a, b, c = draw_case(5, 2, 6), draw_case(5, 2, 6), draw_case(5, 3, 6)
    assert a.key() == b.key()
    assert a.key() != c.key()


#: Resumes of the killed seed-7 campaign (12 systems, drake, 6 steps) with other settings: each is
#: refused (exit 2) naming every difference, and leaves the store as it was.
OTHER_SETTINGS = [
    (["--seed", "1"], ["--seed 1 (store: 7)"]),
    (["--steps", "5"], ["--steps 5 (store: 6)"]),
    (["--systems", "14"], ["--systems 14 (store: 12)"]),
    (["--backends", "drake,cvxpy"], ["--backends drake,cvxpy (store: drake)"]),
    (["--systems", "14", "--steps", "5", "--backends", "cvxpy"],
     ["--systems 14 (store: 12)", "--steps 5 (store: 6)", "--backends cvxpy (store: drake)"]),
]


def _with(args: list[str], changes: list[str]) -> list[str]:
    """``args`` with each option of ``changes`` (pairs) replaced."""
    args = list(args)
    for name, value in zip(changes[::2], changes[1::2]):
        args[args.index(name) + 1] = value
    return args


@pytest.mark.slow
def test_killed_campaign_resumes_with_no_problem_lost_or_run_twice(tmp_path):
    store_path = tmp_path / "k.sqlite"
    args = AMCP + ["--systems", "12", "--backends", "drake", "--seed", "7", "--steps", "6", "--store", str(store_path)]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + GUARD_SECONDS
    while len(_stored(store_path)) < 3 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # the client, the LocalCluster and its workers, mid-campaign
    proc.wait()
    before = _stored(store_path)
    assert 3 <= len(before) < 12, f"the kill should land midway; stored {len(before)}"
    for changes, named in OTHER_SETTINGS:
        refused = subprocess.run(_with(args, changes) + ["--resume"], check=False, capture_output=True, text=True, timeout=GUARD_SECONDS)
        assert refused.returncode == 2, (changes, refused.stdout[-1000:], refused.stderr[-2000:])
        assert "Traceback" not in refused.stderr
        for difference in named:
            assert difference in refused.stderr, (changes, refused.stderr)
        assert _stored(store_path) == before
    result = subprocess.run(args + ["--resume"], capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert result.returncode in (0, 1), result.stderr[-2000:]
    assert f"skipped (already stored) {len(before)}" in result.stdout
    store = CampaignStore(store_path)
    assert store.done(7) == set(range(12))
    assert set(store.completion_counts().values()) == {1}  # every problem completed exactly once
    store.close()


# -- stores made with other settings, damaged stores, foreign files -----------------------------------

BASE_ARGS = ["--systems", "40", "--backends", "drake", "--seed", "0", "--steps", "6"]


def _synthetic_store(path: Path, **changes) -> None:
    """A store of 40 results written through CampaignStore (the campaign's own writer), with the
    settings of BASE_ARGS (``changes`` replace some)."""
    from amcp_drake.studies.campaign import campaign_settings

    settings = {**campaign_settings(0, 40, ("drake",), 6), **changes}
    store = CampaignStore(path)
    store.require_settings(settings)
    for i in range(40):
        store.add({"campaign_seed": 0, "idx": i, "status": "fail" if i % 7 == 3 else "pass", "digest": f"{i:040d}",
                   "seconds": 0.1 * i, "labels": {"n": "2", "note": "x" * 60},
                   "claims": {"drake": {f"claim {j:02d}": {"status": "pass", "margin": 0.5 - j / 64} for j in range(30)}},
                   "coverage": {"drake": {"theta_shrank": 1.0, "constraints_active": 0.0}},
                   **({"replay": [f"amcp certify f/0-{i}/problem.json --backend drake"]} if i % 7 == 3 else {})})
    store.close()


def _invoke(args: list[str]):
    from amcp_drake.cli import main

    return CliRunner().invoke(main, ["campaign", *args])


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.parametrize(("store_changes", "args", "named"), [
    ({}, ["--seed", "1"], ["--seed 1 (store: 0)"]),
    ({}, ["--steps", "5"], ["--steps 5 (store: 6)"]),
    ({}, ["--systems", "14", "--backends", "drake,cvxpy"],
     ["--systems 14 (store: 40)", "--backends drake,cvxpy (store: drake)"]),
    ({"generator": "numpy-random_problems/0"}, [], ["generator version"]),
    ({"design_backend": "cvxpy"}, [], ["design backend drake (store: cvxpy)"]),
    ({"versions": {"cvxpy": "0.0.1"}}, [], ["versions.cvxpy"]),
], ids=["seed", "steps", "systems+backends", "generator", "design-backend", "library-version"])
@pytest.mark.parametrize("resume", [True, False], ids=["resume", "no-resume"])
def test_a_store_made_with_other_settings_is_refused_naming_each_difference(tmp_path, store_changes, args, named,
                                                                          resume):
    store_path = tmp_path / "c.sqlite"
    _synthetic_store(store_path, **store_changes)
    before = _snapshot(tmp_path)
    result = _invoke(_with(BASE_ARGS, args) + ["--store", str(store_path)] + (["--resume"] if resume else []))
    assert result.exit_code == 2, result.output
    assert f"{store_path} was made with" in result.stderr
    for difference in named:
        assert difference in result.stderr, result.stderr
    assert _snapshot(tmp_path) == before  # nothing written, no new file


def _truncate(path: Path) -> None:
    with open(path, "r+b") as handle:
        handle.truncate(path.stat().st_size // 2)


def _garble(path: Path) -> None:
    noise = np.random.default_rng(17).integers(0, 256, size=3 * 4096, dtype=np.uint8).tobytes()
    with open(path, "r+b") as handle:
        handle.seek(path.stat().st_size // 3)
        handle.write(noise)


def _not_sqlite(path: Path) -> None:
    path.write_text("problem,status\n0,pass\n")


def _other_schema(path: Path) -> None:
    path.unlink()
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE measurements (t REAL, value REAL)")
        db.execute("INSERT INTO measurements VALUES (0.0, 1.5)")
    db.close()


#: (damage, what the refusal says, whether --report can still read problems)
DAMAGED = [(_truncate, "truncated", True), (_garble, "corrupted", True),
           (_not_sqlite, "not an SQLite database", False), (_other_schema, "another schema", False)]


@pytest.mark.parametrize(("damage", "said", "readable"), DAMAGED, ids=["truncated", "garbage", "not-sqlite",
                                                                         "other-schema"])
def test_a_damaged_or_foreign_store_is_refused_never_written_and_reported_as_far_as_readable(tmp_path, damage, said,
                                                                                             readable):
    store_path = tmp_path / "c.sqlite"
    _synthetic_store(store_path)
    damage(store_path)
    before = _snapshot(tmp_path)
    for extra in (["--resume"], []):
        result = _invoke(BASE_ARGS + ["--store", str(store_path)] + extra)
        assert result.exit_code == 2, result.output
        assert "--store: expected an amcp campaign store" in result.stderr and str(store_path) in result.stderr
        assert said in result.stderr
        assert _snapshot(tmp_path) == before  # the file untouched, no -wal/-shm left next to it
    report = tmp_path / "out" / "report.html"
    result = _invoke(["--store", str(store_path), "--report", str(report)])
    assert result.exit_code == 2, result.output
    assert said in result.stderr
    if readable:
        assert "could be read" in result.stderr
        page = report.read_text()
        assert "The store is damaged" in page and "<table id='claims'>" in page
    else:
        assert "Nothing could be read" in result.stderr
        assert not report.exists()
    assert _snapshot(tmp_path) == before


def test_a_store_of_issue_9_without_settings_is_read_by_report_but_not_resumed(tmp_path):
    from amcp_drake.studies.campaign_store import LEGACY_TABLES

    store_path = tmp_path / "old.sqlite"
    with sqlite3.connect(store_path) as db:
        for table, columns in LEGACY_TABLES.items():
            db.execute(f"CREATE TABLE {table} ({', '.join(columns)})")
        db.execute("INSERT INTO problems (campaign_seed, idx, status, seconds) VALUES (0, 0, 'pass', 1.0)")
    db.close()
    before = _snapshot(tmp_path)
    result = _invoke(BASE_ARGS + ["--store", str(store_path), "--resume"])
    assert result.exit_code == 2, result.output
    assert "before settings were recorded" in result.stderr and str(store_path) in result.stderr
    assert _snapshot(tmp_path) == before
    result = _invoke(["--store", str(store_path), "--report", str(tmp_path / "out" / "r.html")])
    assert result.exit_code == 0, result.output
    assert "problems stored: 1 (pass: 1)" in (tmp_path / "out" / "r.html").read_text()


def test_report_on_a_healthy_store_and_a_directory_as_store(tmp_path):
    from amcp_drake.cli.campaign import summary_text

    store_path = tmp_path / "c.sqlite"
    _synthetic_store(store_path)
    report = tmp_path / "r.html"
    result = _invoke(["--store", str(store_path), "--report", str(report)])
    assert result.exit_code == 0, result.output
    page = report.read_text()
    assert "damaged" not in page and "problems stored: 40 (fail: 6, pass: 34)" in page
    assert "<code>amcp certify f/0-10/problem.json --backend drake</code>" in page
    store = CampaignStore(store_path)
    assert "  seed 0 #38: replay with\n    amcp certify f/0-38/problem.json --backend drake" in summary_text(store)
    store.close()
    folder = tmp_path / "a-folder"
    folder.mkdir()
    for extra in ([], ["--resume"], ["--report", str(tmp_path / "x.html")]):
        result = _invoke(BASE_ARGS + ["--store", str(folder)] + extra)
        assert result.exit_code == 2, result.output
        assert "--store" in result.stderr and "directory" in result.stderr
        assert list(folder.iterdir()) == []


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_campaign_through_a_separate_scheduler_and_worker_on_loopback(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = str(BIN / "dask")
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:
        deadline = time.monotonic() + GUARD_SECONDS     # the scheduler listens (however long it takes to start)
        while True:
            with socket.socket() as probe:
                if probe.connect_ex(("127.0.0.1", port)) == 0:
                    break
            assert procs[0].poll() is None and time.monotonic() < deadline, "the scheduler did not start"
            time.sleep(0.1)
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        store_path = tmp_path / "s.sqlite"
        result = subprocess.run(AMCP + ["--systems", "3", "--backends", "drake", "--steps", "6", "--scheduler", address,
                                        "--store", str(store_path)], capture_output=True, text=True, timeout=GUARD_SECONDS)
        assert result.returncode in (0, 1), result.stderr[-2000:]
        assert "problems stored: 3" in result.stdout
        assert _stored(store_path) == {0, 1, 2}
    finally:
        for p in procs:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
