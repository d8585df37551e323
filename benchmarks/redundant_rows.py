"""Redundant rows of the vertex-form QP (20), and what removing them would save (issue 16, session 5).

    python benchmarks/redundant_rows.py [--step 60] [--facets 8]

Runs the Drake vertex form of Example 1 (X0 with ``--facets`` facets, N = 10) to step ``--step`` and
takes that step's program in Clarabel's form (``solver_floor.drake_clarabel_data``). A row is
removed when the rows still kept imply it: the LP max row·y over the kept rows (HiGHS through
scipy) stays within its bound (+1e-9). Rows are visited in order, once, so what is left is an
irredundant description of the same feasible set. Done twice: with every row, and without the rows
of (15b) (whose bound depends on x_k: rows implied without them are implied for every x_k). Prints
the counts, the CPU time of the LPs, and raw Clarabel (new solver, 200 solves, median CPU) on the
kept rows against every row, with the largest |Δv| and the largest violation of any row.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import clarabel
import numpy as np
from scipy.optimize import linprog

from amcp_drake.online.controller import AdaptiveMPC

sys.path.insert(0, str(Path(__file__).parent))
from solver_floor import drake_clarabel_data, example_1  # noqa: E402

#: A row is implied when the LP maximum of its left side stays this close to its bound.
IMPLIED_TOL = 1e-9


def irredundant(A: np.ndarray, b: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, float]:
    """The rows of ``rows`` left after removing, in order, each one the others still kept imply; CPU s."""
    kept = list(rows)
    start = time.process_time()
    for r in rows:
        others = [o for o in kept if o != r]
        # the row itself, loosened by 1, keeps the LP bounded without changing the question
        res = linprog(-A[r], A_ub=np.vstack([A[others], A[r]]), b_ub=np.concatenate([b[others], [b[r] + 1.0]]),
                      bounds=[(None, None)] * A.shape[1], method="highs")
        if res.status == 0 and -res.fun <= b[r] + IMPLIED_TOL:
            kept.remove(r)
    return np.array(kept), time.process_time() - start


def clarabel_cpu(P, q, A, b, repeats: int = 200) -> tuple[float, np.ndarray]:
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.iterative_refinement_enable = False
    times = []
    for _ in range(repeats):
        start = time.thread_time()
        solution = clarabel.DefaultSolver(P, q, A, b, [clarabel.NonnegativeConeT(A.shape[0])], settings).solve()
        times.append(time.thread_time() - start)
    return 1e3 * float(np.median(times)), np.asarray(solution.x)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--step", type=int, default=60)
    parser.add_argument("--facets", type=int, default=8)
    args = parser.parse_args()
    problem, sc, d, w = example_1(args.facets, args.step)
    ctrl = AdaptiveMPC(problem, d, backend="drake", formulation="vertex")
    x = np.asarray(sc.x0, float)
    for k in range(args.step + 1):
        u, rec = ctrl.step(x)
        if u is None:
            raise SystemExit(f"step {k}: {rec.status}")
        x = problem.step(x, u, sc.theta_star, w[k])
    mpc = ctrl.mpc
    P, q, A_sparse, b = drake_clarabel_data(mpc)
    A = A_sparse.toarray()
    # rows of (15b): the ones whose bound is -H_x x_k (the constraint _c15b, after (15a))
    n15a = mpc.N * mpc.data.F.shape[0]
    rows_15b = np.arange(n15a, n15a + mpc.u)
    every = np.arange(A.shape[0])
    full_ms, y_full = clarabel_cpu(P, q, A_sparse, b)
    print(f"Example 1, X0 {args.facets} facets, N = 10, vertex form, the QP of step {args.step}: "
          f"{A.shape[1]} variables, {A.shape[0]} rows ({len(mpc._last_vertices[2])} vertices of Theta_k)")
    print(f"raw Clarabel, every row: {full_ms:.3f} ms CPU (median of 200 new solvers)")
    for label, rows in (("every row", every), ("without (15b)", np.setdiff1d(every, rows_15b))):
        kept, cpu = irredundant(A, b, rows)
        line = f"{label}: {len(kept)} of {len(rows)} rows irredundant; {len(rows)} LPs, {cpu:.2f} s CPU"
        if label == "every row":
            ms, y = clarabel_cpu(P, q, A_sparse[kept], b[kept])
            dv = float(np.max(np.abs(y[mpc.v0:] - y_full[mpc.v0:])))
            violation = float(np.max(A @ y - b))
            line += f"; raw Clarabel on the kept rows {ms:.3f} ms CPU, |dv| {dv:.1e}, largest row violation {violation:.1e}"
        print(line)


if __name__ == "__main__":
    main()
