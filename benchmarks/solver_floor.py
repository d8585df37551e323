"""Where the solver-bound performance targets stop: the solver calls of one step, timed apart.

    python benchmarks/solver_floor.py [--steps 300] [--facets 8]

Example 1 (X0 with ``--facets`` facets, N = 10), the vertex form, the Drake and the cvxpy backend
in lockstep (same disturbances; step k of each, then step k+1). After each controller step, the QP
(20) of that step (its coefficients and parameters as the step left them) is solved again, apart
from the step, piece by piece; every figure is the median over the steps of the thread CPU time:

* Drake: the whole ``Solve`` (Drake's translation of the program, a new Clarabel solver, its
  iterations), and Clarabel's own solve time as Drake reports it (``solve_time``, wall). For
  comparison only, the same data given to a Clarabel solver that is kept between steps
  (``update`` then ``solve``). Drake's ``ClarabelSolver`` builds a new solver at every ``Solve`` and
  has no update API; this row shows what that costs (on Example 1: nothing measurable, because
  the update of P and A costs what the new solver's setup costs).
* cvxpy: ``Problem.get_problem_data`` (cvxpy's DPP parameter application), Clarabel's ``update``
  of a kept solver with that data (what cvxpy's ``warm_start=True`` does), Clarabel's ``solve``,
  and the whole ``Problem.solve(warm_start=True)``. "Modelling layer" = whole − Clarabel solve:
  parameter application, data update, unpacking.

The controller's own full step (``amcp_drake.studies.bench_cpu``) is timed as in the bench. The
floors printed follow from the parts alone:

* Drake vertex full step >= Drake ``Solve``;
* cvxpy vertex / Drake vertex through ``Problem.solve`` >= (Clarabel's solve time inside Drake +
  cvxpy's modelling layer) / Drake's full step: even if the cvxpy backend's own code cost nothing and
  Clarabel solved cvxpy's QP (97 variables, 822 rows, x̂ kept as variables) as fast as Drake's (43
  variables, 768 rows), cvxpy's ``Problem.solve`` would add its modelling layer to the same Clarabel
  work (1.6-1.7×; why the backend solves each step by the compiled route instead);
* the same floor through the compiled route the backend uses
  (:mod:`amcp_reference.compiled_clarabel`: cvxpy's compiled data evaluated into fixed patterns, a
  kept Clarabel solver updated by the changed entries), timed on the same step again.

Run it from the repository root with the working tree on PYTHONPATH.
"""

from __future__ import annotations

import argparse
import gc
import time
from dataclasses import replace

import clarabel
import numpy as np
import scipy.sparse as sp

from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import disturbance_sequence
from amcp_drake.studies.bench_cpu import CpuProfile


def _cpu(fn) -> tuple[float, object]:
    start = time.thread_time()
    out = fn()
    return time.thread_time() - start, out


def drake_clarabel_data(mpc) -> tuple[sp.csc_matrix, np.ndarray, sp.csc_matrix, np.ndarray]:
    """(P upper triangle, q, A, b) of Clarabel's form A y + s = b, s >= 0, of the Drake vertex
    program as it stands (every linear constraint and bounding box, finite sides only)."""
    prog, size = mpc.prog, mpc.size
    blocks, lowers, uppers = [], [], []
    for binding in list(prog.linear_constraints()) + list(prog.bounding_box_constraints()):
        ev = binding.evaluator()
        columns = [prog.FindDecisionVariableIndex(v) for v in binding.variables()]
        A = np.zeros((ev.num_constraints(), size))
        A[:, columns] = ev.GetDenseA()
        blocks.append(A)
        lowers.append(ev.lower_bound())
        uppers.append(ev.upper_bound())
    A, lb, ub = np.vstack(blocks), np.concatenate(lowers), np.concatenate(uppers)
    upper, lower = np.isfinite(ub), np.isfinite(lb)
    A_c = sp.csc_matrix(np.vstack([A[upper], -A[lower]]))
    b_c = np.concatenate([ub[upper], -lb[lower]])
    P, q = np.zeros((size, size)), np.zeros(size)
    for binding in prog.quadratic_costs():
        columns = [prog.FindDecisionVariableIndex(v) for v in binding.variables()]
        P[np.ix_(columns, columns)] += binding.evaluator().Q()
        q[columns] += binding.evaluator().b()
    return sp.triu(sp.csc_matrix(P)).tocsc(), q, A_c, b_c


def _settings(options: dict) -> clarabel.DefaultSettings:
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    for name, value in options.items():
        setattr(settings, name, value)
    return settings


