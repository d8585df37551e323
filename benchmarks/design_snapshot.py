"""Snapshot the designs of every file in examples/ and compare two snapshots field by field, exactly.

    PYTHONPATH=.:reference:properties python benchmarks/design_snapshot.py dump OUT.pkl drake,cvxpy
    PYTHONPATH=.:reference:properties python benchmarks/design_snapshot.py compare BEFORE.pkl AFTER.pkl

``dump`` designs each example at its file's settings (``design()``) on each backend and pickles
``OfflineDesign.to_dict()`` (or the error). ``compare`` prints, per (example, backend), "identical"
when every array is bit for bit equal (``np.array_equal``) and every other field equal, the attempts'
labels, outcomes and reasons included (their seconds excluded), else the fields that differ.
Used for the design in units normalised by W (offline/units.py): every example identical before/after on
Drake and cvxpy.
"""

from __future__ import annotations

import glob
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from amcp_drake.model.problem_io import load_spec
from amcp_drake.offline.design import design


def dump(out: str, backends: list[str]) -> None:
    result = {}
    for path in sorted(glob.glob("examples/*.json")):
        spec = load_spec(path)
        for backend in backends:
            start = time.process_time()
            try:
                result[(Path(path).stem, backend)] = design(spec.problem, spec.design, backend=backend).to_dict()
            except Exception as exc:  # noqa: BLE001 - a failing design is a recorded outcome
                result[(Path(path).stem, backend)] = repr(exc)
            print(Path(path).stem, backend, f"{time.process_time() - start:.1f} s CPU", flush=True)
    with open(out, "wb") as fh:
        pickle.dump(result, fh)


def _attempts(info: dict) -> list:
    return [(a["label"], a["outcome"], a["reason"]) for a in info.get("attempts", [])]


def _same(key: str, a, b) -> bool:
    if key == "info":
        strip = lambda d: {k: v for k, v in d.items() if k != "attempts"}  # noqa: E731
        return strip(a) == strip(b) and _attempts(a) == _attempts(b)
    if isinstance(a, list):
        return np.array_equal(np.asarray(a), np.asarray(b))
    return a == b


def compare(before: str, after: str) -> int:
    with open(before, "rb") as fh:
        old = pickle.load(fh)
    with open(after, "rb") as fh:
        new = pickle.load(fh)
    changed = 0
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if not isinstance(a, dict) or not isinstance(b, dict):
            verdict = "identical (error)" if a == b else f"DIFFER: {a!r} / {b!r}"
        else:
            diff = [f for f in a if not _same(f, a[f], b.get(f))]
            verdict = "identical" if not diff else f"DIFFER: {diff}"
        changed += not verdict.startswith("identical")
        print(*key, verdict)
    return changed


if __name__ == "__main__":
    if sys.argv[1] == "dump":
        dump(sys.argv[2], sys.argv[3].split(",") if len(sys.argv) > 3 else ["drake"])
    else:
        sys.exit(1 if compare(sys.argv[2], sys.argv[3]) else 0)
