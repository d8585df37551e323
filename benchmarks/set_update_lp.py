"""How much of a step is the set-membership LP (9)? Times ``DrakeBackend.set_update`` (which builds
a new ``MathematicalProgram`` at every call) against the same LP built once and updated with
``UpdateCoefficients`` (a prototype, not used by the package), and the cvxpy backend's per-row
form, on the data of an Example 1 run.

    python benchmarks/set_update_lp.py [--steps 40]

Measured for issue 8: after the vertex form, LP (9) is the largest part of a Drake step (about
2-3 ms, of which the solver is ~0.4 ms). Caching it is a change to ``drake_.py`` outside the
issue's scope; this script is the evidence for that follow-up.
"""

from __future__ import annotations

import argparse
import time

import numpy as np


class CachedSetUpdateLP:
    """LP (9), min 1ᵀh s.t. Λ >= 0, Λ H̃ = H_θ, Λ h̃ <= h, built once for a shape (q, r, p)."""

    def __init__(self, q: int, r: int, p: int) -> None:
        from pydrake.solvers import MathematicalProgram

        self.q, self.r, self.p = q, r, p
        prog = self.prog = MathematicalProgram()
        self.h = prog.NewContinuousVariables(q, "h")
        self.Lam = prog.NewContinuousVariables(q, r, "Lambda")
        lam = self.Lam.reshape(-1)
        prog.AddBoundingBoxConstraint(0.0, np.inf, lam)
        self.eq = prog.AddLinearEqualityConstraint(np.zeros((q * p, q * r)), np.zeros(q * p), lam).evaluator()
        self.ineq = prog.AddLinearConstraint(np.zeros((q, q * r + q)), np.full(q, -np.inf), np.zeros(q),
                                             np.concatenate([lam, self.h])).evaluator()
        prog.AddLinearCost(np.ones(q), 0.0, self.h)

    def update(self, H_theta, h_prev, H_data, h_data):
        H_tilde = np.vstack([H_theta, H_data])
        h_tilde = np.concatenate([h_prev, h_data])
        self.eq.UpdateCoefficients(np.kron(np.eye(self.q), H_tilde.T), H_theta.reshape(-1))
        self.ineq.UpdateCoefficients(np.hstack([np.kron(np.eye(self.q), h_tilde[None, :]), -np.eye(self.q)]),
                                     np.full(self.q, -np.inf), np.zeros(self.q))
        return self.prog


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=40)
    args = parser.parse_args()

    from amcp_drake.backends import get_backend
    from amcp_drake.backends.drake_ import CLARABEL_LP_OPTIONS, _Solver
    from amcp_drake.model.examples import lorenzen2019_spec
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = lorenzen2019_spec()
    d = design(spec.problem, spec.design, backend="drake")
    ctrl = AdaptiveMPC(spec.problem, d, backend="drake", formulation="vertex")
    calls = []
    original = ctrl.backend.set_update

    def recording(*a):
        calls.append(tuple(np.array(x, float) for x in a))
        return original(*a)

    ctrl.backend.set_update = recording
    simulate(ctrl, spec.scenario.x0, spec.scenario.theta_star, args.steps, "uniform", seed=0)

    drake, cvx = get_backend("drake"), get_backend("cvxpy")
    solver = _Solver("clarabel", CLARABEL_LP_OPTIONS)
    cache: dict[tuple, CachedSetUpdateLP] = {}
    times = {"drake set_update (as is)": [], "drake, LP built once": [], "cvxpy set_update": []}
    worst = 0.0
    for args_ in calls:
        start = time.perf_counter()
        ref = drake.set_update(*args_)
        times["drake set_update (as is)"].append(time.perf_counter() - start)
        start = time.perf_counter()
        H_theta, _, H_data, _ = args_
        key = (H_theta.shape[0], H_theta.shape[0] + H_data.shape[0], H_theta.shape[1])
        lp = cache.get(key) or cache.setdefault(key, CachedSetUpdateLP(*key))
        result, _ = solver.solve(lp.update(*args_))
        h = result.GetSolution(lp.h)
        times["drake, LP built once"].append(time.perf_counter() - start)
        start = time.perf_counter()
        cvx.set_update(*args_)
        times["cvxpy set_update"].append(time.perf_counter() - start)
        worst = max(worst, float(np.max(np.abs(h - ref.h))))
    print(f"LP (9) on {len(calls)} updates of an Example 1 run (wall time per call, ms):")
    for name, t in times.items():
        ms = 1e3 * np.asarray(t)
        print(f"  {name:28s} median {np.median(ms):6.3f}  p90 {np.percentile(ms, 90):6.3f}")
    print(f"  max |h(built once) - h(as is)| = {worst:.1e}")


if __name__ == "__main__":
    main()