def example_1(facets: int, steps: int):
    """(problem, scenario, design, disturbances): Example 1 with an X0 of ``facets`` facets (N = 10),
    the design on Drake, ``steps`` + 1 disturbances uniform on W (seed 0)."""
    spec = lorenzen2019_spec()
    d = design(spec.problem, replace(spec.design, x0_facets=facets), backend="drake")
    return spec.problem, spec.scenario, d, disturbance_sequence(spec.problem, "uniform", steps + 1, seed=0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--facets", type=int, default=8)
    args = parser.parse_args()
    problem, sc, d, w = example_1(args.facets, args.steps)
    drake = AdaptiveMPC(problem, d, backend="drake", formulation="vertex")
    cvx = AdaptiveMPC(problem, d, backend="cvxpy", formulation="vertex")
    profiles = {"drake": CpuProfile(drake), "cvxpy": CpuProfile(cvx)}
    states = {name: np.asarray(sc.x0, float) for name in profiles}
    parts: dict[str, list[float]] = {}
    kept: dict[str, clarabel.DefaultSolver] = {}
    sizes = {}

    def add(name: str, value: float) -> None:
        parts.setdefault(name, []).append(value)

    gc.collect()
    gc.disable()
    for k in range(args.steps + 1):
        for name, prof in profiles.items():
            u, rec, step_parts = prof.step(states[name])
            if u is None:
                raise SystemExit(f"{name}: step {k} {rec.status}")
            states[name] = problem.step(states[name], u, sc.theta_star, w[k])
            if k == 0:
                continue
            add(f"{name} full step", step_parts["total"])
            add(f"{name} QP solver call (in the step)", step_parts["qp_solver"])
            add(f"{name} outside the solver calls (in the step)", step_parts["outside_solvers"])
        if k == 0:
            continue
        # -- Drake: the program as this step left it ------------------------------------------------
        mpc = drake.mpc
        cpu, (result, _) = _cpu(lambda: mpc._solver.solve(mpc.prog))
        add("drake Solve (whole)", cpu)
        add("drake Clarabel solve_time (wall, inside Solve)", result.get_solver_details().solve_time)
        P, q, A, b = drake_clarabel_data(mpc)
        sizes["drake"] = A.shape[::-1]
        cones = [clarabel.NonnegativeConeT(A.shape[0])]
        if "drake" not in kept:
            kept["drake"] = clarabel.DefaultSolver(P, q, A, b, cones, _settings(mpc._solver.option_values))
        cpu_u, _ = _cpu(lambda: kept["drake"].update(P=P, q=q, A=A, b=b))
        cpu_s, sol = _cpu(kept["drake"].solve)
        add("drake data, Clarabel solver kept: update + solve (for comparison)", cpu_u + cpu_s)
        v_drake = np.asarray(result.GetSolution(mpc.y))[mpc.v0:]
        if np.max(np.abs(np.asarray(sol.x)[mpc.v0:] - v_drake)) > 1e-6:
            raise SystemExit(f"step {k}: the kept Clarabel solver disagrees with Drake's Solve")
        # -- cvxpy: the Problem with this step's parameters ---------------------------------------------
        prob = cvx.mpc.problem
        options = cvx.mpc._call.options
        cpu, (data, _, _) = _cpu(lambda: prob.get_problem_data("CLARABEL"))
        add("cvxpy get_problem_data (parameter application)", cpu)
        P, q, A, b = sp.triu(data["P"]).tocsc(), data["c"], data["A"], data["b"]
        sizes["cvxpy"] = A.shape[::-1]
        if "cvxpy" not in kept:
            from cvxpy.reductions.solvers.conic_solvers.clarabel_conif import dims_to_solver_cones

            kept["cvxpy"] = clarabel.DefaultSolver(P, q, A, b, dims_to_solver_cones(data["dims"]), _settings(options))
        cpu_u, _ = _cpu(lambda: kept["cvxpy"].update(P=P, q=q, A=A, b=b))
        cpu_s, _ = _cpu(kept["cvxpy"].solve)
        add("cvxpy Clarabel update (kept solver)", cpu_u)
        add("cvxpy Clarabel solve", cpu_s)
        cpu, _ = _cpu(lambda: prob.solve(solver="CLARABEL", warm_start=True, **options))
        add("cvxpy Problem.solve (whole, warm_start)", cpu)
        add("cvxpy modelling layer (whole - Clarabel solve)", cpu - cpu_s)
        # the compiled route the backend uses (amcp_reference.compiled_clarabel): the same step again
        form = cvx.mpc._forms[cvx.mpc.capacity]
        if form.compiled is not None and form.compiled.reason is None:
            cpu, (answer, _) = _cpu(lambda: cvx.mpc._solve_compiled(form))
            if answer is None:
                raise SystemExit(f"step {k}: the compiled route gave no answer")
            add("cvxpy compiled route (data, update, solve, read back)", cpu)
            add("cvxpy compiled route without its Clarabel solve", cpu - cpu_s)
    gc.enable()
    med = {name: 1e3 * float(np.median(values)) for name, values in parts.items()}
    print(f"Example 1, X0 {args.facets} facets, N = 10, vertex form, {args.steps} steps; "
          f"QP sizes (variables, rows): Drake {sizes['drake']}, cvxpy {sizes['cvxpy']}")
    print("CPU ms, medians (solve_time: wall)")
    width = max(map(len, med))
    for name, value in med.items():
        print(f"  {name:<{width}}  {value:8.3f}")
    drake_step = med["drake full step"]
    floor = (med["drake Clarabel solve_time (wall, inside Solve)"] + med["cvxpy modelling layer (whole - Clarabel solve)"])
    print(f"measured ratio cvxpy / Drake full step: {med['cvxpy full step'] / drake_step:.2f}")
    print(f"floor of that ratio through Problem.solve: (Clarabel inside Drake {med['drake Clarabel solve_time (wall, inside Solve)']:.3f}"
          f" + cvxpy modelling layer {med['cvxpy modelling layer (whole - Clarabel solve)']:.3f}) / Drake full step "
          f"{drake_step:.3f} = {floor / drake_step:.2f}")
    route = med.get("cvxpy compiled route without its Clarabel solve")
    if route is not None:
        print(f"floor through the compiled route: (Clarabel inside Drake "
              f"{med['drake Clarabel solve_time (wall, inside Solve)']:.3f} + compiled route without its Clarabel solve "
              f"{route:.3f}) / Drake full step {drake_step:.3f} = "
              f"{(med['drake Clarabel solve_time (wall, inside Solve)'] + route) / drake_step:.2f}")
    print(f"Drake full step {drake_step:.3f} ms, of which at least the Solve {med['drake Solve (whole)']:.3f} ms; "
          f"outside the solver calls {med['drake outside the solver calls (in the step)']:.3f} ms")


if __name__ == "__main__":
    main()
