"""Performance harness (issue 8): per-step times of the online loop, both backends, both
formulations of the tube MPC QP (20), on Example 1 and on size sweeps.

What is measured. One closed-loop step of :class:`~amcp_drake.online.controller.AdaptiveMPC` (k >= 1) is
split as the controller records it (``StepRecord.times``):

* ``set_update``: the whole set-membership update (9) (building and solving the LP, Δ_k);
  ``set_update_solver`` is the LP solver's own time;
* ``lms``: the projected LMS update (12) (a projection QP only when θ̃ leaves the set);
* ``qp_update``: setting the data of QP (20) for the step (vertex form: Θ_k's vertices too);
* ``solver``: the QP solver call (Drake: wall time of ``Solve``; cvxpy: the solver's own time);
* ``total``: the whole step, measured around ``AdaptiveMPC.step``.

Medians and 90th percentiles are over the steps k = 1..steps (step 0 has no update). All
configurations of one comparison run in lockstep (step k of every configuration, then step k+1):
on a shared, noisy machine every configuration sees the same noise, so the ratios of one run are
meaningful even when the absolute times drift. Python's garbage collector is off inside the timed
loops (as ``timeit`` does). The closed loops are independent (each applies its own input), so the
runs also report how far the formulations' inputs drift apart (``max_abs_dv_vs_plain``).

Reference lines: the paper reports a median solver time of 68 ms for Example 1 (Yalmip, Intel
Core i7 3.4 GHz; 50 ms min, 95 ms max), spec §9.

Output: :func:`run_benchmarks` returns a JSON-ready dict (format ``amcp-bench`` version 1, keys
documented in benchmarks/README.md); :func:`write_outputs` writes it and a PNG (matplotlib Agg).
"""

from __future__ import annotations

import gc
import json
import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

BENCH_FORMAT = "amcp-bench"
BENCH_VERSION = 1
#: Spec §9: "Median solver time reported by Yalmip: 0.068 s (0.10 s with the PE constraint);
#: maximum 0.095 s; minimum 0.05 s; Intel Core i7, 3.4 GHz".
PAPER_MS = {"median_solver": 68.0, "max_solver": 95.0, "min_solver": 50.0}
#: Issue 8: a full step on Example 1 with an 8-facet X0 at a median of at most 7 ms (Drake backend),
#: the cvxpy backend within 2x of it.
TARGET_MS = 7.0
TARGET_CVXPY_RATIO = 2.0
#: Per-step time keys: name in the output -> key of ``StepRecord.times``.
TIME_KEYS = {
    "set_update": "set_update_total",
    "set_update_solver": "set_update",
    "lms": "lms_total",
    "qp_update": "qp_update",
    "solver": "solver",
    "total": "total",
}
#: The extra parameter of the p = 4 sweep point (the first three are Example 1's).
A4 = np.array([[0.02, 0.0], [0.01, 0.02]])
B4 = np.array([[0.02], [0.0]])
THETA_STAR_4 = np.array([0.8, 0.2, -0.5, 0.3])


@dataclass(frozen=True)
class BenchSettings:
    """What to run. ``quick`` shortens everything (CI, tests); explicit lists override."""

    steps: int = 50
    scaling_steps: int = 10
    seed: int = 0
    only: str | None = None                      # None, "example", "scaling" or "section4"
    backends: tuple[str, ...] = ("drake", "cvxpy")
    formulations: tuple[str, ...] = ("plain", "vertex")
    example_facets: tuple[int, ...] = (4, 8)
    sweep_N: tuple[int, ...] = (5, 10, 20, 40)
    sweep_p: tuple[int, ...] = (1, 2, 3, 4)
    sweep_facets: tuple[int, ...] = (4, 6, 8, 12, 16)
    quick: bool = False

    @classmethod
    def quick_settings(cls, **changes: Any) -> BenchSettings:
        base = cls(steps=10, scaling_steps=3, sweep_N=(5, 20), sweep_p=(1, 3), sweep_facets=(4, 8), quick=True)
        return replace(base, **changes)


@dataclass
class RunResult:
    """One configuration's closed-loop run: per-step times (s) and the inputs v_0 it applied."""

    backend: str
    formulation: str
    build_s: float
    times: dict[str, list[float]] = field(default_factory=dict)
    v: list[np.ndarray | None] = field(default_factory=list)
    status: str = "completed"

    @property
    def label(self) -> str:
        return f"{self.backend}/{self.formulation}"


# -- running -----------------------------------------------------------------------------------

