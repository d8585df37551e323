"""The feasible region of the tube MPC QP (20) on a set of initial states (``amcp coverage``).

For every point x0 of a grid (or of a points file) and a parameter set Θ = {H_θ θ <= h_θ}, x0 is
*feasible* when 𝔻(x0, Θ) ≠ ∅, i.e. the first QP (20) of a closed loop started at x0 has a
solution. Each point is decided twice:

* by the **tube QP (20)** of the chosen backend (``controller.mpc.solve``; feasible means the
  status is OPTIMAL, infeasible means INFEASIBLE; any other status leaves the point undecided);
* by an **independent LP** written here with numpy/scipy (HiGHS), on the vertex form of the tube
  constraints *before* dualisation (proof of Proposition 9): for every prediction step l, every
  vertex x^j of X0 and every vertex θ^s of Θ,

      H_x (A_cl(θ^s)(z_l + α_l x^j) + B(θ^s) v_l − z_{l+1}) − α_{l+1} 1 <= −w̄        (5b)

  with (15a) (F + GK) z_l + G v_l + f̄ α_l <= 1, (15b) H_x (x0 − z_0) <= α_0 1, the terminal set
  H_T z_N + h_T α_N <= 1 and α >= 0. Since α_l >= 0, the rows of the vertices x^j are implied by
  the one whose coefficient [H_x A_cl(θ^s) x^j]_i of α_l is largest, so one row per (l, s, i) is
  written (its coefficient the row-wise maximum over the vertices of X0). w̄ and f̄ are recomputed from the vertices of W and X0 and the
  vertices of Θ are enumerated by the certificate's own routine, so neither a backend nor an
  offline constant of the design is trusted. The LP maximises a common slack t (t <= 1) of all rows
  scaled to unit norm: t >= 0 if and only if 𝔻(x0, Θ) ≠ ∅, and |t| measures the distance to the
  boundary.

A point where the two verdicts differ is a **disagreement** when |t| > :data:`AGREEMENT_TOL` and a
**borderline** point otherwise (both are counted and listed). With ``adapt_steps``, a closed loop
of that many steps is run from the problem's scenario and the region is evaluated again for the
learned Θ_T; since Θ_T ⊆ Θ (Lemma 3) every robustly feasible point must stay feasible, and a point
that does not is reported as a ``monotonicity`` violation.

**Slices** (n > 2, or any n): ``plane = (i, j)`` and ``fixed`` (n values) evaluate the grid over the two
states i, j with every other state held at its value in ``fixed`` (0 unless given): the region's
cross-section x_k = fixed_k for k ∉ {i, j}, drawn as a map in that plane (:func:`slice_points`).

**Cost before a grid runs**: each point costs one QP (20) and one LP per parameter set (two sets with
``adapt_steps``); :func:`grid_cost` counts them before anything is solved, and a run measures a short
probe (:data:`PROBE_POINTS` points, QP + LP each) to estimate its time before the grid starts.
``amcp coverage`` refuses more than :data:`DEFAULT_MAX_POINTS` points (exit 2, with the counts) unless
``--max-points`` or ``--yes`` raises the limit (never above :data:`MAX_POINTS`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

from amcp_drake.certificate.feasible_region import TubeLP
from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import Problem, ProblemSpec
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate

#: A QP verdict is confirmed when the LP slack t agrees in sign; within ±AGREEMENT_TOL of the
#: boundary the two solvers may legitimately differ (Clarabel's and HiGHS's feasibility
#: tolerances are ~1e-8 on rows of unit norm; the certificate's TUBE_TOL 1e-6 leaves room for the
#: QP's scaling), so such points are "borderline", listed but not counted as disagreements.
AGREEMENT_TOL = 1e-6
#: Default grid resolution per axis.
DEFAULT_GRID = 21
#: Largest number of grid points (grid**n) accepted (each point costs one QP and one LP).
MAX_POINTS = 250_000
#: Points ``amcp coverage`` evaluates without being asked (``--max-points`` or ``--yes`` for more): 21 per axis
#: in three dimensions (9 261) pass, a 21-point grid in four (194 481, hours of QPs) is refused.
DEFAULT_MAX_POINTS = 10_000
#: Points of the timed probe (QP + LP each) that estimates a grid's time before it runs.
PROBE_POINTS = 3

ROBUST, ADAPTIVE_ONLY, INFEASIBLE = "robust", "adaptive_only", "infeasible"


# -- the set of initial states ---------------------------------------------------------------------
def default_box(problem: Problem, state_bound: float | None = None) -> np.ndarray:
    """(n, 2) bounds lo/hi of x over the projection of Z onto the state space, one LP per side; a
    side where Z does not bound x is taken from ``state_bound`` (design.mu_state_bound), else a
    ProblemError asks for ``--box``."""
    n, m = problem.n, problem.m
    H = np.hstack([problem.F, problem.G])
    h = np.ones(len(H))
    box = np.zeros((n, 2))
    for i in range(n):
        for side, sign in ((1, 1.0), (0, -1.0)):
            d = np.zeros(n + m)
            d[i] = sign
            res = linprog(-d, A_ub=H, b_ub=h, bounds=[(None, None)] * (n + m), method="highs")
            if res.status == 0:
                box[i, side] = sign * float(-res.fun)
            elif res.status == 3 and state_bound is not None:
                box[i, side] = sign * float(state_bound)
            else:
                raise ProblemError("--box", f"bounds for x{i + 1} (Z does not bound it and the problem has no "
                                   "design.mu_state_bound)", "nothing", "Give --box LO:HI,LO:HI,... or --points FILE.")
    return box


def parse_box(text: str, n: int) -> np.ndarray:
    """'lo:hi,lo:hi,...' (one pair per state) as an (n, 2) array; ProblemError naming --box."""
    parts = [p for p in text.split(",")]
    if len(parts) != n:
        raise ProblemError("--box", f"{n} intervals LO:HI separated by commas (one per state)", repr(text))
    box = np.zeros((n, 2))
    for i, part in enumerate(parts):
        try:
            lo, hi = (float(v) for v in part.split(":"))
        except ValueError:
            raise ProblemError("--box", "intervals LO:HI with numbers", repr(part)) from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
            raise ProblemError("--box", "finite LO < HI in every interval", repr(part))
        box[i] = lo, hi
    return box


def grid_points(box: np.ndarray, grid: int) -> tuple[np.ndarray, list[np.ndarray]]:
    """All points of the tensor grid with ``grid`` values per axis (np.linspace over each interval);
    returns (points (grid**n, n), per-axis values). The first axis varies slowest."""
    box = np.asarray(box, float)
    n = box.shape[0]
    if isinstance(grid, bool) or not isinstance(grid, (int, np.integer)) or grid < 1:
        raise ProblemError("--grid", "an integer >= 1", repr(grid))
    if grid ** n > MAX_POINTS:
        raise ProblemError("--grid", f"at most {MAX_POINTS} points (grid**n with n = {n})", f"{grid}**{n} = {grid ** n}")
    axes = [np.linspace(lo, hi, grid) for lo, hi in box]
    mesh = np.meshgrid(*axes, indexing="ij")
    return np.column_stack([a.reshape(-1) for a in mesh]), axes


def slice_points(box: np.ndarray, grid: int, plane: tuple[int, int], fixed: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
    """The grid of a slice: ``grid`` values per axis over the two states of ``plane`` (``box``: their two
    intervals, (2, 2)), every other state at its value in ``fixed`` (n values). Returns (points (grid², n),
    the two axes); the first state of the plane varies slowest."""
    plane_points, axes = grid_points(np.asarray(box, float), grid)
    points = np.tile(np.asarray(fixed, float), (len(plane_points), 1))
    points[:, list(plane)] = plane_points
    return points, axes


def grid_cost(points: int, adapt_steps: int | None = None) -> dict:
    """What a coverage run solves: one QP (20) and one LP per point and parameter set (Θ, and Θ_T with
    ``adapt_steps``), plus the closed loop of ``adapt_steps`` steps that learns Θ_T."""
    sets = 2 if adapt_steps else 1
    return {"points": int(points), "parameter_sets": sets, "qps": int(points) * sets, "lps": int(points) * sets,
            "closed_loop_steps": int(adapt_steps or 0)}


def require_within_limit(cost: dict, limit: int, field: str, what: str) -> None:
    """ProblemError (exit 2) naming ``field`` with the counts of ``cost`` when it has more than ``limit`` points."""
    if cost["points"] <= limit:
        return
    raise ProblemError(field, f"at most {limit} points without a larger --max-points or --yes (at most {MAX_POINTS})",
                       f"{what} = {cost['points']} points: {cost['qps']} QPs (20) and {cost['lps']} LPs",
                       "Pass --max-points N or --yes to run it, or use a slice of two states: --plane I,J "
                       "[--fix NAME=VALUE,...].")


def load_points(path: str | Path, n: int, grid: int) -> tuple[np.ndarray, str]:
    """A points file: JSON ``{"points": [[x1, ..., xn], ...]}`` (the points themselves) or
    ``{"polytope": {"H": [[..]], "h": [..]}}`` (the grid points of its bounding box that lie in
    {H x <= h}). Returns (points, description); ProblemError naming the field otherwise."""
    from amcp_drake.model.errors import ProblemFileError
    from amcp_drake.model.json_strict import load_json_strict

    path = Path(path)
    try:  # strict JSON, at most MAX_INPUT_BYTES, binary data refused before the rest is read
        data = load_json_strict(path, ProblemFileError, "points file")
    except ProblemFileError as exc:
        field = "--points" if exc.field == "file" else f"--points: {exc.field}"
        raise ProblemError(field, exc.expected, exc.received) from None
    if not isinstance(data, dict) or len({"points", "polytope"} & set(data)) != 1:
        raise ProblemError("--points", "a JSON object with exactly one of the keys 'points', 'polytope'",
                           f"{type(data).__name__} with keys {sorted(data) if isinstance(data, dict) else []}")
    if "points" in data:
        try:
            pts = np.array(data["points"], dtype=float)
        except (TypeError, ValueError):
            raise ProblemError("--points: points", f"a list of lists of {n} numbers", "ragged or non-numeric data") from None
        if pts.ndim != 2 or pts.shape[1] != n or len(pts) == 0 or not np.all(np.isfinite(pts)):
            raise ProblemError("--points: points", f"a non-empty list of finite points with {n} coordinates",
                               f"an array of shape {pts.shape}")
        if len(pts) > MAX_POINTS:
            raise ProblemError("--points: points", f"at most {MAX_POINTS} points", str(len(pts)))
        return pts, f"{len(pts)} points from {path}"
    poly = data["polytope"]
    try:
        H = np.array(poly["H"], dtype=float)
        h = np.array(poly["h"], dtype=float)
    except (TypeError, KeyError, ValueError):
        raise ProblemError("--points: polytope", "an object with numeric 'H' (rows of n numbers) and 'h'",
                           repr(poly)[:80]) from None
    if H.ndim != 2 or H.shape[1] != n or h.shape != (H.shape[0],) or not (np.all(np.isfinite(H)) and np.all(np.isfinite(h))):
        raise ProblemError("--points: polytope", f"H of shape (q, {n}) and h of shape (q,), finite",
                           f"H {H.shape}, h {h.shape}")
    if not polytope.is_bounded(H, h):
        raise ProblemError("--points: polytope", "a bounded polytope {H x <= h}", "an unbounded or empty set")
    lo = np.array([polytope.support(H, h, -e).value for e in np.eye(n)]) * -1.0
    hi = np.array([polytope.support(H, h, e).value for e in np.eye(n)])
    pts, _ = grid_points(np.column_stack([lo, hi]), grid)
    inside = np.all(pts @ H.T <= h + 1e-12, axis=1)
    if not np.any(inside):
        raise ProblemError("--points: polytope", "a polytope containing at least one grid point", "none inside")
    return pts[inside], f"{int(inside.sum())} grid points ({grid} per axis) in the polytope of {path}"


# -- one region -------------------------------------------------------------------------------------
@dataclass
class PointVerdict:
    """One x0 for one Θ: the QP's status, the LP slack t, and the verdicts."""

    qp_status: str
    lp_margin: float

    @property
    def qp_feasible(self) -> bool | None:
        """True/False when the QP decided (OPTIMAL/INFEASIBLE), None otherwise."""
        if self.qp_status == SolveStatus.OPTIMAL.value:
            return True
        if self.qp_status == SolveStatus.INFEASIBLE.value:
            return False
        return None

    @property
    def lp_feasible(self) -> bool | None:
        return None if not np.isfinite(self.lp_margin) else bool(self.lp_margin >= 0.0)

    @property
    def feasible(self) -> bool:
        """The point's verdict: the QP's when it decided, else the LP's (flagged as undecided)."""
        qp = self.qp_feasible
        return bool(qp) if qp is not None else bool(self.lp_feasible)

    @property
    def kind(self) -> str:
        """'agree', 'borderline' (differ within AGREEMENT_TOL), 'disagree', 'qp_undecided', 'lp_failed'."""
        if not np.isfinite(self.lp_margin):
            return "lp_failed"
        qp = self.qp_feasible
        if qp is None:
            return "qp_undecided"
        if qp == self.lp_feasible:
            return "agree"
        return "borderline" if abs(self.lp_margin) <= AGREEMENT_TOL else "disagree"


