"""Output folders written all at once: every file of a command is first written into a hidden staging
folder inside the target folder, and moved into place (``os.replace``, atomic per file on one
filesystem) only when all of them are complete.

A failure before the commit (a full disk: ``OSError(ENOSPC)``, a read-only folder, an interrupt)
removes the staging folder and every folder created for it (the target included when it was created
here), so nothing half-written and no empty folder is left; the target's other files are left alone.
Once the commit has started it is completed (renames need no space).
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: Prefix of the staging folders (hidden, so no reader of the target folder takes one for output).
STAGING_PREFIX = ".amcp-staging-"


def _missing_ancestors(folder: Path) -> list[Path]:
    """``folder`` and its parents that do not exist yet, innermost first."""
    missing = []
    probe = folder
    while not (probe.exists() or probe.is_symlink()) and probe.parent != probe:
        missing.append(probe)
        probe = probe.parent
    return missing


def _remove_empty(folders: list[Path]) -> None:
    """Remove each folder of ``folders`` (innermost first) that is empty; keep any that is not."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


@contextmanager
def staged(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a fresh staging folder for the files of ``target``; on a normal exit move each file written
    into it (at any depth) to the same relative path under ``target``, on an exception remove it (see the
    module docstring) and re-raise."""
    target = Path(target)
    created = _missing_ancestors(target)
    staging = target / f"{STAGING_PREFIX}{uuid.uuid4().hex}"
    try:
        target.mkdir(parents=True, exist_ok=True)
        staging.mkdir()
        yield staging
        files = sorted(p.relative_to(staging) for p in staging.rglob("*") if p.is_file() and not p.is_symlink())
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        _remove_empty(created)
        raise
    _commit(staging, target, files)


def _commit(staging: Path, target: Path, files: list[Path]) -> None:
    """Move the staged ``files`` into ``target`` (their folders created), then remove the staging folder;
    an interrupt in between does not stop the remaining moves."""
    pending = list(files)
    try:
        while pending:
            (target / pending[0]).parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / pending[0], target / pending[0])
            pending.pop(0)
    finally:
        for rel in pending:  # reached only when a move failed or was interrupted: finish what can be finished
            try:
                (target / rel).parent.mkdir(parents=True, exist_ok=True)
                os.replace(staging / rel, target / rel)
            except OSError:
                pass
        shutil.rmtree(staging, ignore_errors=True)


__all__ = ["STAGING_PREFIX", "staged"]
