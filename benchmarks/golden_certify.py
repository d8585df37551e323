"""Golden comparison of ``amcp certify``: the certificate.json of Examples 1 and 2 on both backends,
written by two versions of the code, must be equal except timestamps and timings (docs/architecture.md, "Behaviour
unchanged"). Not a test (four closed-loop runs take minutes); docs/architecture.md says how it was used.

    # 1. the bundles of one version (the code on PYTHONPATH; a detached worktree for an old commit)
    git worktree add --detach /tmp/base <rev>
    PYTHONPATH=/tmp/base:/tmp/base/reference python benchmarks/golden_certify.py run /tmp/golden/base
    PYTHONPATH=$PWD:$PWD/reference           python benchmarks/golden_certify.py run /tmp/golden/head
    # 2. compare (exit 0: equal; 1: differences, listed)
    python benchmarks/golden_certify.py compare /tmp/golden/base /tmp/golden/head

The comparison is exact (floats compared with ==): a refactoring runs the same arithmetic, so any
difference in a margin, a series or a verdict is a change of behaviour to explain.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

#: The runs: Example 1 (``lorenzen2019``, the default) and Example 2 (``--example lorenzen2019_ex2``),
#: each on the Drake and the cvxpy backend.
RUNS = [(example, backend) for example in ("lorenzen2019", "lorenzen2019_ex2") for backend in ("drake", "cvxpy")]

#: Keys whose values differ from one run to the next by design: the creation time stamp and the
#: wall-clock solver/step times (``*_time_s``); in the ``provenance`` section, the output folder on the
#: command line, the git commit (none for an exported tree) and the trajectory file's hash (the file
#: records wall-clock times). Nothing else is left out.
VOLATILE_KEYS = {"created"}
VOLATILE_SUFFIX = "_time_s"
VOLATILE_PROVENANCE = {"command_line", "git_commit"}


def run_all(out: Path) -> int:
    """``amcp certify`` for every run of :data:`RUNS`, each into ``out/<example>-<backend>/``
    (its console output beside it as ``.log``); returns the worst exit code."""
    worst = 0
    for example, backend in RUNS:
        name = f"{example}-{backend}"
        cmd = [sys.executable, "-m", "amcp_drake", "certify", "--example", example, "--backend", backend,
               "--out", str(out / name)]
        print(" ".join(cmd[1:]), flush=True)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / f"{name}.log", "w") as log:
            code = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT)
        print(f"  exit {code}", flush=True)
        worst = max(worst, code)
    return worst


def _strip(obj, top: bool = True):
    if top and isinstance(obj, dict) and "provenance" in obj:
        prov = {k: v for k, v in obj["provenance"].items() if k not in VOLATILE_PROVENANCE}
        prov["files"] = {role: {k: v for k, v in entry.items() if not (role == "trajectory" and k == "sha256")}
                         for role, entry in prov.get("files", {}).items()}
        obj = {**obj, "provenance": prov}
    if isinstance(obj, dict):
        return {k: _strip(v, False) for k, v in obj.items() if k not in VOLATILE_KEYS and not k.endswith(VOLATILE_SUFFIX)}
    if isinstance(obj, list):
        return [_strip(v, False) for v in obj]
    return obj


def _leaves(obj) -> int:
    if isinstance(obj, dict):
        return sum(_leaves(v) for v in obj.values())
    if isinstance(obj, list):
        return sum(_leaves(v) for v in obj)
    return 1


def differences(a, b, path: str = "") -> list[str]:
    """Every place where ``a`` and ``b`` (JSON values) differ, as ``path: a vs b``."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'second' if k in b else 'first'}")
            else:
                out += differences(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        out = [f"{path}: length {len(a)} vs {len(b)}"] if len(a) != len(b) else []
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, f"{path}[{i}]")
        return out
    return [] if a == b and type(a) is type(b) else [f"{path}: {a!r} vs {b!r}"]


def compare_all(first: Path, second: Path) -> int:
    """Compare ``certificate.json`` of every run; prints one line per file; 1 if anything differs."""
    total = 0
    for example, backend in RUNS:
        name = f"{example}-{backend}"
        a, b = (json.loads((d / name / "certificate.json").read_text()) for d in (first, second))
        sa, sb = _strip(a), _strip(b)
        diff = differences(sa, sb)
        print(f"{name}: {_leaves(sa)} values compared ({_leaves(a) - _leaves(sa)} volatile left out), "
              f"verdict {a['verdict']} / {b['verdict']}, {len(diff)} differences")
        for line in diff[:20]:
            print(f"   {line}")
        total += len(diff)
    print(f"{len(RUNS)} certificates, {total} differences")
    return 1 if total else 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("run", help="write the four bundles into OUT").add_argument("out", type=Path)
    cmp = sub.add_parser("compare", help="compare two OUT directories")
    cmp.add_argument("first", type=Path)
    cmp.add_argument("second", type=Path)
    args = parser.parse_args(argv)
    return run_all(args.out) if args.command == "run" else compare_all(args.first, args.second)


if __name__ == "__main__":
    sys.exit(main())
