"""Cost of the Section 4 options per step (``amcp bench --only section4``).

Example 1 (docs/explanation/paper.md §9), plain formulation (the options need it), each backend, with: the
certainty-equivalence cost (17) (reference), the PE two-QP procedure of docs/explanation/paper.md §8 (P = n + 1 = 3,
ρ = 0.8, Example 2's values), the min–max cost (19) and time-varying parameters (d_θ = 0.01). The
closed loops are interleaved step by step (same disturbance sequence, each with its own state), so
machine noise hits all configurations alike. Reported per configuration: median and max of the full
step and of all QP solves of the step (with PE: every QP solved, i.e. both bounded QPs and any retry),
and the ratio of the medians and maxima to the reference of the same backend. The paper reports
about 2× the median and maximum solve time for its PE case (docs/explanation/paper.md §8).
"""

from __future__ import annotations

import gc
from collections.abc import Callable
from typing import Any

import numpy as np

#: (label, OnlineOptions fields); the first is the reference of the ratios.
CONFIGS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("CE (17)", {}),
    ("PE P=3 rho=0.8", {"pe_window": 3, "pe_level": 0.8}),
    ("min-max (19)", {"cost": "minmax"}),
    ("d_theta=0.01", {"d_theta": 0.01}),
)
ENFORCED = ("enforced", "enforced_partial", "enforced_necessary")


def qp_time(record) -> float:
    """Seconds spent in QP solves at one step: with PE, every bounded QP (``times['pe_solver']``) plus the
    final unbounded one when no bounded QP was applied; else the one QP."""
    pe = record.times.get("pe_solver")
    if pe is None:
        return float(record.times.get("solver", 0.0))
    return float(pe) + (0.0 if record.pe_status in ENFORCED else float(record.times.get("solver", 0.0)))


def _stats(values: list[float]) -> dict[str, float | int | None]:
    if not values:
        return {"median": None, "max": None, "n": 0}
    ms = 1e3 * np.asarray(values, float)
    return {"median": float(np.median(ms)), "max": float(np.max(ms)), "n": int(len(ms))}


def section4_benchmark(steps: int = 50, seed: int = 0, backends: tuple[str, ...] = ("drake", "cvxpy"),
                       progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Per-step times of the Section 4 options on Example 1 (see the module docstring)."""
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.model.examples import lorenzen2019_spec
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence

    spec = lorenzen2019_spec()
    pr, sc = spec.problem, spec.scenario
    d = design(pr, spec.design)
    w = disturbance_sequence(pr, "uniform", steps + 1, seed=seed)
    rows: list[dict[str, Any]] = []
    for backend in backends:
        progress(f"section4: {backend}, {len(CONFIGS)} configurations, {steps} steps")
        ctrls = [AdaptiveMPC(pr, d, backend=backend, options=OnlineOptions(**fields)) for _, fields in CONFIGS]
        states = [np.asarray(sc.x0, float) for _ in CONFIGS]
        totals = [[] for _ in CONFIGS]
        qps = [[] for _ in CONFIGS]
        status = ["completed"] * len(CONFIGS)
        was_enabled = gc.isenabled()
        gc.collect()
        gc.disable()
        try:
            for k in range(steps + 1):
                for c, ctrl in enumerate(ctrls):
                    if status[c] != "completed":
                        continue
                    try:
                        u, rec = ctrl.step(states[c])
                    except AmcpError as exc:
                        status[c] = f"error at k={k}: {exc}"
                        continue
                    if u is None:
                        status[c] = f"{rec.status.value} at k={k}"
                        continue
                    if k >= 1:
                        totals[c].append(float(rec.times.get("total", 0.0)))
                        qps[c].append(qp_time(rec))
                    states[c] = pr.step(states[c], u, sc.theta_star, w[k])
        finally:
            if was_enabled:
                gc.enable()
        ref_total, ref_qp = _stats(totals[0]), _stats(qps[0])
        for c, (label, fields) in enumerate(CONFIGS):
            t, q = _stats(totals[c]), _stats(qps[c])
            rows.append({"backend": backend, "config": label, "options": fields, "status": status[c],
                         "total_ms": t, "qp_ms": q,
                         "qp_median_ratio": _ratio(q["median"], ref_qp["median"]),
                         "qp_max_ratio": _ratio(q["max"], ref_qp["max"]),
                         "total_median_ratio": _ratio(t["median"], ref_total["median"])})
    return {"problem": "lorenzen2019", "formulation": "plain", "steps": steps, "seed": seed, "rows": rows}


def _ratio(a, b):
    return float(a / b) if a is not None and b else None


def format_section4(result: dict[str, Any]) -> str:
    """Plain-text table of :func:`section4_benchmark`."""
    lines = [f"Section 4 options, Example 1, plain formulation, {result['steps']} steps (ms per step; ratio to CE (17))",
             f"{'backend':7s} {'option':16s} {'total median':>12s} {'QP median':>10s} {'QP max':>8s} "
             f"{'QP med ratio':>12s} {'QP max ratio':>12s}"]
    for r in result["rows"]:
        def f(v, fmt="{:.2f}"):
            return "-" if v is None else fmt.format(v)
        lines.append(f"{r['backend']:7s} {r['config']:16s} {f(r['total_ms']['median']):>12s} {f(r['qp_ms']['median']):>10s} "
                     f"{f(r['qp_ms']['max']):>8s} {f(r['qp_median_ratio']):>12s} {f(r['qp_max_ratio']):>12s}"
                     + ("" if r["status"] == "completed" else f"  [{r['status']}]"))
    return "\n".join(lines)
