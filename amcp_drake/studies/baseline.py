"""Adaptive vs robust baseline on a problem: what does adaptation buy?

:func:`robust_beside` runs the robust baseline beside one recorded adaptive run (the same problem, design,
backend, x0, θ* and recorded disturbance sequence; ``amcp certify`` shows it in report.html, apart from
the verdict). :func:`run_baseline` is the study over many seeds (``amcp baseline``): for each
disturbance seed, two closed loops are run from the same x0 with the same θ* and the same
disturbance sequence:

* **adaptive**: the full scheme, Θ_k by (9) (or the update chosen) and θ̂_k by (12);
* **robust**: ``OnlineOptions(update="none")``, i.e. Θ_k ≡ Θ_0 and θ̂_k ≡ θ̂_0 (the non-adaptive
  homothetic tube MPC with the same tube, terminal set and cost).

Measured per run: the closed-loop cost Σ_k (‖x_k‖²_Q + ‖u_k‖²_R) over the simulated steps; the
one-step uncertainty tube size s_k = max_i (max_{θ∈Θ_k} [H_x D(x_k, u_k)(θ − θ̂_k)]_i + w̄_i), the
smallest scaling s with A(θ)x_k + B(θ)u_k + w ∈ x̂_{1|k} ⊕ s X0 for every θ ∈ Θ_k and w ∈ W
(x̂_{1|k} the certainty-equivalence prediction (18); vertices of Θ_k), i.e. what the set estimate
costs the tube at the applied input, mean over k; the mean of α_{0|k} returned by the QP
(informational only: α is not in the cost (17), so it is not minimised); and the feasible region of the QP
(20): the fraction of a grid of initial states x0 in a box for which 𝔻(x0, Θ_k) ≠ ∅, evaluated at
the final Θ_T of the adaptive run and at Θ_0 = Θ. Because Θ_T ⊆ Θ (Lemma 3), the worst case
max_{θ∈Θ_T} H_x D^j θ in (5b)/(15c) is row-wise at most that over Θ, so a tube feasible for Θ is
feasible for Θ_T: every x0 feasible under Θ is feasible under Θ_T and the adaptive region contains
the robust one (checked point-wise by tests/test_baseline.py). The terminal set X_f is built on Θ
in both cases.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amcp_drake.model.errors import InconsistentDataError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import ProblemSpec
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate

#: Default grid box for x0 on Example 1 ((x1_lo, x1_hi), (x2_lo, x2_hi)): it contains the scenario
#: x0 = [2, 3] and the part of the boundary of the feasible region at positive x1, where the input
#: bound |u| <= 1 and x2 >= -0.3 bite (the region extends far to negative x1, so the box cuts it).
DEFAULT_BOX = ((-5.0, 15.0), (-0.5, 15.0))
#: Default grid resolution per axis.
DEFAULT_GRID = 31


@dataclass
class RunMetrics:
    """One closed loop: cost Σ(‖x‖²_Q + ‖u‖²_R), mean α_{0|k}, completion flag, final offsets h_θT."""

    cost: float
    mean_alpha0: float
    mean_one_step_tube: float
    mean_parametric_tube: float
    completed: bool
    h_theta_final: np.ndarray
    H_theta_final: np.ndarray


@dataclass
class BaselineResult:
    """Per-seed metrics for the adaptive and robust loops and the grid feasibility maps."""

    seeds: list[int]
    adaptive: list[RunMetrics]
    robust: list[RunMetrics]
    grid_x1: np.ndarray
    grid_x2: np.ndarray
    feasible_robust: np.ndarray                       # (g2, g1) bool, Θ_0
    feasible_adaptive: list[np.ndarray] = field(default_factory=list)  # per seed, (g2, g1) bool, Θ_T

    def table_rows(self) -> list[tuple[str, str, str]]:
        ac = np.array([r.cost for r in self.adaptive])
        rc = np.array([r.cost for r in self.robust])
        aa = np.array([r.mean_alpha0 for r in self.adaptive])
        ra = np.array([r.mean_alpha0 for r in self.robust])
        at = np.array([r.mean_one_step_tube for r in self.adaptive])
        rt = np.array([r.mean_one_step_tube for r in self.robust])
        ap = np.array([r.mean_parametric_tube for r in self.adaptive])
        rp = np.array([r.mean_parametric_tube for r in self.robust])
        fr = float(np.mean(self.feasible_robust))
        fa = np.array([float(np.mean(f)) for f in self.feasible_adaptive])
        return [
            ("runs completed", f"{sum(r.completed for r in self.adaptive)}/{len(self.adaptive)}",
             f"{sum(r.completed for r in self.robust)}/{len(self.robust)}"),
            ("closed-loop cost Σ(‖x‖²_Q+‖u‖²_R), median", f"{np.median(ac):.3f}", f"{np.median(rc):.3f}"),
            ("closed-loop cost, mean", f"{np.mean(ac):.3f}", f"{np.mean(rc):.3f}"),
            ("cost ratio adaptive/robust per seed, median", f"{np.median(ac / rc):.4f}", "1"),
            ("one-step tube size mean_k s_k, median over seeds", f"{np.median(at):.4f}", f"{np.median(rt):.4f}"),
            ("one-step tube size ratio adaptive/robust per seed, median", f"{np.median(at / rt):.4f}", "1"),
            ("parametric part max_i max_θ [H_x D(θ−θ̂_k)]_i, mean_k, median over seeds", f"{np.median(ap):.4f}",
             f"{np.median(rp):.4f}"),
            ("QP's α_{0|k}, mean over k, median over seeds (not minimised)", f"{np.median(aa):.4f}",
             f"{np.median(ra):.4f}"),
            ("feasible fraction of the x0 grid (QP (20)), median", f"{np.median(fa):.4f}", f"{fr:.4f}"),
            ("feasible fraction, min over seeds", f"{np.min(fa):.4f}", f"{fr:.4f}"),
        ]

    def markdown(self) -> str:
        lines = ["| quantity | adaptive (Θ_k by the update) | robust (Θ_k ≡ Θ, θ̂_k ≡ θ̂0) |", "|---|---|---|"]
        lines += [f"| {a} | {b} | {c} |" for a, b, c in self.table_rows()]
        return "\n".join(lines)


def one_step_tube(problem, design: OfflineDesign, x, u, H_theta, h_theta, theta_hat, disturbance: bool = True) -> float:
    """s = max_i (max_{θ∈Θ_k} [H_x D(x, u)(θ − θ̂)]_i + w̄_i): the smallest s with every one-step
    successor A(θ)x + B(θ)u + w (θ ∈ Θ_k, w ∈ W) in x̂_1 ⊕ s X0, X0 = {H_x x <= 1}, x̂_1 the prediction
    with θ̂. Computed from the vertices of Θ_k (numpy/scipy only). ``disturbance=False``: the
    parametric part alone, max_i max_{θ∈Θ_k} [H_x D(x, u)(θ − θ̂)]_i."""
    from amcp_drake.model.polytope import theta_vertices

    verts = theta_vertices(H_theta, h_theta)
    if verts is None or len(verts) == 0:
        return float("nan")
    D = problem.regressor(x, u)
    spread = np.asarray(design.H_x, float) @ D @ (verts - np.asarray(theta_hat, float)).T  # (u, vertices)
    w_bar = np.asarray(design.w_bar, float) if disturbance else 0.0
    return float(np.max(spread.max(axis=1) + w_bar))


def _metrics(traj, Q, R) -> RunMetrics:
    x, u = traj.x[: len(traj.u)], traj.u
    cost = float(np.einsum("ki,ij,kj->", x, Q, x) + np.einsum("ki,ij,kj->", u, R, u))
    alphas = [r.alpha[0] for r in traj.records if r.alpha is not None]
    tubes = [one_step_tube(traj.problem, traj.design, traj.x[r.k], traj.u[r.k], r.H_theta, r.h_theta, r.theta_hat)
             for r in traj.records if r.k < len(traj.u)]
    params = [one_step_tube(traj.problem, traj.design, traj.x[r.k], traj.u[r.k], r.H_theta, r.h_theta, r.theta_hat,
                            disturbance=False) for r in traj.records if r.k < len(traj.u)]
    last = traj.records[-1]
    return RunMetrics(cost=cost, mean_alpha0=float(np.mean(alphas)) if alphas else float("nan"),
                      mean_one_step_tube=float(np.mean(tubes)) if tubes else float("nan"),
                      mean_parametric_tube=float(np.mean(params)) if params else float("nan"),
                      completed=traj.stop_reason == "completed" and traj.all_solved,
                      h_theta_final=np.asarray(last.h_theta, float), H_theta_final=np.asarray(last.H_theta, float))


def feasible_grid(controller: AdaptiveMPC, h_theta: np.ndarray, grid_x1: np.ndarray, grid_x2: np.ndarray,
                  H_theta: np.ndarray | None = None) -> np.ndarray:
    """Boolean map (len(grid_x2), len(grid_x1)): 𝔻(x0, Θ) ≠ ∅ for Θ = {H θ <= h_theta}, i.e. the QP
    (20) is solved to optimality at x0 (the cost's θ̂ is irrelevant to feasibility; θ̂0 is used)."""
    theta_hat = controller.problem.theta_hat0
    out = np.zeros((len(grid_x2), len(grid_x1)), dtype=bool)
    for i, x2 in enumerate(grid_x2):
        for j, x1 in enumerate(grid_x1):
            sol = controller.mpc.solve(np.array([x1, x2], float), h_theta, theta_hat, H_theta)
            out[i, j] = sol.status is SolveStatus.OPTIMAL
    return out


def run_baseline(spec: ProblemSpec, design: OfflineDesign, seeds: int | list[int] = 20, steps: int | None = None,
                 backend: str = "drake", formulation: str = "vertex", update: str = "fixed",
                 box=DEFAULT_BOX, grid: int = DEFAULT_GRID, disturbance: str | None = None) -> BaselineResult:
    """Adaptive vs robust over ``seeds`` (a count -> seeds 0..count-1, or a list) on ``spec``'s
    scenario. The problem must have n = 2 for the grid (Example 1)."""
    pr, sc = spec.problem, spec.scenario
    if sc is None:
        from amcp_drake.model.errors import ProblemError

        raise ProblemError("scenario", "a scenario in the problem file (x0, theta_star)", "none")
    seed_list = list(range(seeds)) if isinstance(seeds, (int, np.integer)) else [int(s) for s in seeds]
    steps = steps or sc.steps
    if disturbance is None:
        disturbance = sc.disturbance_for(steps)  # an explicit sequence is the same for every seed
    adaptive = AdaptiveMPC(pr, design, backend=backend, options=OnlineOptions(update=update), formulation=formulation)
    robust = AdaptiveMPC(pr, design, backend=backend, options=OnlineOptions(update="none"), formulation=formulation)
    g1 = np.linspace(*box[0], grid)
    g2 = np.linspace(*box[1], grid)
    res = BaselineResult(seeds=seed_list, adaptive=[], robust=[], grid_x1=g1, grid_x2=g2,
                         feasible_robust=feasible_grid(robust, design.h_theta0, g1, g2))
    for s in seed_list:
        ta = simulate(adaptive, sc.x0, sc.theta_star, steps, disturbance, seed=s)
        tr = simulate(robust, sc.x0, sc.theta_star, steps, disturbance, seed=s)
        ma, mr = _metrics(ta, pr.Q, pr.R), _metrics(tr, pr.Q, pr.R)
        res.adaptive.append(ma)
        res.robust.append(mr)
        H_arg = ma.H_theta_final if update == "exact" else None
        res.feasible_adaptive.append(feasible_grid(adaptive, ma.h_theta_final, g1, g2, H_arg))
    return res


# -- the robust baseline beside one recorded run (report.html of ``amcp certify``) ----------------------
#: Directions probed for the feasible region: the direction of x0, its opposite, and ±e_i for the first
#: RAY_AXES states (at most 2 + 2·RAY_AXES rays, so the cost does not grow with n).
RAY_AXES = 2
#: Relative accuracy of the feasible radius along a ray (bisection).
RAY_REL_TOL = 1e-2
#: The radius is searched up to 2**RAY_DOUBLINGS times max(‖x0‖, 1); beyond it is reported as a lower bound.
RAY_DOUBLINGS = 6


def closed_loop_cost(traj) -> float:
    """Σ_{k<T} (‖x_k‖²_Q + ‖u_k‖²_R) over the T applied inputs (the stage cost of (17) on the run)."""
    x, u = traj.x[: len(traj.u)], traj.u
    Q, R = traj.problem.Q, traj.problem.R
    return float(np.einsum("ki,ij,kj->", x, Q, x) + np.einsum("ki,ij,kj->", u, R, u))


def tube_series(traj, disturbance: bool) -> list[float]:
    """The one-step tube size s_k (:func:`one_step_tube`) at every applied step k of ``traj``."""
    return [one_step_tube(traj.problem, traj.design, traj.x[r.k], traj.u[r.k], r.H_theta, r.h_theta, r.theta_hat,
                          disturbance=disturbance) for r in traj.records if r.k < len(traj.u)]


def ray_directions(x0: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(name, unit vector) of the rays along which the feasible region is probed."""
    n = len(x0)
    out: list[tuple[str, np.ndarray]] = []
    norm = float(np.linalg.norm(x0))
    if norm > 0:
        out += [("x0", x0 / norm + 0.0), ("−x0", -x0 / norm + 0.0)]  # + 0.0: no negative zeros
    for i in range(min(n, RAY_AXES)):
        for sign, name in ((1.0, f"+e{i + 1}"), (-1.0, f"−e{i + 1}")):
            e = np.zeros(n)
            e[i] = sign
            if not any(np.allclose(e, d) for _, d in out):
                out.append((name, e))
    return out


def feasible_radius(feasible, direction: np.ndarray, start: float) -> tuple[float | None, bool]:
    """(r, capped): the largest t with ``feasible(t·direction)`` (to RAY_REL_TOL), None when the origin is
    infeasible. The feasible set of (20) in x0 is convex (a projection of a polyhedron), so along a ray from
    a feasible origin it is an interval [0, r]. ``capped``: still feasible at the search limit (r is then a
    lower bound)."""
    if not feasible(np.zeros_like(direction)):
        return None, False
    lo, hi = 0.0, start
    for _ in range(RAY_DOUBLINGS + 1):
        if not feasible(hi * direction):
            break
        lo, hi = hi, 2.0 * hi
    else:
        return lo, True
    while hi - lo > RAY_REL_TOL * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if feasible(mid * direction) else (lo, mid)
    return lo, False


def robust_beside(traj, progress=None, by_lp: bool | None = None) -> dict:
    """The robust baseline (``update="none"``: Θ_k ≡ Θ, θ̂_k ≡ θ̂0) run beside the recorded adaptive run
    ``traj``: the same problem, offline design, backend, formulation and other online options, the same
    x0 and θ*, and the *recorded* disturbance sequence w_0..w_{T−1}. Returns a JSON-ready dict:

    * ``adaptive``/``robust``: steps applied, stop reason, closed-loop cost Σ(‖x‖²_Q + ‖u‖²_R), mean
      one-step tube size s_k and its parametric part (:func:`one_step_tube`), ‖x_T‖, and per step s_k's
      parametric part and ‖x_k‖;
    * ``rays``: per direction, the feasible radius of the QP (20) at Θ (robust) and at the adaptive run's
      final Θ_T; Θ_T ⊆ Θ (Lemma 3) makes the adaptive radius at least the robust one. Whether (20) is
      feasible at a state is decided by the LP of :class:`~amcp_drake.certificate.feasible_region.TubeLP`
      (its slack >= −:data:`~amcp_drake.model.tolerances.PREMISE_LP_TOL`: the same feasible set, one HiGHS LP
      instead of a QP whose infeasible answers run the whole retry ladder) when the online options leave
      the feasible set of (20) as in (5) (θ* constant, no PE constraint), else by the QP itself
      (``ray_method`` names which; ``by_lp`` forces the choice). ``progress`` (optional) is called with a
      line of text before each ray.

    Not a claim of the paper and not part of the verdict: what adaptation bought on this run. A run that
    applied no input gives ``{"error": reason}``."""
    from dataclasses import replace

    problem, design = traj.problem, traj.design
    options = replace(traj.options, update="none")
    ctrl = AdaptiveMPC(problem, design, backend=traj.backend, options=options,
                       formulation=traj.meta.get("formulation", "plain"))
    T = len(traj.u)
    if T == 0:
        return {"error": f"the run applied no input ({traj.stop_reason}): there is no disturbance sequence to rerun"}
    theta_star = np.asarray(traj.theta_star, float)
    stop = None
    try:
        robust = simulate(ctrl, traj.x[0], theta_star, T, np.asarray(traj.w, float), seed=traj.meta.get("seed") or 0,
                          mu_state_bound=traj.mu_state_bound)
    except InconsistentDataError as exc:  # cannot happen with Θ_k ≡ Θ, but never hide it
        robust, stop = exc.trajectory, str(exc)

    def finite(value: float) -> float | None:  # NaN (Θ_k vertices not enumerable) is JSON null
        return float(value) if np.isfinite(value) else None

    def run_figures(t) -> dict:
        tube = tube_series(t, True)
        param = tube_series(t, False)
        return {"steps": len(t.u), "stop_reason": stop if t is robust and stop else t.stop_reason,
                "all_solved": bool(t.all_solved), "cost": closed_loop_cost(t),
                "mean_one_step_tube": finite(np.mean(tube)) if tube else None,
                "mean_parametric_tube": finite(np.mean(param)) if param else None,
                "final_state_norm": float(np.linalg.norm(t.x[-1])),
                "parametric_tube": [finite(v) for v in param], "state_norm": np.linalg.norm(t.x, axis=1).tolist()}

    last = traj.records[-1]
    h_T = np.asarray(last.h_theta, float)
    H_T = np.asarray(last.H_theta, float) if traj.options.update == "exact" else None

    if by_lp is None:
        by_lp = options.d_theta == 0 and options.pe_window is None

    def feasible_at(h, H):
        if by_lp:
            from amcp_drake.certificate.feasible_region import TubeLP
            from amcp_drake.model.tolerances import PREMISE_LP_TOL

            lp = TubeLP.build(problem, design, np.asarray(design.H_theta if H is None else H, float), h)
            return lambda x: bool(lp.margin(np.asarray(x, float)) >= -PREMISE_LP_TOL)  # nan (LP failed): infeasible
        h_arg = ctrl.stage_offsets(h) if options.d_theta > 0 else h

        def ok(x) -> bool:
            return ctrl.mpc.solve(np.asarray(x, float), h_arg, problem.theta_hat0, H).status is SolveStatus.OPTIMAL
        return ok

    start = max(float(np.linalg.norm(traj.x[0])), 1.0)
    rays = []
    directions = ray_directions(np.asarray(traj.x[0], float))
    for i, (name, d) in enumerate(directions, start=1):
        if progress is not None:
            progress(f"  ... robust baseline: feasible radius along {name} ({i}/{len(directions)})")
        r_rob, cap_rob = feasible_radius(feasible_at(np.asarray(design.h_theta0, float), None), d, start)
        r_ada, cap_ada = feasible_radius(feasible_at(h_T, H_T), d, start)
        rays.append({"direction": name, "unit": d.tolist(), "robust": r_rob, "robust_capped": cap_rob,
                     "adaptive": r_ada, "adaptive_capped": cap_ada})
    return {"update": "none", "disturbance": "the adaptive run's recorded w_0..w_(T-1)", "final_k": int(last.k),
            "adaptive": run_figures(traj), "robust": run_figures(robust), "rays": rays,
            "ray_rel_tol": RAY_REL_TOL, "ray_method": "LP (TubeLP)" if by_lp else "QP (20)"}
