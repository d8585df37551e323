"""The campaign store: one SQLite file, written as each problem finishes (issue 9).

Tables:

* ``problems(campaign_seed, idx, digest, status, seconds, failure_dir, labels, completed_at)``:
  one row per finished problem, primary key (campaign_seed, idx) — a problem is never stored twice;
* ``claims(campaign_seed, idx, backend, claim, status, margin)``: the certificate of each backend;
* ``coverage(campaign_seed, idx, backend, key, value)``: whether the run exercised the claims;
* ``completions(campaign_seed, idx, at)``: an append-only log, one row per completion received,
  so a test can prove that no problem was run to completion twice across an interrupt + resume.

Every write is one transaction; a crash loses at most the problem being written.
"""

from __future__ import annotations

import json
import sqlite3
import time
from pathlib import Path
from typing import Any

SCHEMA = """
CREATE TABLE IF NOT EXISTS problems (
    campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, digest TEXT, status TEXT NOT NULL,
    seconds REAL, failure_dir TEXT, labels TEXT, message TEXT, completed_at REAL,
    PRIMARY KEY (campaign_seed, idx));
CREATE TABLE IF NOT EXISTS claims (
    campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, backend TEXT NOT NULL, claim TEXT NOT NULL,
    status TEXT NOT NULL, margin REAL, PRIMARY KEY (campaign_seed, idx, backend, claim));
CREATE TABLE IF NOT EXISTS coverage (
    campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, backend TEXT NOT NULL, key TEXT NOT NULL,
    value REAL, PRIMARY KEY (campaign_seed, idx, backend, key));
CREATE TABLE IF NOT EXISTS completions (campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, at REAL);
"""


class CampaignStore:
    """SQLite store of campaign results (see module docstring)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.db = sqlite3.connect(self.path, timeout=30)
        self.db.execute("PRAGMA journal_mode=WAL")
        self.db.executescript(SCHEMA)
        self.db.commit()

    def close(self) -> None:
        self.db.close()

    def done(self, campaign_seed: int) -> set[int]:
        """Indices already stored for this campaign seed (skipped on --resume)."""
        rows = self.db.execute("SELECT idx FROM problems WHERE campaign_seed = ?", (campaign_seed,))
        return {r[0] for r in rows}

    def add(self, result: dict[str, Any]) -> bool:
        """Store one problem's result in one transaction; False if it was already stored."""
        seed, idx = result["campaign_seed"], result["idx"]
        with self.db:
            self.db.execute("INSERT INTO completions VALUES (?, ?, ?)", (seed, idx, time.time()))
            cur = self.db.execute(
                "INSERT OR IGNORE INTO problems VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (seed, idx, result.get("digest"), result["status"], result.get("seconds"), result.get("failure_dir"),
                 json.dumps(result.get("labels", {})), result.get("message", ""), time.time()))
            if cur.rowcount == 0:
                return False
            for backend, claims in result.get("claims", {}).items():
                self.db.executemany("INSERT INTO claims VALUES (?, ?, ?, ?, ?, ?)",
                                    [(seed, idx, backend, name, c["status"], c.get("margin")) for name, c in claims.items()])
            for backend, cov in result.get("coverage", {}).items():
                self.db.executemany("INSERT INTO coverage VALUES (?, ?, ?, ?, ?)",
                                    [(seed, idx, backend, key, float(v)) for key, v in cov.items()])
        return True

    # -- summaries ------------------------------------------------------------------------------
    def claim_table(self) -> list[tuple[str, str, int, int, int]]:
        """(claim, backend, passed, failed, not_run) over every stored problem."""
        rows = self.db.execute(
            "SELECT claim, backend, SUM(status = 'pass'), SUM(status = 'fail'), SUM(status = 'not_run') "
            "FROM claims GROUP BY claim, backend ORDER BY claim, backend")
        return [tuple(r) for r in rows]

    def coverage_table(self) -> list[tuple[str, str, float, int]]:
        """(key, backend, fraction of problems with value > 0, count)."""
        rows = self.db.execute("SELECT key, backend, AVG(value > 0), COUNT(*) FROM coverage GROUP BY key, backend "
                               "ORDER BY key, backend")
        return [tuple(r) for r in rows]

    def problem_counts(self) -> dict[str, int]:
        return {r[0]: r[1] for r in self.db.execute("SELECT status, COUNT(*) FROM problems GROUP BY status")}

    def slowest(self, limit: int = 5) -> list[tuple[int, int, float]]:
        return [tuple(r) for r in self.db.execute(
            "SELECT campaign_seed, idx, seconds FROM problems ORDER BY seconds DESC LIMIT ?", (limit,))]

    def failures(self) -> list[tuple[int, int, str, str]]:
        return [tuple(r) for r in self.db.execute(
            "SELECT campaign_seed, idx, failure_dir, message FROM problems WHERE status != 'pass' ORDER BY idx")]

    def completion_counts(self) -> dict[tuple[int, int], int]:
        return {(r[0], r[1]): r[2] for r in self.db.execute(
            "SELECT campaign_seed, idx, COUNT(*) FROM completions GROUP BY campaign_seed, idx")}
