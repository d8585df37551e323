"""CPU time per part of a full step: Example 1, X0 with 8 facets, N = 10, in lockstep.

    python benchmarks/step_profile.py [--steps 300] [--config drake/vertex ...]

Every configuration runs its own closed loop (same disturbances, seed 0), interleaved step by step
(step k of each, then step k+1), so they share the machine's noise. Medians over steps 1..steps of
the thread CPU time of each part (amcp_drake.studies.bench_cpu) and of the wall time of the whole step.
"""

from __future__ import annotations

import argparse
import gc
import time
from dataclasses import replace

import numpy as np

from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import disturbance_sequence
from amcp_drake.studies.bench_cpu import PARTS, CpuProfile


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--facets", type=int, default=8)
    parser.add_argument("--config", action="append",
                        help="backend/formulation[/option=value,...], e.g. drake/vertex or drake/vertex/qp_solver=daqp")
    args = parser.parse_args()
    configs = args.config or ["drake/vertex", "cvxpy/vertex", "drake/plain"]
    spec = lorenzen2019_spec()
    d = design(spec.problem, replace(spec.design, x0_facets=args.facets), backend="drake")
    problem, sc = spec.problem, spec.scenario
    w = disturbance_sequence(problem, "uniform", args.steps + 1, seed=0)
    profiles, states, cpu, wall = [], [], [], []
    for cfg in configs:
        backend, formulation, *rest = cfg.split("/")
        options = dict(kv.split("=") for kv in rest[0].split(",")) if rest else {}
        ctrl = AdaptiveMPC(problem, d, backend=backend, formulation=formulation, **options)
        profiles.append(CpuProfile(ctrl))
        states.append(np.asarray(sc.x0, float))
        cpu.append({p: [] for p in PARTS})
        wall.append([])
    gc.collect()
    gc.disable()
    for k in range(args.steps + 1):
        # the order alternates step by step (the configuration after another one's solver call finds
        # the caches evicted)
        for c in (range(len(profiles)) if k % 2 == 0 else reversed(range(len(profiles)))):
            prof = profiles[c]
            start = time.perf_counter()
            u, rec, parts = prof.step(states[c])
            elapsed = time.perf_counter() - start
            if u is None:
                raise SystemExit(f"{configs[c]}: step {k} {rec.status}")
            if k >= 1:
                for p in PARTS:
                    cpu[c][p].append(parts[p])
                wall[c].append(elapsed)
            states[c] = problem.step(states[c], u, sc.theta_star, w[k])
    gc.enable()
    print(f"Example 1, X0 {args.facets} facets, N = {problem.N}, {args.steps} steps: CPU ms medians (wall total)")
    print(f"{'config':34s}" + "".join(f"{p:>17s}" for p in PARTS) + f"{'wall total':>12s}")
    for cfg, times, walls in zip(configs, cpu, wall):
        print(f"{cfg:34s}" + "".join(f"{1e3 * np.median(times[p]):17.3f}" for p in PARTS)
              + f"{1e3 * np.median(walls):12.3f}")


if __name__ == "__main__":
    main()
