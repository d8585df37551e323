"""Before/after of a change in ONE interleaved run: CPU per part, Example 1, 8 facets, N = 10.

    python benchmarks/before_after.py --before <git revision> [--steps 300] [--config drake/vertex ...]

The package at ``--before`` (``git archive``: amcp_drake and reference/amcp_reference) is extracted
into a temporary directory with its packages renamed (``amcp_drake_before``, ``amcp_reference_before``),
so both versions live in this one process. Each configuration runs twice — the revision's code and the
working tree's — and all closed loops advance in lockstep (step k of each, then step k+1) with the
same disturbances, so "before" and "after" share the machine's noise. Medians of the thread CPU time
per part (amcp_drake.studies.bench_cpu, each version its own), the wall time of each full step
(``perf_counter``), and max |Δv|, |Δh_θ| between the two
versions of each configuration. Run it from the repository root with the working tree on PYTHONPATH.
"""

from __future__ import annotations

import argparse
import gc
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import disturbance_sequence
from amcp_drake.studies.bench_cpu import PARTS, CpuProfile

RENAME = re.compile(r"\b(amcp_drake|amcp_reference)\b")


def extract(revision: str, into: Path) -> None:
    """amcp_drake and amcp_reference of ``revision`` under ``into`` as *_before packages."""
    archive = into / "src.tar"
    with archive.open("wb") as out:
        subprocess.run(["git", "archive", revision, "amcp_drake", "reference/amcp_reference"], stdout=out, check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into / "src", filter="data")
    (into / "src" / "amcp_drake").rename(into / "amcp_drake_before")
    (into / "src" / "reference" / "amcp_reference").rename(into / "amcp_reference_before")
    for path in list((into / "amcp_drake_before").rglob("*.py")) + list((into / "amcp_reference_before").rglob("*.py")):
        path.write_text(RENAME.sub(lambda m: m.group(1) + "_before", path.read_text()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="git revision of the 'before' code")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--config", action="append",
                        help="backend/formulation[/option=value,...], e.g. drake/vertex or drake/vertex/qp_solver=daqp")
    args = parser.parse_args()
    configs = args.config or ["drake/vertex", "drake/vertex/qp_solver=daqp", "cvxpy/vertex", "drake/plain"]
    with tempfile.TemporaryDirectory() as tmp:
        extract(args.before, Path(tmp))
        sys.path.insert(0, tmp)
        from amcp_drake_before.online.controller import AdaptiveMPC as BeforeMPC
        from amcp_drake_before.studies.bench_cpu import CpuProfile as BeforeProfile

        spec = lorenzen2019_spec()
        d = design(spec.problem, replace(spec.design, x0_facets=8), backend="drake")
        problem, sc = spec.problem, spec.scenario
        w = disturbance_sequence(problem, "uniform", args.steps + 1, seed=0)
        runs = []
        for cfg in configs:
            backend, formulation, *rest = cfg.split("/")
            options = dict(kv.split("=") for kv in rest[0].split(",")) if rest else {}
            for tag, cls, profile in (("before", BeforeMPC, BeforeProfile), ("after", AdaptiveMPC, CpuProfile)):
                ctrl = cls(problem, d, backend=backend, formulation=formulation, **options)
                runs.append({"name": f"{cfg} {tag}", "profile": profile(ctrl), "x": np.asarray(sc.x0, float),
                             "cpu": {p: [] for p in PARTS}, "wall": [], "v": [], "h": []})
        gc.collect()
        gc.disable()
        for k in range(args.steps + 1):
            # the order alternates step by step: the run right after another one's solver call finds the
            # caches evicted (same code as before and after: 5-18 µs more for the second)
            for run in (runs if k % 2 == 0 else runs[::-1]):
                start = time.perf_counter()
                u, rec, parts = run["profile"].step(run["x"])
                elapsed = time.perf_counter() - start
                if u is None:
                    raise SystemExit(f"{run['name']}: step {k} {rec.status} {rec.detail}")
                if k >= 1:
                    for p in PARTS:
                        run["cpu"][p].append(parts[p])
                    run["wall"].append(elapsed)
                run["v"].append(rec.v)
                run["h"].append(rec.h_theta)
                run["x"] = problem.step(run["x"], u, sc.theta_star, w[k])
        gc.enable()
    load = os.getloadavg()
    print(f"Example 1, X0 8 facets, N = {problem.N}, {args.steps} steps, before = {args.before}: CPU ms medians; "
          f"load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1 / 5 / 15 min)")
    print(f"{'config':40s}" + "".join(f"{p:>16s}" for p in PARTS) + f"{'wall total':>12s}")
    for run in runs:
        print(f"{run['name']:40s}" + "".join(f"{1e3 * np.median(run['cpu'][p]):16.3f}" for p in PARTS)
              + f"{1e3 * np.median(run['wall']):12.3f}")
    print()
    for before, after in zip(runs[::2], runs[1::2]):
        dv = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) for a, b in zip(before["v"], after["v"]))
        dh = max(float(np.max(np.abs(np.asarray(a) - np.asarray(b)))) for a, b in zip(before["h"], after["h"]))
        ratio = np.median(after["cpu"]["total"]) / np.median(before["cpu"]["total"])
        wall = np.median(after["wall"]) / np.median(before["wall"])
        print(f"{after['name'][:-6]:34s} total after/before {ratio:.3f} CPU, {wall:.3f} wall; "
              f"max |Δv| {dv:.1e}, max |Δh_θ| {dh:.1e}")


if __name__ == "__main__":
    main()
