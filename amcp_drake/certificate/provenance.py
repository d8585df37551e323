"""What a certificate certifies and what produced it: the ``provenance`` section of certificate.json.

A referee who holds a certificate needs to tie it to the files it was computed from and to the software
that computed it. :func:`provenance` records

* ``files``: the SHA-256 of every input and output file the certificate is about (the trajectory file
  written beside it, the problem file and a given trajectory file), keyed by role;
* ``libraries``: the installed versions of the producing libraries (drake, clarabel, cvxpy) and of the
  checking ones (numpy, scipy; scipy's HiGHS checks the linear programs), read from the installed
  distributions' metadata without importing them (the certificate never imports a solver);
* ``command_line``: the arguments of the command that wrote the certificate (stored as data, never run);
* ``platform``, ``python``, ``amcp_drake`` (the project version) and ``git_commit`` when the package runs
  from a git checkout (``null`` otherwise).

:func:`file_sha256` is the one hash function; :func:`check_files` recomputes the hashes of a bundle so that
a changed byte is found (``amcp_drake.certificate.provenance.check_files(cert_dict, folder)``).
"""

from __future__ import annotations

import hashlib
import os
import platform
import subprocess
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any

from amcp_drake import __version__

#: distributions whose versions are recorded: the producers of a run, then the checkers of its certificate
PRODUCER_LIBRARIES = ("drake", "clarabel", "cvxpy")
CHECKER_LIBRARIES = ("numpy", "scipy")
_HASH_CHUNK = 1 << 20


def file_sha256(path: str | os.PathLike) -> str:
    """The SHA-256 of a file's bytes, as lowercase hex (read in chunks: any file size)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(_HASH_CHUNK), b""):
            digest.update(chunk)
    return digest.hexdigest()


def library_versions(names: Sequence[str]) -> dict[str, str | None]:
    """Installed version of each distribution (``None`` when it is not installed)."""
    versions: dict[str, str | None] = {}
    for name in names:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def git_commit() -> str | None:
    """The commit of the checkout the package runs from, or ``None`` (an installed package, no git)."""
    root = Path(__file__).resolve().parents[2]
    if not (root / ".git").exists():
        return None
    try:
        out = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True, text=True,
                             timeout=10, check=False, env={"PATH": os.environ.get("PATH", "/usr/bin:/bin")})
    except (OSError, subprocess.SubprocessError):
        return None
    commit = out.stdout.strip()
    return commit if out.returncode == 0 and len(commit) == 40 and all(c in "0123456789abcdef" for c in commit) else None


def provenance(files: Mapping[str, str | os.PathLike], command_line: Sequence[str] | None = None) -> dict[str, Any]:
    """The ``provenance`` section: hashes of ``files`` (role -> path), versions, command line, platform."""
    return {
        "files": {role: {"name": Path(path).name, "sha256": file_sha256(path)} for role, path in files.items()},
        "libraries": {"producer": library_versions(PRODUCER_LIBRARIES), "checker": library_versions(CHECKER_LIBRARIES)},
        "amcp_drake": __version__,
        "git_commit": git_commit(),
        "command_line": [str(a) for a in command_line] if command_line is not None else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
    }


def check_files(certificate: Mapping[str, Any], folder: str | os.PathLike) -> dict[str, bool]:
    """For each file of ``certificate["provenance"]["files"]`` that lies in ``folder`` (by its recorded name),
    whether its SHA-256 still matches; files not in the folder are left out."""
    result = {}
    for role, entry in certificate.get("provenance", {}).get("files", {}).items():
        path = Path(folder) / Path(str(entry["name"])).name
        if path.is_file():
            result[role] = file_sha256(path) == entry["sha256"]
    return result


__all__ = ["CHECKER_LIBRARIES", "PRODUCER_LIBRARIES", "check_files", "file_sha256", "git_commit", "library_versions",
           "provenance"]