def qp_status(controller: AdaptiveMPC, x0: np.ndarray, H_theta, h_theta, exact: bool) -> str:
    """Status of the first QP (20) at x0 for Θ = {H_θ θ <= h_θ} (θ̂0 in the cost; it does not
    affect feasibility)."""
    sol = controller.mpc.solve(np.asarray(x0, float), np.asarray(h_theta, float), controller.problem.theta_hat0,
                               np.asarray(H_theta, float) if exact else None)
    return sol.status.value


def evaluate_region(controller: AdaptiveMPC, points: np.ndarray, H_theta, h_theta, exact: bool = False,
                    progress=None, lp: TubeLP | None = None) -> list[PointVerdict]:
    """QP and LP verdicts at every point for one Θ (``exact``: pass H_θ to the QP, for update "exact").
    ``progress``: an object with ``update(1)`` (called per point) and optionally ``close()`` (a tqdm bar);
    ``lp``: the LP of this Θ when already built."""
    if lp is None:
        lp = TubeLP.build(controller.problem, controller.design, np.asarray(H_theta, float), np.asarray(h_theta, float))
    out = []
    for x0 in points:
        out.append(PointVerdict(qp_status(controller, x0, H_theta, h_theta, exact), lp.margin(x0)))
        if progress is not None:
            progress.update(1)
    if progress is not None and hasattr(progress, "close"):
        progress.close()
    return out


