"""Which QP solver for the vertex form? Times the tube MPC QP (20) in vertex form on the data of an
Example 1 run (8-facet X0) with every candidate that is installed, against the plain form solved
at tight tolerances (the reference for v).

    python benchmarks/qp_solvers.py [--facets 8] [--steps 30]

Candidates: Clarabel through Drake (defaults; without iterative refinement = the vertex form's
setting), Clarabel's own Python API, and, only if installed (they are not dependencies of the
project): DAQP (dual active set, dense), PIQP (proximal interior point, dense), ProxQP (dense),
HiGHS (active-set QP). Each is timed on the same matrices; "max |dv|" is against the reference.
This is the measurement behind the choice recorded in benchmarks/README.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import time

import numpy as np
import scipy.sparse as sp


def run_data(facets: int, steps: int):
    from amcp_drake.model.examples import lorenzen2019_spec
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = lorenzen2019_spec()
    d = design(spec.problem, dataclasses.replace(spec.design, x0_facets=facets), backend="drake")
    ctrl = AdaptiveMPC(spec.problem, d, backend="drake", formulation="vertex")
    traj = simulate(ctrl, spec.scenario.x0, spec.scenario.theta_star, steps, "uniform", seed=0)
    return ctrl.data, [(r.x, r.h_theta, r.theta_hat) for r in traj.records]


def dense_qp(mpc, x, h, theta_hat):
    """The vertex-form QP as min ½ yᵀ P y + qᵀ y, A y <= b, α >= 0 (α = y[a0:v0])."""
    from amcp_drake.backends.vertex_form import theta_vertices

    d, n, m, N, u = mpc.data, mpc.n, mpc.m, mpc.N, mpc.u
    A_tube, b_tube = mpc.tube_rows(theta_vertices(d.H_theta, h))
    size, a0, v0 = mpc.size, mpc.a0, mpc.v0
    rows, rhs = [A_tube.toarray()], [b_tube]
    c = d.F.shape[0]
    FGK = d.F + d.G @ d.K
    for l in range(N):
        R = np.zeros((c, size))
        R[:, l * n:(l + 1) * n] = FGK
        R[:, v0 + l * m:v0 + (l + 1) * m] = d.G
        R[:, a0 + l] = d.f_bar
        rows.append(R)
        rhs.append(np.ones(c))
    R = np.zeros((u, size))
    R[:, :n] = -d.H_x
    R[:, a0] = -1.0
    rows.append(R)
    rhs.append(-d.H_x @ x)
    R = np.zeros((len(d.H_T), size))
    R[:, N * n:(N + 1) * n] = d.H_T
    R[:, a0 + N] = d.h_T
    rows.append(R)
    rhs.append(np.ones(len(d.H_T)))
    Hv, g, const = mpc._cost_model.matrices(x, theta_hat)
    P = np.zeros((size, size))
    P[v0:, v0:] = 2 * Hv
    q = np.zeros(size)
    q[v0:] = 2 * g
    return P, q, np.vstack(rows), np.concatenate(rhs), (a0, v0)


def candidates():
    out = {}

    def clarabel_py(P, q, A, b, idx, **settings):
        import clarabel

        a0, v0 = idx
        st = clarabel.DefaultSettings()
        st.verbose = False
        for k, v in settings.items():
            setattr(st, k, v)
        G = sp.vstack([sp.csc_matrix(A), -sp.eye(P.shape[0], format="csc")[a0:v0]]).tocsc()
        h = np.concatenate([b, np.zeros(v0 - a0)])
        sol = clarabel.DefaultSolver(sp.csc_matrix(np.triu(P)), q, G, h, [clarabel.NonnegativeConeT(len(h))], st).solve()
        return np.asarray(sol.x)[v0:]

    out["clarabel (python API)"] = clarabel_py
    out["clarabel (python API, no IR)"] = lambda *a: clarabel_py(*a, iterative_refinement_enable=False)
    if importlib.util.find_spec("daqp"):
        def daqp_solve(P, q, A, b, idx):
            import daqp

            a0, v0 = idx
            lo = np.full(P.shape[0], -1e30)
            lo[a0:v0] = 0.0
            x, _, flag, _ = daqp.solve(P, q, A, np.concatenate([np.full(P.shape[0], 1e30), b]),
                                       np.concatenate([lo, np.full(len(b), -1e30)]))
            return np.asarray(x)[v0:] if flag == 1 else None
        out["daqp"] = daqp_solve
    if importlib.util.find_spec("piqp"):
        def piqp_solve(P, q, A, b, idx):
            import piqp

            a0, v0 = idx
            s = piqp.DenseSolver()
            s.settings.verbose = False
            lo = np.full(P.shape[0], -np.inf)
            lo[a0:v0] = 0.0
            s.setup(P, q, None, None, A, np.full(len(b), -np.inf), b, lo, np.full(P.shape[0], np.inf))
            s.solve()
            return s.result.x[v0:]
        out["piqp (dense)"] = piqp_solve
    if importlib.util.find_spec("proxsuite"):
        def proxqp_solve(P, q, A, b, idx):
            import proxsuite

            a0, v0 = idx
            lo = np.full(P.shape[0], -1e20)
            lo[a0:v0] = 0.0
            qp = proxsuite.proxqp.dense.QP(P.shape[0], 0, len(b), box_constraints=True)
            qp.settings.verbose = False
            qp.settings.eps_abs = 1e-9
            qp.init(P, q, None, None, A, np.full(len(b), -1e20), b, lo, np.full(P.shape[0], 1e20))
            qp.solve()
            return qp.results.x[v0:]
        out["proxqp (dense)"] = proxqp_solve
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--facets", type=int, default=8)
    parser.add_argument("--steps", type=int, default=30)
    args = parser.parse_args()

    from amcp_drake.backends.drake_ import DrakeBackend

    data, points = run_data(args.facets, args.steps)
    tight = {"tol_gap_abs": 1e-11, "tol_gap_rel": 1e-11, "tol_feas": 1e-11}
    reference = DrakeBackend(solver_options=tight).tube_mpc(data)
    refs = [reference.solve(*pt).v.ravel() for pt in points]
    times: dict[str, list[float]] = {}
    errors: dict[str, list[float]] = {}
    drake_variants = {
        "drake clarabel, defaults": DrakeBackend(formulation="vertex", solver_options={"iterative_refinement_enable": True}),
        "drake clarabel, vertex-form settings": DrakeBackend(formulation="vertex"),
        "drake clarabel, plain form (15)": DrakeBackend(),
    }
    mpcs = {name: be.tube_mpc(data) for name, be in drake_variants.items()}
    others = candidates()
    helper = mpcs["drake clarabel, vertex-form settings"]
    for pt, ref in zip(points, refs):
        for name, mpc in mpcs.items():
            sol = mpc.solve(*pt)
            times.setdefault(name, []).append(sol.solver_time)
            errors.setdefault(name, []).append(float(np.max(np.abs(sol.v.ravel() - ref))))
        P, q, A, b, idx = dense_qp(helper, *pt)
        for name, solve in others.items():
            start = time.perf_counter()
            v = solve(P, q, A, b, idx)
            times.setdefault(name, []).append(time.perf_counter() - start)
            errors.setdefault(name, []).append(np.inf if v is None else float(np.max(np.abs(v - ref))))
    print(f"vertex-form QP of Example 1, X0 with {args.facets} facets, {len(points)} steps: solver call, ms")
    for name in times:
        t = 1e3 * np.asarray(times[name])
        print(f"  {name:40s} median {np.median(t):7.3f}  p90 {np.percentile(t, 90):7.3f}  "
              f"max |dv| vs reference {max(errors[name]):.1e}")


if __name__ == "__main__":
    main()
