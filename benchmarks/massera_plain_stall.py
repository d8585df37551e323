"""Anatomy of one cvxpy plain-form tube QP (20) as Clarabel sees it (session 8, docs/decisions.md "The cvxpy
plain form's unanswered QPs on massera2017").

    python benchmarks/massera_plain_stall.py [--width 1e-4] [--option direct_solve_method=faer ...] [--verbose]

Reads the recorded step ``tests/data/massera2017-plain-stall-step.json`` (massera2017, θ* = −1, its
``TubeMPCData``), sets Θ_k = [−1, −1 + width] (width 2: Θ itself), takes cvxpy's Clarabel data of the
plain form and solves it with Clarabel directly (options: Clarabel's defaults, then ``--option``s). Prints
the sizes, the rows grouped by the variables they touch, the status, μ = sᵀz / (inequality rows), per group
sᵀz, the interior pairs (s > 1e-3, z < 1e-6) and the extreme slacks and duals, the singular values of the
rows of (15c) and (15d) of stage 0, and the largest |cos| between the rows of (15c) and (15d) (rows
normalised; pairs of (15c) rows above 0.999 and 1 − 1e-6).
"""

from __future__ import annotations

import argparse
import ast
import json
from collections import Counter
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from amcp_drake.backends import TubeMPCData

STEP = Path(__file__).resolve().parent.parent / "tests" / "data" / "massera2017-plain-stall-step.json"
#: Groups of rows (by the variables they touch) whose near-parallel pairs are counted.
TUBE, EQUALITY = "in:Lambda+alpha+v+z", "eq:Lambda+alpha+v+z"


def clarabel_data(width: float):
    """(cvxpy problem data, row group per row) of the plain form at Θ_k = [−1, −1 + width]."""
    from amcp_reference.solver_call import SolverCall
    from amcp_reference.tube_mpc import CvxpyTubeMPC

    step = json.loads(STEP.read_text())
    data = TubeMPCData(**{k: (v if k in ("N", "cost") else np.asarray(v, float)) for k, v in step["tube_data"].items()})
    h = np.array([1.0, 1.0]) if width >= 2 else np.array([-1.0 + width, 1.0])
    mpc = CvxpyTubeMPC(data, SolverCall("CLARABEL", {}, keep_solver=False))
    mpc._set_parameters(mpc.form, np.asarray(step["x"], float), h, np.asarray(step["theta_hat"], float))
    problem_data, _, inverse = mpc.form.problem.get_problem_data("CLARABEL")
    # the variables after cvxpy's reductions: the originals by id, the copies made for the nonneg
    # attribute by shape (alpha (N+1,), each Λ_l (v·u, q))
    stuffed = inverse[-2]
    names = {v.id: v.name() for v in mpc.form.problem.variables()}
    lam_shape = mpc.form.Lambda[0].shape
    owner = np.empty(problem_data["A"].shape[1], dtype=object)
    for vid, offset in stuffed.var_offsets.items():
        shape = stuffed.var_shapes[vid]
        name = names.get(vid) or ("alpha" if shape == mpc.form.alpha.shape else "Lambda" if shape == lam_shape else "aux")
        owner[offset:offset + int(np.prod(shape))] = "Lambda" if name.startswith("Lambda") else name
    A = problem_data["A"].tocsr()
    zero = problem_data["dims"].zero
    groups = []
    for r in range(A.shape[0]):
        cols = A.indices[A.indptr[r]:A.indptr[r + 1]]
        groups.append(("eq:" if r < zero else "in:") + "+".join(sorted(set(owner[cols]))) + ("#1" if len(cols) == 1 else ""))
    return problem_data, np.array(groups)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--width", type=float, default=1e-4)
    ap.add_argument("--option", action="append", default=[], help="Clarabel setting=value (Python literal)")
    ap.add_argument("--verbose", action="store_true", help="Clarabel's iteration log")
    args = ap.parse_args(argv)
    import clarabel

    d, groups = clarabel_data(args.width)
    A, b, P, c, dims = d["A"].tocsc(), d["b"], d["P"], d["c"], d["dims"]
    print(f"width {args.width:g}: {A.shape[1]} variables, {dims.zero} equality rows, {dims.nonneg} inequality rows")
    print("rows:", dict(Counter(groups)))
    settings = clarabel.DefaultSettings()
    settings.verbose = args.verbose
    for item in args.option:
        key, value = item.split("=", 1)
        setattr(settings, key, ast.literal_eval(value) if value[:1] not in "abcdefghijklmnopqrstuvwxyz" else value)
    cones = [clarabel.ZeroConeT(dims.zero), clarabel.NonnegativeConeT(dims.nonneg)]
    sol = clarabel.DefaultSolver(sp.triu(P).tocsc(), c, A, b, cones, settings).solve()
    s, z = np.array(sol.s), np.array(sol.z)
    mu = float(s[dims.zero:] @ z[dims.zero:]) / dims.nonneg
    print(f"{sol.status} after {sol.iterations} iterations; primal {sol.obj_val:.10g}, dual {sol.obj_val_dual:.10g}, "
          f"mu = s'z/{dims.nonneg} = {mu:.3g}")
    for group in sorted(set(groups)):
        rows = np.flatnonzero(groups == group)
        if group.startswith("eq"):
            print(f"  {group:28s} {len(rows):5d} rows, |dual| max {np.abs(z[rows]).max():.3g}")
            continue
        pairs = s[rows] * z[rows]
        interior = int(np.sum((s[rows] > 1e-3) & (z[rows] < 1e-6)))
        print(f"  {group:28s} {len(rows):5d} rows, s'z {pairs.sum():.3g} (s z / mu {pairs.min() / mu:.3g}..{pairs.max() / mu:.3g}), "
              f"interior {interior}, s {s[rows].min():.3g}..{s[rows].max():.3g}, z {z[rows].min():.3g}..{z[rows].max():.3g}")
    # conditioning of (15c)-(15d) of stage 0 (cvxpy adds the constraints stage by stage, so a group's
    # first v·u rows are stage 0's): each multiplier row couples its q multipliers to both rows
    per_stage = len(np.flatnonzero(groups == EQUALITY)) // int(json.loads(STEP.read_text())["tube_data"]["N"])
    stage = np.concatenate([np.flatnonzero(groups == g)[:per_stage] for g in (EQUALITY, TUBE)])
    block = sp.csr_matrix(A)[stage]
    dense = block[:, np.unique(block.nonzero()[1])].toarray()
    sv = np.linalg.svd(dense, compute_uv=False)
    print(f"  stage 0, rows of (15c) and (15d) {dense.shape}: singular values {sv.min():.3g}..{sv.max():.3g}, "
          f"{int(np.sum(sv < 1e-2))} below 1e-2, condition {sv.max() / sv.min():.3g}")
    norms = sp.linalg.norm(A, axis=1)
    unit = sp.diags(1.0 / np.maximum(norms, 1e-300)) @ A.tocsr()
    gram = (unit @ unit.T).tocoo()
    upper = gram.row < gram.col
    r, k, cos = gram.row[upper], gram.col[upper], np.abs(gram.data[upper])
    for first, second in ((TUBE, EQUALITY), (TUBE, TUBE), (EQUALITY, EQUALITY)):
        sel = ((groups[r] == first) & (groups[k] == second)) | ((groups[r] == second) & (groups[k] == first))
        print(f"  |cos| {first} / {second}: max {cos[sel].max():.10f}, pairs > 0.999: {int(np.sum(cos[sel] > 0.999))}, "
              f"> 1 - 1e-6: {int(np.sum(cos[sel] > 1 - 1e-6))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
