"""The campaign store: one SQLite file, written as each problem finishes.

Tables (schema version :data:`SCHEMA_VERSION`, marked by ``PRAGMA application_id`` =
:data:`APPLICATION_ID` and ``PRAGMA user_version``):

* ``settings(key, value)``: what determines the results (campaign seed, number of systems,
  backends, steps, generator version, design backend, formulation, library versions), JSON values,
  written once when the store is created; a campaign with other settings is refused
  (:func:`settings_differences`), so one store never mixes two campaigns;
* ``problems(campaign_seed, idx, digest, status, seconds, failure_dir, labels, message,
  completed_at, replay)``: one row per finished problem, primary key (campaign_seed, idx) — a
  problem is never stored twice; ``replay`` is the JSON list of replay commands of a failure;
* ``claims(campaign_seed, idx, backend, claim, status, margin)``: the certificate of each backend;
* ``coverage(campaign_seed, idx, backend, key, value)``: whether the run exercised the claims;
* ``completions(campaign_seed, idx, at)``: an append-only log, one row per completion received,
  so a test can prove that no problem was run to completion twice across an interrupt + resume.

Every write is one transaction; a crash loses at most the problem being written, and a failed write (a
full disk) rolls back, leaving the store resumable. A campaign holds the store exclusively
(``exclusive=True``: an ``flock`` on the file for as long as it is open), so a second campaign on the
same store is refused at once instead of running the same problems again; ``--report`` only reads and
needs no lock. An existing file
is inspected read-only before it is opened for writing (:func:`inspect_store`): a file that is not
SQLite, is damaged (truncated, garbled: ``PRAGMA quick_check``) or holds another schema raises
:class:`~amcp_drake.model.errors.CampaignStoreError` naming the file, and is never written to.
:func:`salvage` reads what it can of a damaged store for ``amcp campaign --report``.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import struct
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from amcp_drake.model.errors import CampaignStoreError

#: ``PRAGMA application_id`` of a campaign store: "amcp" in ASCII (sqlite.org/fileformat.html, offset 68).
APPLICATION_ID = 0x616D6370
#: ``PRAGMA user_version``: 2 = with the settings table and replay commands; stores of
#: the first layout have no marks (version 1) and can be read by --report but not resumed.
SCHEMA_VERSION = 2
#: The first 16 bytes of every SQLite 3 database file.
SQLITE_HEADER = b"SQLite format 3\x00"
#: Seconds to wait for a lock held by another connection (a concurrent --report).
LOCK_TIMEOUT = 30
#: :func:`salvage` looks up rows one by one past a damaged page of a table; it stops after this many
#: consecutive row ids that cannot be read (a leaf page of a table holds at most a few hundred rows).
SALVAGE_MISSES = 1024

SCHEMA = """
CREATE TABLE IF NOT EXISTS settings (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS problems (
    campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, digest TEXT, status TEXT NOT NULL,
    seconds REAL, failure_dir TEXT, labels TEXT, message TEXT, completed_at REAL, replay TEXT,
    PRIMARY KEY (campaign_seed, idx));
CREATE TABLE IF NOT EXISTS claims (
    campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, backend TEXT NOT NULL, claim TEXT NOT NULL,
    status TEXT NOT NULL, margin REAL, PRIMARY KEY (campaign_seed, idx, backend, claim));
CREATE TABLE IF NOT EXISTS coverage (
    campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, backend TEXT NOT NULL, key TEXT NOT NULL,
    value REAL, PRIMARY KEY (campaign_seed, idx, backend, key));
CREATE TABLE IF NOT EXISTS completions (campaign_seed INTEGER NOT NULL, idx INTEGER NOT NULL, at REAL);
"""
#: The columns of each table (a file with other tables or columns is another schema).
TABLES = {
    "settings": ("key", "value"),
    "problems": ("campaign_seed", "idx", "digest", "status", "seconds", "failure_dir", "labels", "message",
                 "completed_at", "replay"),
    "claims": ("campaign_seed", "idx", "backend", "claim", "status", "margin"),
    "coverage": ("campaign_seed", "idx", "backend", "key", "value"),
    "completions": ("campaign_seed", "idx", "at"),
}
#: The tables of a store of the first layout (schema 1): no settings, no replay column.
LEGACY_TABLES = {name: tuple(c for c in cols if c != "replay") for name, cols in TABLES.items() if name != "settings"}
#: How a setting is named in messages (the CLI option that sets it).
SETTING_NAMES = {"seed": "--seed", "systems": "--systems", "backends": "--backends", "steps": "--steps",
                 "generator": "generator version", "design_backend": "design backend", "formulation": "formulation",
                 "versions": "library versions", "state_dims": "--state-dims"}


def _error(path: Path, what: str, fix: str = "") -> CampaignStoreError:
    return CampaignStoreError("--store", "an amcp campaign store (SQLite, written by `amcp campaign`)",
                              f"{path}: {what}", fix or "The file was left untouched; give a new --store path.")


def _connect_readonly(path: Path) -> sqlite3.Connection:
    return sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=LOCK_TIMEOUT)


def _head(path: Path, size: int = 100) -> bytes:
    with open(path, "rb") as handle:
        return handle.read(size)


def _truncation(path: Path) -> str | None:
    """"truncated (...)" when the file is shorter than the database size its header records (bytes
    16-17 page size, 28-31 page count, valid when bytes 24-27 equal 92-95; sqlite.org/fileformat.html)."""
    head = _head(path)
    if len(head) < 100:
        return f"truncated (a {len(head)}-byte file; an SQLite header alone has 100 bytes)"
    page_size = struct.unpack(">H", head[16:18])[0]
    page_size = 65536 if page_size == 1 else page_size
    pages = struct.unpack(">I", head[28:32])[0]
    size = path.stat().st_size
    wal = path.with_name(path.name + "-wal")
    if wal.exists() and wal.stat().st_size > 0:
        # pages past the end of the file may be in the write-ahead log (a checkpoint that a full disk
        # stopped after it rewrote page 1); SQLite reads them from there, and quick_check finds real damage
        return None
    if head[24:28] == head[92:96] and pages * page_size > size:
        return (f"truncated (its header records {pages} pages of {page_size} bytes = {pages * page_size} bytes; "
                f"the file has {size})")
    return None


def _first_lines(messages: list[str], keep: int = 3) -> str:
    """The first ``keep`` lines of quick_check's report (it can list every damaged cell)."""
    lines = [line for message in messages for line in message.splitlines() if line.strip()]
    more = f"; and {len(lines) - keep} more lines" if len(lines) > keep else ""
    return "; ".join(lines[:keep]) + more


def _remove_empty(paths: list[Path]) -> None:
    """Remove the sidecar files a read-only open created (only those that did not exist before and
    hold no data: an empty -wal, and the -shm index that goes with it)."""
    wal = [p for p in paths if p.name.endswith("-wal")]
    if any(p.exists() and p.stat().st_size > 0 for p in wal):
        return
    for p in paths:
        if p.exists():
            p.unlink()


def _table_columns(db: sqlite3.Connection) -> dict[str, tuple[str, ...]]:
    names = [r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
    return {name: tuple(r[1] for r in db.execute(f'PRAGMA table_info("{name}")')) for name in names}


@dataclass
class StoreState:
    """What :func:`inspect_store` found: ``kind`` is "new" (missing, empty file or empty database),
    "store" (schema 2) or "legacy" (a schema-1 store without settings)."""

    kind: str
    settings: dict[str, Any] | None = None


DAMAGED_FIX = "The file was left untouched; `amcp campaign --report` shows what can still be read."


def inspect_store(path: str | Path) -> StoreState:
    """Look at ``path`` read-only; CampaignStoreError when it is a directory, not SQLite, damaged, or
    an SQLite database of another schema. Never writes to the file (the -wal/-shm files a read-only
    open creates next to a file that is then refused are removed again)."""
    path = Path(path)
    if path.is_dir():
        raise CampaignStoreError("--store", "a file path for the SQLite store", f"{path}: a directory")
    if not path.exists() or path.stat().st_size == 0:
        return StoreState("new")  # an empty file holds nothing to lose (SQLite creates one before writing)
    try:
        head = _head(path, len(SQLITE_HEADER))
    except OSError as exc:
        raise _error(path, f"unreadable ({exc.strerror})") from None
    if head != SQLITE_HEADER:
        raise _error(path, f"not an SQLite database (the file starts with {head!r})")
    truncated = _truncation(path)
    if truncated:
        raise _error(path, truncated, DAMAGED_FIX)
    fresh = [p for p in (path.with_name(path.name + "-wal"), path.with_name(path.name + "-shm")) if not p.exists()]
    try:
        return _classify(path)
    except CampaignStoreError:
        _remove_empty(fresh)
        raise


def _classify(path: Path) -> StoreState:
    """quick_check, then the marks and tables of the file (see :func:`inspect_store`)."""
    try:
        db = _connect_readonly(path)
        try:
            problems = [r[0] for r in db.execute("PRAGMA quick_check")]
            if problems != ["ok"]:
                raise _error(path, f"corrupted (PRAGMA quick_check: {_first_lines(problems)})", DAMAGED_FIX)
            app_id = db.execute("PRAGMA application_id").fetchone()[0]
            version = db.execute("PRAGMA user_version").fetchone()[0]
            columns = _table_columns(db)
            settings = ({k: json.loads(v) for k, v in db.execute("SELECT key, value FROM settings")}
                        if "settings" in columns else None)
        finally:
            db.close()
    except sqlite3.DatabaseError as exc:
        raise _error(path, f"corrupted ({exc})", DAMAGED_FIX) from None
    except json.JSONDecodeError as exc:
        raise _error(path, f"corrupted (a settings value is not JSON: {exc.msg})", DAMAGED_FIX) from None
    if not columns and app_id == 0:
        return StoreState("new")
    if app_id == APPLICATION_ID and version == SCHEMA_VERSION and columns == TABLES:
        return StoreState("store", settings)
    if app_id == 0 and columns == LEGACY_TABLES:
        return StoreState("legacy")
    if app_id == APPLICATION_ID and version != SCHEMA_VERSION:
        raise _error(path, f"a campaign store of schema version {version} (this amcp reads {SCHEMA_VERSION})")
    found = ", ".join(f"{name}({', '.join(cols)})" for name, cols in sorted(columns.items()))
    raise _error(path, f"an SQLite database of another schema (tables: {found or 'none'})")


def settings_differences(recorded: dict[str, Any], requested: dict[str, Any]) -> list[str]:
    """Each setting that differs, as "--steps 5 (store: 15)"; library versions one by one."""
    requested = json.loads(json.dumps(requested))  # the form they take in the store (lists, not tuples)
    out = []
    for key in sorted(set(recorded) | set(requested), key=lambda k: (k not in SETTING_NAMES, k)):
        old, new = recorded.get(key), requested.get(key)
        if old == new:
            continue
        if isinstance(old, dict) and isinstance(new, dict):
            out += [f"{key}.{name} {new.get(name)} (store: {old.get(name)})"
                    for name in sorted(set(old) | set(new)) if old.get(name) != new.get(name)]
            continue
        show = (lambda v: ",".join(map(str, v)) if isinstance(v, list) else str(v))
        out.append(f"{SETTING_NAMES.get(key, key)} {show(new)} (store: {show(old)})")
    return out


class CampaignStore:
    """SQLite store of campaign results (see module docstring). Opening an existing file inspects it
    first (CampaignStoreError on a damaged or foreign file, which is then never written to)."""

    def __init__(self, path: str | Path, *, allow_legacy: bool = False, exclusive: bool = False) -> None:
        self.path = Path(path)
        self.created = False
        self._lock_fd: int | None = None
        self.db = None
        try:
            if exclusive:
                self._lock()
            state = inspect_store(self.path)
            if state.kind == "legacy" and not allow_legacy:
                raise _error(self.path, "a campaign store written before settings were recorded (schema 1): the "
                             "settings of its problems are unknown, so it cannot be resumed",
                             "Start a new --store; `amcp campaign --report` still reads this one.")
            self.kind = state.kind
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.db = sqlite3.connect(self.path, timeout=LOCK_TIMEOUT)
            if state.kind == "new":
                self.db.execute("PRAGMA journal_mode=WAL")
                self.db.executescript(SCHEMA)
                self.db.execute(f"PRAGMA application_id = {APPLICATION_ID}")
                self.db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
                self.db.commit()
                self.kind = "store"
        except BaseException:
            self.close(discard_new=True)
            raise

    def _lock(self) -> None:
        """Hold an exclusive ``flock`` on the store file for as long as this object is open (the kernel
        releases it when the process dies): a second writer is refused at once with
        CampaignStoreError, so two campaigns never run the same problems into one store. SQLite's own
        locks are POSIX record locks, independent of ``flock`` on Linux. Creates the file (empty, which
        :func:`inspect_store` reads as a new store) when it does not exist; ``created`` says so."""
        import fcntl
        import os

        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o666)
            self.created = True
        except FileExistsError:
            fd = os.open(self.path, os.O_RDWR)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            self.created = False  # the file is the other writer's now
            raise CampaignStoreError(
                "--store", "a store no other process is writing",
                f"{self.path}: in use by another amcp campaign (it holds the store's lock)",
                "Wait for it to end (or stop it), then continue with --resume; two campaigns never share a "
                "store.") from None
        self._lock_fd = fd

    def close(self, discard_new: bool = False) -> None:
        """Close the store (and release its lock). ``discard_new``: when this object created the file and
        no problem was stored, remove it and its -wal/-shm files (a refused or failed start writes nothing)."""
        import os

        if self.db is not None:
            empty = True
            if discard_new and self.created:
                try:
                    empty = not self.done_any()
                except sqlite3.Error:
                    empty = True
            self.db.close()
            self.db = None
        else:
            empty = True
        if discard_new and self.created and empty:
            for name in (self.path.name, self.path.name + "-wal", self.path.name + "-shm", self.path.name + "-journal"):
                try:
                    os.unlink(self.path.with_name(name))
                except FileNotFoundError:
                    pass
            self.created = False
        if self._lock_fd is not None:  # after the connection: closing it drops no SQLite lock of ours
            os.close(self._lock_fd)
            self._lock_fd = None

    @classmethod
    def in_memory(cls) -> CampaignStore:
        """An empty store in memory (what :func:`salvage` fills with the readable rows)."""
        store = cls.__new__(cls)
        store.path = Path(":memory:")
        store.kind = "store"
        store.created, store._lock_fd = False, None
        store.db = sqlite3.connect(":memory:")
        store.db.executescript(SCHEMA)
        return store

    # -- settings -------------------------------------------------------------------------------
    def settings(self) -> dict[str, Any] | None:
        """The recorded settings (None: none recorded yet)."""
        if self.kind == "legacy":
            return None
        rows = self.db.execute("SELECT key, value FROM settings").fetchall()
        return {k: json.loads(v) for k, v in rows} or None

    def record_settings(self, settings: dict[str, Any]) -> None:
        """Write the campaign's settings (once, in one transaction)."""
        with self.db:
            self.db.executemany("INSERT INTO settings VALUES (?, ?)",
                                [(k, json.dumps(v, sort_keys=True)) for k, v in settings.items()])

    def require_settings(self, settings: dict[str, Any]) -> None:
        """Record ``settings`` in a store that has none; CampaignStoreError naming each difference when
        the store was made with other settings."""
        recorded = self.settings()
        if recorded is None:
            if self.done_any():
                raise _error(self.path, "problems but no recorded settings")
            self.record_settings(settings)
            return
        diffs = settings_differences(recorded, settings)
        if diffs:
            raise CampaignStoreError(
                "--store", f"the settings {self.path} was made with",
                "other settings: " + "; ".join(diffs),
                "Repeat the command with the store's settings, or give a new --store for a new campaign.")

    # -- results --------------------------------------------------------------------------------
    def done_any(self) -> bool:
        return self.db.execute("SELECT 1 FROM problems LIMIT 1").fetchone() is not None

    def done(self, campaign_seed: int) -> set[int]:
        """Indices already stored for this campaign seed (skipped on --resume)."""
        rows = self.db.execute("SELECT idx FROM problems WHERE campaign_seed = ?", (campaign_seed,))
        return {r[0] for r in rows}

    def add(self, result: dict[str, Any]) -> bool:
        """Store one problem's result in one transaction; False if it was already stored."""
        seed, idx = result["campaign_seed"], result["idx"]
        replay = json.dumps(result["replay"]) if result.get("replay") else None
        with self.db:
            self.db.execute("INSERT INTO completions VALUES (?, ?, ?)", (seed, idx, time.time()))
            cur = self.db.execute(
                "INSERT OR IGNORE INTO problems VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (seed, idx, result.get("digest"), result["status"], result.get("seconds"), result.get("failure_dir"),
                 json.dumps(result.get("labels", {})), result.get("message", ""), time.time(), replay))
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
        """(key, backend, fraction of problems with value > 0, count); the solver-answer counts
        (keys ``answers_...``) are :meth:`answer_table`'s."""
        rows = self.db.execute("SELECT key, backend, AVG(value > 0), COUNT(*) FROM coverage WHERE key NOT LIKE 'answers\\_%' "
                               "ESCAPE '\\' GROUP BY key, backend ORDER BY key, backend")
        return [tuple(r) for r in rows]

    def answer_table(self) -> list[tuple[str, str, float, int, int]]:
        """(key, backend, total count over the problems, problems with a count > 0, problems) of the
        solver-answer counts ``answers_<problem>_<count>`` (studies.campaign._answer_counts)."""
        rows = self.db.execute("SELECT key, backend, SUM(value), SUM(value > 0), COUNT(*) FROM coverage "
                               "WHERE key LIKE 'answers\\_%' ESCAPE '\\' GROUP BY key, backend ORDER BY backend, key")
        return [tuple(r) for r in rows]

    def problem_counts(self) -> dict[str, int]:
        return {r[0]: r[1] for r in self.db.execute("SELECT status, COUNT(*) FROM problems GROUP BY status")}

    def labels(self) -> list[tuple[int, int, dict[str, str]]]:
        """(seed, idx, the generator's labels) of every stored problem."""
        return [(s, i, json.loads(lab) if lab else {}) for s, i, lab in self.db.execute(
            "SELECT campaign_seed, idx, labels FROM problems ORDER BY campaign_seed, idx")]

    def slowest(self, limit: int = 5) -> list[tuple[int, int, float]]:
        return [tuple(r) for r in self.db.execute(
            "SELECT campaign_seed, idx, seconds FROM problems ORDER BY seconds DESC LIMIT ?", (limit,))]

    def failures(self) -> list[tuple[int, int, str, str, list[str]]]:
        """(seed, idx, failure folder, message, replay commands) of every problem that did not pass."""
        replay = "replay" if self.kind != "legacy" else "NULL"
        return [(s, i, d, m, json.loads(r) if r else []) for s, i, d, m, r in self.db.execute(
            f"SELECT campaign_seed, idx, failure_dir, message, {replay} FROM problems WHERE status != 'pass' "
            "ORDER BY campaign_seed, idx")]

    def completion_counts(self) -> dict[tuple[int, int], int]:
        return {(r[0], r[1]): r[2] for r in self.db.execute(
            "SELECT campaign_seed, idx, COUNT(*) FROM completions GROUP BY campaign_seed, idx")}