# -- the study -------------------------------------------------------------------------------------
@dataclass
class CoverageResult:
    """Everything ``amcp coverage`` reports; :meth:`to_dict` is the JSON file."""

    problem: str
    n: int
    points: np.ndarray
    source: str
    axes: list | None
    backend: str
    formulation: str
    robust: list[PointVerdict]
    adaptive: list[PointVerdict] | None = None
    adapt_info: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    design_info: dict = field(default_factory=dict)
    #: labels of the n states (``name [unit]``; ``x1 … xn`` when unnamed), for the plot's axes
    labels: list[str] = field(default_factory=list)
    #: a slice: the two states (0-based) of the grid, and the values of all n states (the plane's are 0)
    plane: tuple[int, int] | None = None
    fixed: np.ndarray | None = None
    #: grid_cost of the run and the probe's measured time (``estimate_s``: the estimated time of the grid)
    estimate: dict = field(default_factory=dict)

    def label(self, i: int) -> str:
        return self.labels[i] if self.labels else f"x{i + 1}"

    def _fraction(self, verdicts) -> float:
        return float(np.mean([v.feasible for v in verdicts]))

    def classes(self) -> list[str]:
        """Per point: 'robust', 'adaptive_only' or 'infeasible' (QP verdicts)."""
        out = []
        for i, r in enumerate(self.robust):
            if r.feasible:
                out.append(ROBUST)
            elif self.adaptive is not None and self.adaptive[i].feasible:
                out.append(ADAPTIVE_ONLY)
            else:
                out.append(INFEASIBLE)
        return out

    def issues(self) -> dict[str, list[dict]]:
        """Points to report: disagreements, borderline points, undecided QPs, failed LPs, and
        monotonicity violations (feasible for Θ, infeasible for Θ_T ⊆ Θ)."""
        rows: dict[str, list[dict]] = {"disagree": [], "borderline": [], "qp_undecided": [], "lp_failed": [],
                                       "monotonicity": []}
        for label, verdicts in (("robust", self.robust), ("adaptive", self.adaptive or [])):
            for i, v in enumerate(verdicts):
                if v.kind != "agree":
                    rows[v.kind].append({"index": i, "x0": self.points[i].tolist(), "theta_set": label,
                                         "qp_status": v.qp_status, "lp_margin": _finite(v.lp_margin)})
        if self.adaptive is not None:
            for i, (r, a) in enumerate(zip(self.robust, self.adaptive)):
                if r.feasible and not a.feasible:
                    rows["monotonicity"].append({"index": i, "x0": self.points[i].tolist(),
                                                 "robust_lp_margin": _finite(r.lp_margin),
                                                 "adaptive_lp_margin": _finite(a.lp_margin)})
        return rows

    @property
    def passed(self) -> bool:
        """No disagreement, no undecided QP, no failed LP, no monotonicity violation."""
        issues = self.issues()
        return not any(issues[k] for k in ("disagree", "qp_undecided", "lp_failed", "monotonicity"))

    def summary(self) -> dict:
        out = {"points": len(self.points), "robust_fraction": self._fraction(self.robust)}
        if self.adaptive is not None:
            out["adaptive_fraction"] = self._fraction(self.adaptive)
            out["adaptive_only_fraction"] = float(np.mean([c == ADAPTIVE_ONLY for c in self.classes()]))
        issues = self.issues()
        out.update({f"{k}_count": len(v) for k, v in issues.items()})
        out["passed"] = self.passed
        return out

    def to_dict(self) -> dict:
        return {
            "problem": self.problem, "n": self.n, "source": self.source, "backend": self.backend,
            "formulation": self.formulation, "agreement_tol": AGREEMENT_TOL,
            "summary": self.summary(), "adapt": self.adapt_info, "timings": self.timings, "design": self.design_info,
            "issues": self.issues(),
            "estimate": self.estimate,
            "slice": None if self.plane is None else {
                "plane": [self.label(i) for i in self.plane], "plane_index": [i + 1 for i in self.plane],
                "fixed": {self.label(i): float(self.fixed[i]) for i in range(self.n) if i not in self.plane}},
            "points": self.points.tolist(), "axes": None if self.axes is None else [a.tolist() for a in self.axes],
            "classes": self.classes(),
            "robust": [{"qp_status": v.qp_status, "lp_margin": _finite(v.lp_margin)} for v in self.robust],
            "adaptive": None if self.adaptive is None else
            [{"qp_status": v.qp_status, "lp_margin": _finite(v.lp_margin)} for v in self.adaptive],
        }


