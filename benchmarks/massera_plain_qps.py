"""The cvxpy plain form's tube QPs (20) on massera2017 with θ* = −1 and vertex disturbances.

Rebuilds the measurement of docs/decisions.md, "The cvxpy plain form on thin Θ_k": the plain form writes
(15c) as c κ_l + Λ s_l: 40-step closed loops (cvxpy backend, plain form, x_0 of the example's scenario) on
seeds 0-3 give 4 × 41 states (x_k, θ̂_k, Θ_k); at each state the QP is solved with six Θ_k:
Θ = [−1, 1], [−1, −1 + w] for w = 1e-2, 1e-4, 1e-6, 0, and the recorded Θ_k (984 QPs). Each QP is
one fresh Clarabel solve (a new solver, no warm start) with the backend's retry ladder
(clarabel_retry: first try without refinement, then the defaults, then the rungs). Counted per
formulation: QPs left without an answer, and first tries that needed a retry.

    python benchmarks/massera_plain_qps.py --out DIR [--steps 40] [--seeds 0 1 2 3] [--drake]
        [--clarabel '{"direct_solve_method": "qdldl"}']
    python benchmarks/massera_plain_qps.py --loops [--example massera2017|lorenzen2019] [--steps 40]

``--clarabel``: Clarabel options of the cvxpy plain form (the user's options, over the backend's
``tube_mpc.PLAIN_FORM_CLARABEL_OPTIONS``): ``direct_solve_method: qdldl`` gives the QP with
Clarabel's default factorisation. ``--loops``: 40-step closed loops of the cvxpy plain form (the controller as a user runs
it, solver kept between steps) with QDLDL and with faer in lockstep (step k of each, the order
alternating), per seed: steps whose notes show a retry or a fallback (studies.resolves), and the
medians of CPU (thread time) and wall time per step; any other built-in example with its own scenario
(θ*, disturbance kind), e.g. ``--example lorenzen2019`` (Example 1).

The trajectories are saved in DIR (``seed<k>.json.gz``) and reused on the next run (``--rerun``
runs the closed loops again), so a change to the tube QP is measured on the same states. Writes
``DIR/qps.json`` (one entry per QP) and prints the counts and the QPs without an answer.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np

from amcp_drake.model.examples import get_example
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answer_checks
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate

THETA_STAR = np.array([-1.0])
WIDTHS = ("Theta", 1e-2, 1e-4, 1e-6, 0.0, "recorded")
#: The notes clarabel_retry.solve_with_retries writes into the detail when the first try gave no answer.
RETRY_NOTE = re.compile(r"re-solved|Clarabel retr")


def trajectories(out: Path, steps: int, seeds, rerun: bool, design_backend: str = "cvxpy") -> dict[int, Trajectory]:
    """The closed loops (cvxpy plain form), saved in ``out`` and loaded from there when present."""
    spec = get_example("massera2017")
    runs, design_ = {}, None
    for seed in seeds:
        path = out / f"seed{seed}.json.gz"
        if path.exists() and not rerun:
            runs[seed] = Trajectory.load(path)
            continue
        if design_ is None:
            from amcp_drake.offline.design import design

            design_ = design(spec.problem, spec.design, backend=design_backend)
        ctrl = AdaptiveMPC(spec.problem, design_, backend="cvxpy", options=spec.online, formulation="plain")
        traj = simulate(ctrl, spec.scenario.x0, THETA_STAR, steps, disturbance="vertices", seed=seed)
        traj.save(path)
        runs[seed] = traj
    return runs


def theta_k(width, recorded_h: np.ndarray) -> np.ndarray:
    """h_θk of Θ_k = {[1; −1] θ <= h}: Θ itself, [−1, −1 + w], or the recorded one."""
    if width == "Theta":
        return np.array([1.0, 1.0])
    if width == "recorded":
        return np.asarray(recorded_h, float)
    return np.array([-1.0 + float(width), 1.0])


def fresh_mpc(backend: str, data, clarabel: dict):
    """The tube QP of ``backend`` (plain form) with a solver built anew for every solve."""
    if backend == "cvxpy":
        from amcp_reference.solver_call import SolverCall
        from amcp_reference.tube_mpc import CvxpyTubeMPC

        return CvxpyTubeMPC(data, SolverCall("CLARABEL", clarabel, keep_solver=False))
    from amcp_drake.backends import get_backend

    return get_backend("drake", formulation="plain").tube_mpc(data)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path)
    ap.add_argument("--clarabel", type=json.loads, default={}, help="Clarabel options of the cvxpy plain form (JSON)")
    ap.add_argument("--loops", action="store_true", help="closed loops, QDLDL against faer")
    ap.add_argument("--example", default="massera2017",
                    help="built-in example of --loops: massera2017 with θ* = −1 and vertex disturbances, any other "
                         "with its scenario (θ*, disturbance kind)")
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--drake", action="store_true", help="also the Drake plain form")
    ap.add_argument("--rerun", action="store_true", help="run the closed loops again")
    ap.add_argument("--design", default="cvxpy", choices=("cvxpy", "drake"),
                    help="backend of the offline design of new closed loops (default: cvxpy)")
    args = ap.parse_args(argv)
    if args.loops:
        return closed_loops(args.example, args.steps, args.seeds)
    if args.out is None:
        ap.error("--out is required without --loops")
    args.out.mkdir(parents=True, exist_ok=True)
    runs = trajectories(args.out, args.steps, args.seeds, args.rerun, args.design)
    backends = ["cvxpy"] + (["drake"] if args.drake else [])
    spec = get_example("massera2017")
    entries = []
    for seed, traj in runs.items():
        ctrl = AdaptiveMPC(spec.problem, traj.design, backend="cvxpy", options=spec.online, formulation="plain")
        mpcs = {b: fresh_mpc(b, ctrl.data, args.clarabel) for b in backends}
        for rec in traj.records:
            for width in WIDTHS:
                h = theta_k(width, rec.h_theta)
                for b, mpc in mpcs.items():
                    cpu, wall = time.thread_time(), time.perf_counter()
                    sol = mpc.solve(rec.x, h, rec.theta_hat)
                    cpu, wall = time.thread_time() - cpu, time.perf_counter() - wall
                    failed = ([c.describe() for c in answer_checks.failures(ctrl._tube_checks(sol, rec.x, h, None))]
                              if sol.status is SolveStatus.OPTIMAL else [])
                    entries.append({"seed": seed, "k": rec.k, "width": str(width), "backend": b,
                                    "x": rec.x.tolist(), "theta_hat": rec.theta_hat.tolist(), "h_theta": h.tolist(),
                                    "status": sol.status.value, "detail": sol.detail, "failed_checks": failed,
                                    "retried": bool(RETRY_NOTE.search(sol.detail)),
                                    "cost": sol.cost, "cpu": cpu, "wall": wall})
    (args.out / "qps.json").write_text(json.dumps(entries, indent=0))
    for b in backends:
        mine = [e for e in entries if e["backend"] == b]
        unanswered = [e for e in mine if e["status"] != SolveStatus.OPTIMAL.value
                      and e["status"] != SolveStatus.INFEASIBLE.value]
        infeasible = [e for e in mine if e["status"] == SolveStatus.INFEASIBLE.value]
        retried = [e for e in mine if e["retried"]]
        failed = [e for e in mine if e["failed_checks"]]
        print(f"{b}: {len(mine)} QPs, without an answer {len(unanswered)}, infeasible {len(infeasible)}, "
              f"first try needed a retry {len(retried)}, answers failing the answer checks {len(failed)}, CPU median {1e3 * np.median([e['cpu'] for e in mine]):.1f} ms "
              f"(wall {1e3 * np.median([e['wall'] for e in mine]):.1f} ms)")
        for e in unanswered + failed:
            print(f"  seed {e['seed']} k {e['k']} width {e['width']}: {e['status']} {e['detail']} {e['failed_checks']}")
    return 0


def closed_loops(example: str, steps: int, seeds) -> int:
    """Closed loops of the cvxpy plain form with Clarabel's QDLDL and faer, in lockstep (see the module)."""
    import gc

    from amcp_drake.offline.design import design
    from amcp_drake.online.simulate import disturbance_sequence
    from amcp_drake.studies.resolves import count_resolves, step_kinds

    spec = get_example(example)
    problem = spec.problem
    massera = example == "massera2017"
    theta_star = THETA_STAR if massera else np.asarray(spec.scenario.theta_star, float)
    offline = design(problem, spec.design, backend="cvxpy")
    # before: QDLDL for the plain form (Clarabel's default factorisation) (the user's option overrides the backend's);
    # after: the backend as it is (faer for the plain form's QP, every other problem unchanged)
    solvers = {"qdldl (before)": {"direct_solve_method": "qdldl"}, "faer (after)": {}}
    for seed in seeds:
        w = disturbance_sequence(problem, "vertices" if massera else spec.scenario.disturbance, steps, seed)
        runs = []
        for name, options in solvers.items():
            ctrl = AdaptiveMPC(problem, offline, backend="cvxpy", options=spec.online, formulation="plain",
                               solver_options=options)
            runs.append({"name": name, "ctrl": ctrl, "x": np.asarray(spec.scenario.x0, float), "cpu": [], "wall": [],
                         "notes": [], "stop": ""})
        gc.collect()
        gc.disable()
        for k in range(steps):
            for run in (runs if k % 2 == 0 else runs[::-1]):
                if run["stop"]:
                    continue
                cpu, wall = time.thread_time(), time.perf_counter()
                u, rec = run["ctrl"].step(run["x"])
                run["cpu"].append(time.thread_time() - cpu)
                run["wall"].append(time.perf_counter() - wall)
                run["notes"].append(step_kinds(rec))
                if u is None:
                    run["stop"] = f"step {k}: {rec.status.value}"
                    continue
                theta_k = theta_star if theta_star.ndim == 1 else theta_star[min(k, len(theta_star) - 1)]  # θ*_k (Section 4.1)
                run["x"] = problem.step(run["x"], u, theta_k, w[k])
        gc.enable()
        for run in runs:
            counts = {kind: c for kind, c in count_resolves(run["notes"]).items() if c}
            print(f"{example} seed {seed} {run['name']:14s}: {len(run['cpu'])} steps {run['stop'] or 'completed'}; "
                  f"CPU per step median {1e3 * np.median(run['cpu']):.1f} ms (wall {1e3 * np.median(run['wall']):.1f} ms); "
                  f"{counts or 'no retry, no fallback'}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
