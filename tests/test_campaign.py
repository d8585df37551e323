"""Campaigns on Dask (issue 9): a LocalCluster run, kill + resume with nothing lost or run twice,
and a scheduler and workers started as separate processes on loopback."""

from __future__ import annotations

import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from amcp_drake.studies.campaign_store import CampaignStore

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
    assert "<table id='claims'>" in report_html(store)
    # a second run without --resume is refused, with --resume nothing is re-run
    from amcp_drake.model.errors import ProblemError

    store.close()
    with pytest.raises(ProblemError, match="--resume"):
        run_campaign(store_path, systems=6, backends=("drake",), seed=3, progress=False)
    again = run_campaign(store_path, systems=6, backends=("drake",), seed=3, resume=True, progress=False)
    assert again == {"submitted": 0, "stored": 0, "skipped": 6}


def test_problem_draws_are_reproducible_per_index():
    from amcp_drake.studies.campaign import draw_case

    a, b, c = draw_case(5, 2, 6), draw_case(5, 2, 6), draw_case(5, 3, 6)
    assert a.key() == b.key()
    assert a.key() != c.key()


def test_killed_campaign_resumes_with_no_problem_lost_or_run_twice(tmp_path):
    store_path = tmp_path / "k.sqlite"
    args = AMCP + ["--systems", "12", "--backends", "drake", "--seed", "7", "--steps", "6", "--store", str(store_path)]
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 240
    while len(_stored(store_path)) < 3 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)  # the client, the LocalCluster and its workers, mid-campaign
    proc.wait()
    before = _stored(store_path)
    assert 3 <= len(before) < 12, f"the kill should land midway; stored {len(before)}"
    result = subprocess.run(args + ["--resume"], capture_output=True, text=True, timeout=400)
    assert result.returncode in (0, 1), result.stderr[-2000:]
    assert f"skipped (already stored) {len(before)}" in result.stdout
    store = CampaignStore(store_path)
    assert store.done(7) == set(range(12))
    assert set(store.completion_counts().values()) == {1}  # every problem completed exactly once
    store.close()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_campaign_through_a_separate_scheduler_and_worker_on_loopback(tmp_path):
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    dask = str(BIN / "dask")
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:
        time.sleep(3)
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1", "--nthreads", "1", "--no-dashboard"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
        store_path = tmp_path / "s.sqlite"
        result = subprocess.run(AMCP + ["--systems", "3", "--backends", "drake", "--steps", "6", "--scheduler", address,
                                        "--store", str(store_path)], capture_output=True, text=True, timeout=300)
        assert result.returncode in (0, 1), result.stderr[-2000:]
        assert "problems stored: 3" in result.stdout
        assert _stored(store_path) == {0, 1, 2}
    finally:
        for p in procs:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