def _finite(value: float):
    return float(value) if np.isfinite(value) else None


def learned_set(spec: ProblemSpec, design: OfflineDesign, steps: int, backend: str, formulation: str,
                options: OnlineOptions, x0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, dict]:
    """Θ_T after a closed loop of ``steps`` steps on the problem's scenario (x0 — or the given
    ``x0`` — θ*, disturbance, seed). A run that stops early gives the set of its last step
    (``steps_run`` < ``steps`` in the dict)."""
    sc = spec.scenario
    if sc is None:
        raise ProblemError("scenario", "a scenario in the problem file (x0, theta_star) for --adapt", "none")
    if x0 is None:
        x0 = sc.x0
    else:
        x0 = np.asarray(x0, float)
        if x0.shape != (spec.problem.n,) or not np.all(np.isfinite(x0)):
            raise ProblemError("--adapt-x0", f"{spec.problem.n} finite numbers", repr(x0.tolist()))
    ctrl = AdaptiveMPC(spec.problem, design, backend=backend, options=options, formulation=formulation)
    traj = simulate(ctrl, x0, sc.theta_star_for(steps), steps, sc.disturbance, seed=sc.seed)
    last = traj.records[-1]
    info = {"steps": steps, "steps_run": len(traj.u), "stop_reason": traj.stop_reason, "update": options.update,
            "x0": np.asarray(x0).tolist(), "theta_star": np.asarray(sc.theta_star).tolist(),
            "disturbance": sc.disturbance, "seed": sc.seed,
            "H_theta": np.asarray(last.H_theta).tolist(), "h_theta": np.asarray(last.h_theta).tolist(),
            "h_theta0": np.asarray(design.h_theta0).tolist()}
    return np.asarray(last.H_theta, float), np.asarray(last.h_theta, float), info