def lockstep(problem, design, configs: list[tuple[str, str]], x0, theta_star, steps: int, seed: int) -> list[RunResult]:
    """Run the closed loop of every (backend, formulation) in ``configs`` for ``steps`` + 1 steps,
    interleaved step by step, with the same disturbance sequence (uniform on W, ``seed``)."""
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence

    w = disturbance_sequence(problem, "uniform", steps + 1, seed=seed)
    theta_star = np.asarray(theta_star, float)
    runs, ctrls, states = [], [], []
    for backend, formulation in configs:
        start = time.perf_counter()
        ctrl = AdaptiveMPC(problem, design, backend=backend, formulation=formulation)
        runs.append(RunResult(backend, formulation, time.perf_counter() - start,
                              {name: [] for name in TIME_KEYS}))
        ctrls.append(ctrl)
        states.append(np.asarray(x0, float))
    active = [True] * len(runs)
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        for k in range(steps + 1):
            for c, (run, ctrl) in enumerate(zip(runs, ctrls)):
                if not active[c]:
                    continue
                try:
                    u, rec = ctrl.step(states[c])
                except AmcpError as exc:
                    run.status, active[c] = f"error at k={k}: {exc}", False
                    continue
                run.v.append(None if rec.v is None else np.asarray(rec.v, float))
                if u is None:
                    run.status, active[c] = f"{rec.status.value} at k={k}", False
                    continue
                if k >= 1:  # full steps only: update + LMS + QP
                    for name, key in TIME_KEYS.items():
                        run.times[name].append(float(rec.times.get(key, 0.0)))
                states[c] = problem.step(states[c], u, theta_star, w[k])
    finally:
        if was_enabled:
            gc.enable()
    return runs


