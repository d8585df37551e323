"""The certificate bundle: certificate.json, a self-contained report.html, trajectory.json.gz.

The page is rendered with jinja2 from ``templates/report.html`` and loads nothing from the network:
the plots (:mod:`amcp_drake.certificate.report_plots`, drawn by :mod:`amcp_drake.certificate.plots`) are
SVG data-URI ``<img>`` elements with fixed ids; the claims are shown grouped by the paper's results with the notation set as HTML
(:mod:`amcp_drake.certificate.report_groups`). The robust baseline beside the run
(``figures.robust_baseline``, :func:`amcp_drake.studies.baseline.robust_beside`) is shown in its own
section, apart from the verdict, when the certificate carries it.

:func:`write_outputs` writes the bundle atomically: all three files are first written into a
hidden staging directory inside ``out_dir``; only when every file is complete are they moved into
place with ``os.replace`` (atomic per file, same filesystem), and once that commit has started it
is completed even on Ctrl-C. A failure or interrupt before the commit removes the staging
directory and leaves ``out_dir`` as it was (a directory created for this call is removed again).
Other files in ``out_dir`` (e.g. ``compare.json`` of ``amcp compare``) are left alone.

A process killed while writing (SIGKILL: no handler runs) leaves its ``.certify-staging-<hex>``
behind. Each staging directory holds a lock file (``fcntl.flock``) for as long as its writer lives; the
kernel releases the lock when the process dies, so :func:`remove_stale_staging` (called by ``amcp
certify`` before it starts and by :func:`write_outputs`) removes exactly the staging directories whose
writer is gone, and never one that a concurrent ``amcp certify`` into the same folder is writing.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.certificate.certify import Certificate, claim_to_dict
from amcp_drake.certificate.provenance import provenance
from amcp_drake.certificate.report_groups import grouped, math_html, regressor_gram_lambda_min, theta_hat_outside_theta_k
from amcp_drake.certificate.report_plots import PLOTS, draw
from amcp_drake.model.problem_io import check_output_dir
from amcp_drake.online.simulate import Trajectory

CERTIFICATE_FILE = "certificate.json"
REPORT_FILE = "report.html"
TRAJECTORY_FILE = "trajectory.json.gz"
OUTPUT_FILES = (CERTIFICATE_FILE, REPORT_FILE, TRAJECTORY_FILE)


#: Name of the staging directories (``.certify-staging-`` + 32 hex digits) and of their lock file.
STAGING_PATTERN = re.compile(r"\.certify-staging-[0-9a-f]{32}")
STAGING_LOCK = ".lock"
#: A staging directory without a lock file is removed only when older than this (it may have been
#: created a moment ago by a writer that has not yet taken its lock).
STAGING_UNLOCKED_GRACE_S = 60.0


# -- output directory ------------------------------------------------------------------------------
def check_out_dir(out_dir: str | os.PathLike) -> Path:
    """Refuse an output path that is empty, exists but is not a directory, lies below a file or cannot
    be written (e.g. in /proc). Raises ProblemError (exit code 2)."""
    return check_output_dir("--out", out_dir)


def remove_stale_staging(out_dir: str | os.PathLike) -> list[Path]:
    """Remove the ``.certify-staging-<hex>`` directories in ``out_dir`` left by killed writers (their
    lock is free); return the removed paths."""
    out = Path(out_dir)
    removed: list[Path] = []
    if not out.is_dir():
        return removed
    for entry in out.iterdir():
        if STAGING_PATTERN.fullmatch(entry.name) and entry.is_dir() and not entry.is_symlink() \
                and not _staging_in_use(entry):
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
    return removed


def _staging_in_use(staging: Path) -> bool:
    """True when a live process holds the staging folder's lock (or, without a lock file, when the
    folder is younger than STAGING_UNLOCKED_GRACE_S: its writer may not have taken the lock yet)."""
    try:
        with open(staging / STAGING_LOCK, "rb") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            return False  # closing the file releases the lock taken here
    except FileNotFoundError:
        return time.time() - staging.stat().st_mtime < STAGING_UNLOCKED_GRACE_S
    except OSError:
        return True  # unreadable: leave it alone


def write_outputs(out_dir: str | os.PathLike, traj: Trajectory, cert: Certificate, *,
                  inputs: Mapping[str, str | os.PathLike] | None = None,
                  command_line: Sequence[str] | None = None, plane: tuple[int, int] | None = None) -> Path:
    """Write certificate.json, report.html and trajectory.json.gz into ``out_dir`` atomically.

    The certificate's ``provenance`` (:mod:`amcp_drake.certificate.provenance`) holds the SHA-256 of the
    trajectory file written here and of ``inputs`` (role -> path: the problem file, a given trajectory file),
    the library versions, ``command_line``, the platform and the project's version and commit. ``plane``: the
    two states (0-based) of the tube plot (default: :func:`amcp_drake.certificate.plots.tightest_plane`)."""
    out = check_out_dir(out_dir)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_staging(out)
    staging = out / f".certify-staging-{uuid.uuid4().hex}"
    lock = None
    try:  # a failure (a full disk) or an interrupt before the commit leaves nothing behind
        staging.mkdir()
        lock = open(staging / STAGING_LOCK, "wb")
        fcntl.flock(lock, fcntl.LOCK_EX)  # held while this process writes (the kernel drops it on a kill)
        traj.save(staging / TRAJECTORY_FILE)
        cert = replace(cert, provenance=provenance({"trajectory": staging / TRAJECTORY_FILE, **dict(inputs or {})},
                                                   command_line))
        (staging / CERTIFICATE_FILE).write_text(json.dumps(cert.to_dict(), indent=1, allow_nan=False))
        (staging / REPORT_FILE).write_text(render_report(traj, cert, plane), encoding="utf-8")
    except BaseException:
        if lock is not None:
            lock.close()
        shutil.rmtree(staging, ignore_errors=True)
        if created:
            shutil.rmtree(out, ignore_errors=True)
        raise
    with lock:
        _commit(staging, out)
    return out


def _commit(staging: Path, out: Path) -> None:
    """Move the staged files into ``out``; an interrupt in between does not stop the remaining moves."""
    pending = list(OUTPUT_FILES)
    try:
        while pending:
            os.replace(staging / pending[0], out / pending[0])
            pending.pop(0)
    finally:
        for name in pending:  # only reached on an interrupt mid-commit: finish it, then re-raise
            if (staging / name).exists():
                os.replace(staging / name, out / name)
        shutil.rmtree(staging, ignore_errors=True)


# -- HTML ------------------------------------------------------------------------------------------
#: Window of the regressor Gram in the note on θ̂_k convergence when the run does not enforce PE.
GRAM_WINDOW = 10


def render_report(traj: Trajectory, cert: Certificate, plane: tuple[int, int] | None = None) -> str:
    """The self-contained HTML report (template ``templates/report.html``); ``plane`` as in :func:`write_outputs`."""
    import jinja2

    env = jinja2.Environment(loader=jinja2.PackageLoader("amcp_drake.certificate", "templates"),
                             autoescape=jinja2.select_autoescape(["html"]), undefined=jinja2.StrictUndefined)
    plots = {pid: dict(id=pid, alt=alt, src=src, note=note) for pid, alt, (src, note) in
             ((pid, alt, draw(pid, traj, cert, plane)) for pid, alt in PLOTS)}
    claims = [claim_to_dict(c) for c in cert.claims]
    data = cert.to_dict()
    window = data["run"].get("pe_window") or GRAM_WINDOW
    gram_first, gram_last = regressor_gram_lambda_min(traj, window)
    return env.get_template("report.html").render(
        cert=data, sections=grouped(claims, cert.not_claimed), plots=plots, baseline=data["figures"].get("robust_baseline"),
        gram={"window": window, "first": gram_first, "last": gram_last}, outside=theta_hat_outside_theta_k(traj), fmt=_fmt, vec=_vec, math=math_html,
        ratio=_ratio, relative_tolerances=any(c.get("tolerance_relative") for c in claims))


def _fmt(value: Any, digits: int = 3) -> str:
    if value is None:
        return "n/a"
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return str(value)
    value = float(value)
    if value == 0:
        return "0"  # also −0.0
    if not np.isfinite(value):
        return str(value)
    return f"{value:.{digits}e}" if value != 0 and (abs(value) < 1e-3 or abs(value) >= 1e4) else f"{value:.{digits}g}"


def _vec(values) -> str:
    return "[" + ", ".join(_fmt(v, 4) for v in np.ravel(values)) + "]"


def _ratio(a: float | None, b: float | None) -> str:
    """a / b to 3 significant digits, or n/a."""
    if a is None or b is None or not np.isfinite(a) or not np.isfinite(b) or b == 0:
        return "n/a"
    return f"{a / b:.3g}"