@dataclass
class Salvage:
    """What :func:`salvage` could read of a store: an in-memory copy of the readable rows, and one
    line per table (or check) that could not be read in full."""

    store: CampaignStore | None
    rows: dict[str, int] = field(default_factory=dict)
    damage: list[str] = field(default_factory=list)


def salvage(path: str | Path) -> Salvage:
    """Read every row that can still be read from the store at ``path`` into an in-memory store:
    from a temporary copy (the file itself is never opened), with the header's page count set to the
    pages present when the file was truncated, table by table, past damaged pages by row id.
    ``store`` is None when nothing at all could be read."""
    path = Path(path)
    if path.is_dir():
        raise CampaignStoreError("--store", "a file path for the SQLite store", f"{path}: a directory")
    if not path.exists():
        raise CampaignStoreError("--store", "an existing campaign store to report on", f"{path}: no such file")
    head = _head(path, len(SQLITE_HEADER))
    if head != SQLITE_HEADER:
        return Salvage(None, damage=[f"not an SQLite database (the file starts with {head!r})"])
    with tempfile.TemporaryDirectory(prefix="amcp-salvage-") as tmp:
        copy = Path(tmp) / "store.sqlite"
        shutil.copyfile(path, copy)
        wal = path.with_name(path.name + "-wal")
        if wal.exists():
            shutil.copyfile(wal, copy.with_name(copy.name + "-wal"))
        damage = []
        truncated = _truncation(copy)
        if truncated:
            damage.append(truncated)
            if copy.stat().st_size >= 100:
                page_size = struct.unpack(">H", _head(copy)[16:18])[0] or 1
                page_size = 65536 if page_size == 1 else page_size
                with open(copy, "r+b") as handle:
                    handle.seek(28)
                    handle.write(struct.pack(">I", copy.stat().st_size // page_size))
        try:
            db = sqlite3.connect(copy)
        except sqlite3.DatabaseError as exc:
            return Salvage(None, damage=damage + [f"cannot be opened: {exc}"])
        try:
            return _salvage_rows(db, damage)
        finally:
            db.close()


def _salvage_rows(db: sqlite3.Connection, damage: list[str]) -> Salvage:
    try:
        checks = [r[0] for r in db.execute("PRAGMA quick_check")]
        if checks != ["ok"]:
            damage.append(f"PRAGMA quick_check: {_first_lines(checks)}")
    except sqlite3.DatabaseError as exc:
        damage.append(f"PRAGMA quick_check: {exc}")
    try:
        columns = _table_columns(db)
    except sqlite3.DatabaseError as exc:
        return Salvage(None, damage=damage + [f"the list of tables (sqlite_master) cannot be read: {exc}"])
    out = Salvage(CampaignStore.in_memory(), damage=damage)
    for table, wanted in TABLES.items():
        have = [c for c in wanted if c in columns.get(table, ())]
        if not have:
            out.damage.append(f"table {table}: missing")
            continue
        rows, error = _read_table(db, table, have)
        out.store.db.executemany(f"INSERT OR IGNORE INTO {table} ({', '.join(have)}) "
                                 f"VALUES ({', '.join('?' * len(have))})", rows)
        out.rows[table] = len(rows)
        if error:
            out.damage.append(f"table {table}: {len(rows)} rows read; the rest is unreadable ({error})")
    out.store.db.commit()
    if not any(out.rows.values()) and out.damage:
        out.store.close()
        return Salvage(None, out.rows, out.damage)
    return out


def _read_table(db: sqlite3.Connection, table: str, cols: list[str]) -> tuple[list[tuple], str | None]:
    """The readable rows of ``table``: a scan, then, past the first damaged page, lookups by row id
    until :data:`SALVAGE_MISSES` consecutive ids cannot be read. Returns (rows, first error or None)."""
    found: dict[int, tuple] = {}
    select = f"SELECT rowid, {', '.join(cols)} FROM {table}"
    try:
        for row in db.execute(select):
            found[row[0]] = row[1:]
        return list(found.values()), None
    except sqlite3.DatabaseError as exc:
        error = str(exc)
    rowid, misses = 1, 0
    while misses < SALVAGE_MISSES:
        if rowid in found:
            misses = 0
        else:
            try:
                row = db.execute(select + " WHERE rowid = ?", (rowid,)).fetchone()
            except sqlite3.DatabaseError:
                row = None
            if row is None:
                misses += 1
            else:
                found[rowid], misses = row[1:], 0
        rowid += 1
    return [found[k] for k in sorted(found)], error


__all__ = [
    "APPLICATION_ID",
    "SCHEMA_VERSION",
    "CampaignStore",
    "Salvage",
    "StoreState",
    "inspect_store",
    "salvage",
    "settings_differences",
]