def _stats(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {"median": None, "p90": None, "mean": None, "max": None, "n": 0}
    ms = 1e3 * np.asarray(values, float)
    return {"median": float(np.median(ms)), "p90": float(np.percentile(ms, 90)), "mean": float(np.mean(ms)),
            "max": float(np.max(ms)), "n": int(len(ms))}


def _max_dv(a: RunResult, b: RunResult) -> float | None:
    diffs = [float(np.max(np.abs(va - vb))) for va, vb in zip(a.v, b.v) if va is not None and vb is not None]
    return max(diffs) if diffs else None


def _summaries(runs: list[RunResult], extra: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for run in runs:
        plain = next((r for r in runs if r.backend == run.backend and r.formulation == "plain"), None)
        row = dict(extra)
        row.update({"backend": run.backend, "formulation": run.formulation, "status": run.status,
                    "build_s": run.build_s, "times_ms": {name: _stats(vals) for name, vals in run.times.items()},
                    "max_abs_dv_vs_plain": _max_dv(run, plain) if plain is not None and plain is not run else None})
        out.append(row)
    return out


def _configs(settings: BenchSettings) -> list[tuple[str, str]]:
    return [(b, f) for b in settings.backends for f in settings.formulations]


def _design_or_reason(problem, options):
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.offline.design import design

    try:
        return design(problem, options, backend="drake"), None
    except AmcpError as exc:
        return None, f"design failed: {exc}"


def example_benchmark(settings: BenchSettings, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Example 1 (spec §9) with X0 of each facet count, every backend and formulation."""
    from amcp_drake.model.examples import lorenzen2019_spec

    spec = lorenzen2019_spec()
    sc = spec.scenario
    runs_out: list[dict[str, Any]] = []
    for facets in settings.example_facets:
        progress(f"example: X0 with {facets} facets, {settings.steps} steps")
        d, reason = _design_or_reason(spec.problem, replace(spec.design, x0_facets=facets))
        if d is None:
            runs_out.append({"x0_facets": facets, "status": reason})
            continue
        runs = lockstep(spec.problem, d, _configs(settings), sc.x0, sc.theta_star, settings.steps, settings.seed)
        runs_out.extend(_summaries(runs, {"x0_facets": facets, "x0_vertices": int(len(d.X0_vertices)),
                                          "steps": settings.steps}))
    return {"problem": "lorenzen2019", "x0": np.asarray(sc.x0).tolist(), "theta_star": np.asarray(sc.theta_star).tolist(),
            "runs": runs_out, "ratios": _ratios(runs_out)}


def _median(row: dict[str, Any], key: str) -> float | None:
    return (row.get("times_ms") or {}).get(key, {}).get("median")


def _ratio(a: float | None, b: float | None) -> float | None:
    return float(a / b) if a is not None and b not in (None, 0.0) else None


def _ratios(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Speed-up of the vertex form over the plain form (same backend, same X0) and cvxpy/Drake
    (same formulation), from the medians of one lockstep run."""
    out = []
    index = {(r.get("x0_facets"), r.get("backend"), r.get("formulation")): r for r in rows if "times_ms" in r}
    facets = sorted({key[0] for key in index})
    for f in facets:
        for backend in ("drake", "cvxpy"):
            plain, vertex = index.get((f, backend, "plain")), index.get((f, backend, "vertex"))
            if plain and vertex:
                out.append({"x0_facets": f, "kind": "plain/vertex", "backend": backend,
                            "total": _ratio(_median(plain, "total"), _median(vertex, "total")),
                            "solver": _ratio(_median(plain, "solver"), _median(vertex, "solver"))})
        for formulation in ("plain", "vertex"):
            drake, cvx = index.get((f, "drake", formulation)), index.get((f, "cvxpy", formulation))
            if drake and cvx:
                out.append({"x0_facets": f, "kind": "cvxpy/drake", "formulation": formulation,
                            "total": _ratio(_median(cvx, "total"), _median(drake, "total")),
                            "solver": _ratio(_median(cvx, "solver"), _median(drake, "solver"))})
    return out


def problem_with_p(problem, p: int):
    """Example 1 with its first p parameters (p = 4 adds A_4 = A4, B_4 = B4); Θ = [-1, 1]^p."""
    A = np.concatenate([problem.A, A4[None]])[:p]
    B = np.concatenate([problem.B, B4[None]])[:p]
    return problem.with_changes(A=A, B=B, H_theta=np.vstack([np.eye(p), -np.eye(p)]), h_theta=np.ones(2 * p),
                                theta_hat0=np.zeros(p))


def scaling_benchmark(settings: BenchSettings, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Sweeps around Example 1 (8-facet X0, N = 10, p = 3): horizon N, parameter count p, facets of X0."""
    from amcp_drake.model.examples import lorenzen2019_spec

    spec = lorenzen2019_spec()
    sc = spec.scenario
    base = spec.problem
    points: dict[str, list[tuple[int, Any, Any, np.ndarray]]] = {
        "N": [(N, base.with_changes(N=N), spec.design, sc.theta_star) for N in settings.sweep_N],
        "p": [(p, problem_with_p(base, p), spec.design, THETA_STAR_4[:p]) for p in settings.sweep_p],
        "x0_facets": [(f, base, replace(spec.design, x0_facets=f), sc.theta_star) for f in settings.sweep_facets],
    }
    out: dict[str, list[dict[str, Any]]] = {}
    for axis, items in points.items():
        rows: list[dict[str, Any]] = []
        for value, problem, options, theta_star in items:
            progress(f"scaling: {axis} = {value}, {settings.scaling_steps} steps")
            d, reason = _design_or_reason(problem, options)
            if d is None:
                rows.append({axis: value, "status": reason})
                continue
            runs = lockstep(problem, d, _configs(settings), sc.x0, theta_star, settings.scaling_steps, settings.seed)
            rows.extend(_summaries(runs, {axis: value, "N": problem.N, "p": problem.p,
                                          "x0_facets": int(len(d.H_x)), "steps": settings.scaling_steps}))
        out[axis] = rows
    return out


def _target(example: dict[str, Any] | None) -> dict[str, Any]:
    rows = {(r.get("x0_facets"), r.get("backend"), r.get("formulation")): r
            for r in (example or {}).get("runs", []) if "times_ms" in r}
    drake = rows.get((8, "drake", "vertex"))
    cvx = rows.get((8, "cvxpy", "vertex"))
    drake_ms = _median(drake, "total") if drake else None
    cvx_ms = _median(cvx, "total") if cvx else None
    ratio = _ratio(cvx_ms, drake_ms)
    return {"what": "median full step (update + LMS + QP), Example 1, 8-facet X0, vertex form",
            "target_ms": TARGET_MS, "drake_ms": drake_ms,
            "met": None if drake_ms is None else bool(drake_ms <= TARGET_MS),
            "cvxpy_ms": cvx_ms, "cvxpy_over_drake": ratio, "cvxpy_target_ratio": TARGET_CVXPY_RATIO,
            "cvxpy_met": None if ratio is None else bool(ratio <= TARGET_CVXPY_RATIO)}


def machine_info() -> dict[str, Any]:
    import os
    from importlib import metadata

    versions = {}
    for pkg in ("drake", "cvxpy", "clarabel", "numpy", "scipy"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "versions": versions}


def run_benchmarks(settings: BenchSettings | None = None,
                   progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Run the selected benchmarks; return the JSON-ready result (format ``amcp-bench``)."""
    settings = settings or BenchSettings()
    if settings.only not in (None, "example", "scaling", "section4"):
        raise ValueError(f"only: expected None, 'example', 'scaling' or 'section4', got {settings.only!r}")
    started = time.perf_counter()
    example = example_benchmark(settings, progress) if settings.only in (None, "example") else None
    scaling = scaling_benchmark(settings, progress) if settings.only in (None, "scaling") else None
    section4 = None
    if settings.only in (None, "section4"):
        from amcp_drake.studies.bench_section4 import section4_benchmark

        section4 = section4_benchmark(settings.steps, settings.seed, settings.backends, progress)
    settings_dict = asdict(settings)
    settings_dict["gc_disabled_in_timed_loops"] = True
    return {
        "format": BENCH_FORMAT, "version": BENCH_VERSION,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "machine": machine_info(), "settings": settings_dict,
        "time_keys": {name: f"StepRecord.times[{key!r}]" for name, key in TIME_KEYS.items()},
        "reference_ms": {"paper": PAPER_MS, "target_drake_full_step": TARGET_MS},
        "example": example, "scaling": scaling, "section4": section4, "target": _target(example),
        "elapsed_s": time.perf_counter() - started,
    }


# -- output ------------------------------------------------------------------------------------

def _clean(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, NaN/inf to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _clean(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        value = float(obj)
        return value if np.isfinite(value) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def write_outputs(result: dict[str, Any], out_dir: str | Path, plot: bool = True) -> dict[str, Path]:
    """Write ``bench.json`` (and ``bench.png`` when ``plot``) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": out_dir / "bench.json"}
    paths["json"].write_text(json.dumps(_clean(result), indent=1, allow_nan=False) + "\n")
    if plot:
        paths["png"] = out_dir / "bench.png"
        plot_results(result, paths["png"])
    return paths


_COMPONENTS = ("set_update", "lms", "qp_update", "solver")
_STYLE = {("drake", "plain"): ("tab:blue", "o"), ("drake", "vertex"): ("tab:green", "s"),
          ("cvxpy", "plain"): ("tab:orange", "^"), ("cvxpy", "vertex"): ("tab:red", "D")}


def plot_results(result: dict[str, Any], path: str | Path) -> None:
    """Four panels: Example 1 stacked per-step medians, then total (solid) and solver-only
    (dashed) medians against N, p and the facet count of X0; the paper's 68 ms and the 7 ms target."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(13, 9))
    ax = axes[0, 0]
    rows = [r for r in ((result.get("example") or {}).get("runs") or []) if "times_ms" in r]
    if rows:
        labels, bottoms = [], np.zeros(len(rows))
        x = np.arange(len(rows))
        colors = {"set_update": "tab:purple", "lms": "tab:gray", "qp_update": "tab:cyan", "solver": "tab:olive"}
        for comp in _COMPONENTS:
            vals = np.array([(r["times_ms"][comp]["median"] or 0.0) for r in rows])
            ax.bar(x, vals, bottom=bottoms, color=colors[comp], label=f"{comp} (median)")
            bottoms += vals
        totals = np.array([r["times_ms"]["total"]["median"] or np.nan for r in rows])
        p90 = np.array([r["times_ms"]["total"]["p90"] or np.nan for r in rows])
        ax.errorbar(x, totals, yerr=[np.zeros_like(totals), np.maximum(p90 - totals, 0)], fmt="k_", ms=14,
                    capsize=4, label="total: median, p90")
        labels = [f"{r['backend']}\n{r['formulation']}\n{r['x0_facets']} facets" for r in rows]
        ax.set_xticks(x, labels, fontsize=8)
    ax.axhline(PAPER_MS["median_solver"], color="k", ls="--", lw=1, label="paper: 68 ms median solver time")
    ax.axhline(TARGET_MS, color="tab:green", ls=":", lw=1, label="target: 7 ms full step")
    ax.set_ylabel("ms per step")
    ax.set_title("Example 1: per-step split (stacked medians of each part) and total", fontsize=10)
    ax.legend(fontsize=7, loc="upper right")

    scaling = result.get("scaling") or {}
    for ax, axis, xlabel in ((axes[0, 1], "N", "horizon N"), (axes[1, 0], "p", "parameters p"),
                             (axes[1, 1], "x0_facets", "facets of X0")):
        rows = [r for r in scaling.get(axis, []) if "times_ms" in r]
        for key, (color, marker) in _STYLE.items():
            sel = sorted((r for r in rows if (r["backend"], r["formulation"]) == key), key=lambda r: r[axis])
            if not sel:
                continue
            xs = [r[axis] for r in sel]
            ax.plot(xs, [r["times_ms"]["total"]["median"] or np.nan for r in sel], color=color, marker=marker,
                    label=f"{key[0]} {key[1]}: total")
            ax.plot(xs, [r["times_ms"]["solver"]["median"] or np.nan for r in sel], color=color, marker=marker,
                    ls="--", mfc="none", label=f"{key[0]} {key[1]}: solver only")
        ax.axhline(PAPER_MS["median_solver"], color="k", ls="--", lw=1, label="paper: 68 ms")
        ax.axhline(TARGET_MS, color="tab:green", ls=":", lw=1)
        failed = [str(r[axis]) for r in scaling.get(axis, []) if "times_ms" not in r]
        title = f"scaling with {xlabel} (medians)"
        if failed:
            title += f"; no design for {', '.join(failed)}"
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(xlabel)
        if rows:
            ax.set_xticks(sorted({r[axis] for r in rows}))
        ax.set_ylabel("ms per step")
        ax.set_yscale("log")
        ax.grid(True, which="both", alpha=0.3)
        if rows:
            ax.legend(fontsize=6, ncol=2)
    fig.suptitle(f"amcp bench ({result.get('created', '')}; {result.get('machine', {}).get('cpu_count')} cores)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def format_summary(result: dict[str, Any]) -> str:
    """Plain-text table of the Example 1 runs, the ratios and the target."""
    lines = []
    example = result.get("example")
    if example:
        head = f"{'backend':8s} {'form':7s} {'X0':>3s}  " + "  ".join(f"{k:>17s}" for k in
                                                                      ("set update", "LMS", "QP update", "solver", "total"))
        lines += ["Example 1, ms per step: median / p90 over the run", head]
        for r in example["runs"]:
            if "times_ms" not in r:
                lines.append(f"X0 {r.get('x0_facets')} facets: {r.get('status')}")
                continue
            cells = []
            for key in ("set_update", "lms", "qp_update", "solver", "total"):
                s = r["times_ms"][key]
                cells.append(f"{_fmt(s['median'])} / {_fmt(s['p90'])}".rjust(17))
            status = "" if r["status"] == "completed" else f"  [{r['status']}]"
            dv = r.get("max_abs_dv_vs_plain")
            dv_text = f"  max|dv| vs plain {dv:.1e}" if dv is not None else ""
            lines.append(f"{r['backend']:8s} {r['formulation']:7s} {r['x0_facets']:>3d}  " + "  ".join(cells) + status + dv_text)
        for q in example["ratios"]:
            who = q.get("backend") or q.get("formulation")
            lines.append(f"ratio {q['kind']:12s} {who:6s} X0 {q['x0_facets']:>2d} facets: total {_fmt(q['total'], 2)}x, "
                         f"solver {_fmt(q['solver'], 2)}x")
    target = result.get("target") or {}
    if target.get("drake_ms") is not None:
        text = (f"target: Drake vertex form, 8 facets, median full step {target['drake_ms']:.2f} ms "
                f"(<= {target['target_ms']:.0f} ms: {'met' if target['met'] else 'NOT met'})")
        if target.get("cvxpy_over_drake") is not None:
            text += (f"; cvxpy {target['cvxpy_ms']:.2f} ms = {target['cvxpy_over_drake']:.2f}x Drake "
                     f"(<= {target['cvxpy_target_ratio']:.0f}x: {'met' if target['cvxpy_met'] else 'NOT met'})")
        lines.append(text)
    scaling = result.get("scaling")
    if scaling:
        lines.append("scaling, median total / solver ms:")
        for axis, rows in scaling.items():
            for r in rows:
                if "times_ms" not in r:
                    lines.append(f"  {axis} = {r[axis]}: {r['status']}")
                    continue
                lines.append(f"  {axis} = {r[axis]:>3}  {r['backend']:6s} {r['formulation']:7s} "
                             f"{_fmt(r['times_ms']['total']['median'])} / {_fmt(r['times_ms']['solver']['median'])}"
                             + ("" if r["status"] == "completed" else f"  [{r['status']}]"))
    if result.get("section4"):
        from amcp_drake.studies.bench_section4 import format_section4

        lines.append(format_section4(result["section4"]))
    return "\n".join(lines)


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"