def run_coverage(spec: ProblemSpec, design: OfflineDesign, points: np.ndarray, source: str = "points",
                 axes: list | None = None, adapt_steps: int | None = None, backend: str = "drake",
                 formulation: str = "vertex", options: OnlineOptions | None = None, adapt_x0=None,
                 progress_factory: Callable[[int, str], object] | None = None, plane: tuple[int, int] | None = None,
                 fixed=None, on_estimate: Callable[[dict], None] | None = None) -> CoverageResult:
    """The region for Θ (and for the learned Θ_T when ``adapt_steps``); see the module docstring.

    ``progress_factory(total, label)`` returns a progress object for :func:`evaluate_region` (e.g. a
    tqdm bar); ``adapt_x0``: initial state of the adaptive run instead of the scenario's; ``options``: the
    online options of the adaptive run (default: the file's, else fixed); ``plane``, ``fixed``: the slice
    the points lie on (recorded and drawn); ``on_estimate(estimate)`` is called after the timed probe of
    :data:`PROBE_POINTS` points, before the grid runs (``estimate``: :func:`grid_cost` with the probe's
    seconds per point and ``estimate_s``, the estimated time of all QPs and LPs)."""
    options = options or spec.online or OnlineOptions()
    if options.d_theta > 0:
        raise ProblemError("online.d_theta", "0 for amcp coverage (the region is evaluated for one constant "
                           "parameter set)", str(options.d_theta))
    points = np.asarray(points, float)
    pr = spec.problem
    exact = options.update == "exact"
    ctrl = AdaptiveMPC(pr, design, backend=backend, options=OnlineOptions(update="none"), formulation=formulation)
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    lp = TubeLP.build(pr, design, np.asarray(design.H_theta, float), np.asarray(design.h_theta0, float))
    estimate = probe(ctrl, lp, points, design, grid_cost(len(points), adapt_steps))
    if on_estimate is not None:
        on_estimate(estimate)
    t_wall, t_cpu = time.perf_counter(), time.process_time()  # the region itself (the probe is in the estimate)
    bar = progress_factory(len(points), "robust Θ") if progress_factory else None
    robust = evaluate_region(ctrl, points, design.H_theta, design.h_theta0, False, bar, lp=lp)
    timings = {"robust_wall_s": time.perf_counter() - t_wall, "robust_cpu_s": time.process_time() - t_cpu}
    result = CoverageResult(problem=pr.name, n=pr.n, points=points, source=source, axes=axes, backend=backend,
                            formulation=formulation, robust=robust, timings=timings,
                            design_info={"x0_facets": len(design.H_x), "lambda_bar": float(design.lambda_bar),
                                         "x0_template": (design.info or {}).get("x0_template"),
                                         "terminal_rows": len(design.H_T)},
                            labels=[pr.state_label(i) for i in range(pr.n)], plane=plane,
                            fixed=None if fixed is None else np.asarray(fixed, float), estimate=estimate)
    if adapt_steps:
        t_wall, t_cpu = time.perf_counter(), time.process_time()
        H_T, h_T, info = learned_set(spec, design, adapt_steps, backend, formulation, options, adapt_x0)
        timings.update({"adapt_run_wall_s": time.perf_counter() - t_wall, "adapt_run_cpu_s": time.process_time() - t_cpu})
        t_wall, t_cpu = time.perf_counter(), time.process_time()
        bar = progress_factory(len(points), f"Θ_{info['steps_run']}") if progress_factory else None
        result.adaptive = evaluate_region(ctrl, points, H_T, h_T, exact, bar)
        result.adapt_info = info
        timings.update({"adaptive_wall_s": time.perf_counter() - t_wall, "adaptive_cpu_s": time.process_time() - t_cpu})
    return result


