"""Design and robust feasible region of the SLS-MPC 2-D family per ε_A, for each X0 template.

For every ε_A of the sweep and every design choice below, the script designs (every design check
of offline/checks.py must pass, else the row says why), then decides on a 10 x 10 grid of initial
states in the box ‖x‖∞ <= 8 whether the first QP (20) with Θ_0 = Θ is feasible: by the Drake
controller's QP (status optimal) and, independently, by the vertex-form LP of
properties/amcp_properties/feasible.py (scipy HiGHS); disagreements are counted and printed.

Choices:
* ``before``: the minimal-RPI template alone, with the smallest facet count that designs
  (8, 12, 16, 20, 24, 32, 48, 64, 96): what a user needed without the automatic design;
* ``auto``: the default design (first candidate of offline/auto.py that passes);
* ``contractive λ, R x c``: the λ-contractive template with the gain of the LMI with R scaled by c.

    PYTHONPATH=.:reference:properties python benchmarks/x0_template_regions.py [--grid 10] [--out FILE]

Writes a JSON table (default benchmarks/results/x0_template_regions.json) and prints a text table.
Design times are wall-clock (one run each; this is a measurement, not a timed test).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from amcp_drake.model.errors import DesignError
from amcp_drake.model.problem import DesignOptions
from amcp_drake.model.problem_io import write_json_atomic
from amcp_drake.model.sls_mpc_2d import SLS_EPS_A_SWEEP, sls_mpc_2d_spec
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design, design_fixed
from amcp_drake.online.controller import AdaptiveMPC

BEFORE_FACETS = (8, 12, 16, 20, 24, 32, 48, 64, 96)
ALTERNATIVES = {"contractive 0.99": dict(x0_template="contractive", x0_lambda=0.99),
                "contractive 0.95, R x 100": dict(x0_template="contractive", x0_lambda=0.95, gain_R_scale=100.0),
                "contractive 0.98, R x 100": dict(x0_template="contractive", x0_lambda=0.98, gain_R_scale=100.0)}


def grid_states(grid: int, bound: float = 8.0) -> np.ndarray:
    xs = np.linspace(-bound, bound, grid)
    return np.array([[a, b] for a in xs for b in xs])


def region(problem, d, states: np.ndarray) -> dict:
    """Fraction of ``states`` where the first QP is feasible (controller) and the LP agrees."""
    from amcp_properties.feasible import TubeGeometry, feasibility_margin

    geo = TubeGeometry.build(problem, d, problem.theta_vertices())
    qp, lp = [], []
    for x in states:
        ctrl = AdaptiveMPC(problem, d, backend="drake", formulation="vertex")
        _, record = ctrl.step(x)
        qp.append(record.status is SolveStatus.OPTIMAL)
        lp.append(feasibility_margin(geo, x) >= 0.0)
    qp, lp = np.array(qp), np.array(lp)
    return {"fraction_qp": float(qp.mean()), "fraction_lp": float(lp.mean()),
            "disagreements": int(np.sum(qp != lp))}


def _checked(problem, d) -> str:
    failed = [c.name for c in verify_design(problem, d) if not c.passed]
    return "pass" if not failed else "checks failed: " + ", ".join(failed)


def measure(eps_A: float, states: np.ndarray, choices=("before", "auto", "alternatives")) -> list[dict]:
    spec = sls_mpc_2d_spec(eps_A)
    pr = spec.problem
    rows = []
    start = time.perf_counter()
    for facets in BEFORE_FACETS if "before" in choices else ():
        try:
            d = design_fixed(pr, replace(spec.design, x0_template="mrpi", x0_facets=facets))
        except DesignError:
            continue
        if _checked(pr, d) == "pass":
            rows.append({"eps_A": eps_A, "choice": "before", "template": f"mrpi, {facets} facets",
                         "seconds": time.perf_counter() - start, **region(pr, d, states)})
            break
    else:
        if "before" in choices:
            rows.append({"eps_A": eps_A, "choice": "before", "template": "none designs",
                         "seconds": time.perf_counter() - start})
    start = time.perf_counter()
    d = design(pr, spec.design)
    if "auto" in choices:
        rows.append({"eps_A": eps_A, "choice": "auto", "template": d.info["x0_template"],
                 "seconds": time.perf_counter() - start, "attempts": len(d.info["attempts"]), **region(pr, d, states)})
    for name, changes in ALTERNATIVES.items() if "alternatives" in choices else ():
        start = time.perf_counter()
        try:
            d = design_fixed(pr, DesignOptions(**changes))
        except DesignError as exc:
            rows.append({"eps_A": eps_A, "choice": name, "template": f"fails: {str(exc)[:80]}"})
            continue
        status = _checked(pr, d)
        row = {"eps_A": eps_A, "choice": name, "template": f"{len(d.H_x)} facets, K {np.round(d.K, 3).tolist()}",
               "seconds": time.perf_counter() - start, "checks": status}
        if status == "pass":
            row.update(region(pr, d, states))
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grid", type=int, default=10)
    parser.add_argument("--eps", type=float, nargs="*", default=list(SLS_EPS_A_SWEEP))
    parser.add_argument("--out", default="benchmarks/results/x0_template_regions.json")
    parser.add_argument("--choices", nargs="*", default=["before", "auto", "alternatives"])
    args = parser.parse_args()
    states = grid_states(args.grid)
    rows = []
    for eps_A in args.eps:
        for row in measure(eps_A, states, tuple(args.choices)):
            rows.append(row)
            print(f"eps_A {row['eps_A']:.2f}  {row['choice']:26s} {row['template']:44s} "
                  f"{row.get('seconds', float('nan')):6.1f} s  region QP {row.get('fraction_qp', float('nan')):.2f} "
                  f"LP {row.get('fraction_lp', float('nan')):.2f}  disagree {row.get('disagreements', '-')}", flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic({"grid": args.grid, "box": 8.0, "rows": rows}, args.out)


if __name__ == "__main__":
    main()