def probe(ctrl: AdaptiveMPC, lp: TubeLP, points: np.ndarray, design: OfflineDesign, cost: dict) -> dict:
    """``cost`` with the measured wall time per point (QP + LP at up to :data:`PROBE_POINTS` points spread over
    the grid, robust Θ) and ``estimate_s`` = that time × QPs (the closed loop of ``--adapt`` not included)."""
    picks = sorted({int(round(i)) for i in np.linspace(0, len(points) - 1, min(PROBE_POINTS, len(points)))})
    start = time.perf_counter()
    evaluate_region(ctrl, points[picks], design.H_theta, design.h_theta0, False, lp=lp)
    per_point = (time.perf_counter() - start) / max(len(picks), 1)
    return {**cost, "probe_points": len(picks), "probe_s_per_point": per_point, "estimate_s": per_point * cost["qps"]}


# -- outputs ---------------------------------------------------------------------------------------
COLOURS = {ROBUST: "#2b8a3e", ADAPTIVE_ONLY: "#f59f00", INFEASIBLE: "#ced4da"}
LABELS = {ROBUST: "feasible robustly (Θ)", ADAPTIVE_ONLY: "feasible only after adaptation (Θ_T)",
          INFEASIBLE: "infeasible"}


def draw_region(result: CoverageResult, ax=None):
    """A matplotlib Figure of the region (object API, no pyplot): a map of the points in the plane of a slice
    (any n) or for n = 2, a strip for n = 1; None for n >= 3 without a slice. Axes carry the states' names
    and units. Disagreements are marked with a black ×. Drawn into ``ax`` when given (its Figure is
    returned), as the functions of ``amcp.plots``."""
    if result.n > 2 and result.plane is None:
        return None
    from matplotlib.figure import Figure

    classes = np.array(result.classes())
    plane = result.plane or ((0, 1) if result.n == 2 else None)
    pts = result.points[:, list(plane)] if plane else np.column_stack([result.points[:, 0], np.zeros(len(result.points))])
    if ax is None:
        fig = Figure(figsize=(6.4, 5.2) if plane else (6.4, 2.2), layout="constrained")
        ax = fig.add_subplot(1, 1, 1)
    else:
        fig = ax.figure
    size = max(4.0, min(60.0, 9000.0 / max(len(pts), 1)))
    for kind in (INFEASIBLE, ADAPTIVE_ONLY, ROBUST):
        sel = classes == kind
        if np.any(sel):
            ax.scatter(pts[sel, 0], pts[sel, 1], s=size, marker="s", c=COLOURS[kind], label=f"{LABELS[kind]}: "
                       f"{sel.sum()}/{len(sel)}", linewidths=0)
    bad = [row["index"] for row in result.issues()["disagree"]]
    if bad:
        ax.scatter(pts[bad, 0], pts[bad, 1], s=size, marker="x", c="black", label=f"QP/LP disagreement: {len(bad)}")
    ax.set_xlabel(result.label(plane[0] if plane else 0))
    if plane:
        ax.set_ylabel(result.label(plane[1]))
    else:
        ax.set_yticks([])
    title = f"{result.problem}: feasible set of QP (20), robust {result.summary()['robust_fraction']:.2f}"
    if result.adaptive is not None:
        title += f", after {result.adapt_info.get('steps_run')} steps {result.summary()['adaptive_fraction']:.2f}"
    if result.plane is not None and result.n > 2:
        title += "\nslice at " + ", ".join(f"{result.label(i)} = {result.fixed[i]:g}" for i in range(result.n)
                                           if i not in result.plane)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14 if plane else -0.35), ncol=2,
              frameon=False)
    return fig


def write_coverage(result: CoverageResult, out_dir: str | Path) -> tuple[Path, Path | None]:
    """coverage.json and (n <= 2, or a slice) coverage.png in ``out_dir``, each written atomically."""
    import os
    import tempfile

    from amcp_drake.model.problem_io import write_json_atomic

    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise ProblemError("--out", "a directory (new or existing)", f"{out_dir} is a file")
    out_dir.mkdir(parents=True, exist_ok=True)
    png = None
    fig = draw_region(result)
    if fig is not None:
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        FigureCanvasAgg(fig)
        png = out_dir / "coverage.png"
        fd, tmp = tempfile.mkstemp(dir=out_dir, prefix=".coverage.", suffix=".png")
        os.close(fd)
        try:
            fig.savefig(tmp, dpi=110, format="png")
            os.chmod(tmp, 0o644)
            os.replace(tmp, png)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
    js = write_json_atomic(result.to_dict(), out_dir / "coverage.json")
    return js, png
