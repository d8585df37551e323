"""One lockstep run of several controller configurations: the timing loop shared by
the Example 1 bench (:mod:`.bench`) and the sweeps (:mod:`.bench_scaling`).

All configurations run in lockstep (step k of every configuration, then step k+1): on a shared,
noisy machine every configuration sees the same noise, so the ratios of one run are meaningful even
when the absolute times drift. Python's garbage collector is off inside the timed loop (as
``timeit`` does). The closed loops are independent (each applies its own input, same disturbance
sequence), so the runs also report how far the formulations' inputs drift apart.
"""

from __future__ import annotations

import gc
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amcp_drake.studies.resolves import count_resolves, step_kinds

#: Formulations the bench knows: the QP (20) forms, plus "fast" = the vertex form with the DAQP fast
#: path (Drake only): name -> keyword arguments of AdaptiveMPC.
FORMULATION_OPTIONS = {"plain": {"formulation": "plain"}, "vertex": {"formulation": "vertex"},
                       "fast": {"formulation": "vertex", "qp_solver": "daqp"}}
#: Per-step wall-time keys: name in the output -> key of ``StepRecord.times``. The CPU-time keys are
#: ``cpu_<part>`` for the parts of :data:`amcp_drake.studies.bench_cpu.PARTS`.
TIME_KEYS = {
    "set_update": "set_update_total",
    "set_update_solver": "set_update",
    "lms": "lms_total",
    "qp_update": "qp_update",
    "solver": "solver",
    "total": "total",
}


@dataclass
class RunResult:
    """One configuration's closed-loop run: per-step times (s) and the inputs v_0 it applied."""

    backend: str
    formulation: str
    build_s: float
    times: dict[str, list[float]] = field(default_factory=dict)
    v: list[np.ndarray | None] = field(default_factory=list)
    status: str = "completed"
    build_cpu_s: float = 0.0
    fast_path: dict[str, int] | None = None   # fast path: steps answered by DAQP and fallbacks
    #: steps that needed more than the first solve (:func:`count_resolves`; full and first steps)
    resolves: dict[str, int] = field(default_factory=dict)
    #: fast path: why it was switched off during the run ('' while on, or for other configurations)
    fast_path_off: str = ""

    @property
    def label(self) -> str:
        return f"{self.backend}/{self.formulation}"


# -- running -----------------------------------------------------------------------------------

def lockstep(problem, design, configs: list[tuple[str, str]], x0, theta_star, steps: int, seed: int) -> list[RunResult]:
    """Run the closed loop of every (backend, formulation) in ``configs`` for ``steps`` + 1 steps,
    interleaved step by step, with the same disturbance sequence (uniform on W, ``seed``).

    Per full step: the wall times of ``StepRecord.times`` (:data:`TIME_KEYS`) and the thread CPU
    time of each part (``cpu_<part>``, :class:`~amcp_drake.studies.bench_cpu.CpuProfile`)."""
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import disturbance_sequence
    from amcp_drake.studies.bench_cpu import PARTS, CpuProfile

    w = disturbance_sequence(problem, "uniform", steps + 1, seed=seed)
    theta_star = np.asarray(theta_star, float)
    runs, profiles, states = [], [], []
    notes: list[list[str]] = []   # per run: one string per step (QP details + answer-check notes)
    for backend, formulation in configs:
        start, cpu = time.perf_counter(), time.thread_time()
        ctrl = AdaptiveMPC(problem, design, backend=backend, **FORMULATION_OPTIONS[formulation])
        run = RunResult(backend, formulation, time.perf_counter() - start,
                        {name: [] for name in (*TIME_KEYS, *(f"cpu_{p}" for p in PARTS))})
        run.build_cpu_s = time.thread_time() - cpu
        runs.append(run)
        profiles.append(CpuProfile(ctrl))
        states.append(np.asarray(x0, float))
        notes.append([])
    active = [True] * len(runs)
    was_enabled = gc.isenabled()
    gc.collect()
    gc.disable()
    try:
        for k in range(steps + 1):
            # the order alternates step by step: a configuration that runs right after another one's
            # solver call finds the caches evicted (measured: 5-37 µs of bias per step)
            for c in (range(len(runs)) if k % 2 == 0 else reversed(range(len(runs)))):
                run, prof = runs[c], profiles[c]
                if not active[c]:
                    continue
                try:
                    u, rec, cpu_parts = prof.step(states[c])
                except AmcpError as exc:
                    run.status, active[c] = f"error at k={k}: {exc}", False
                    continue
                notes[c].append(step_kinds(rec))
                run.v.append(None if rec.v is None else np.asarray(rec.v, float))
                if u is None:
                    run.status, active[c] = f"{rec.status.value} at k={k}", False
                    continue
                if k >= 1:  # full steps only: update + LMS + QP
                    for name, key in TIME_KEYS.items():
                        run.times[name].append(float(rec.times.get(key, 0.0)))
                    for part, value in cpu_parts.items():
                        run.times[f"cpu_{part}"].append(value)
                states[c] = problem.step(states[c], u, theta_star, w[k])
    finally:
        if was_enabled:
            gc.enable()
    for run, prof, run_notes in zip(runs, profiles, notes):
        run.fast_path = getattr(prof.ctrl.mpc, "fast_path_counts", None)
        run.fast_path_off = getattr(prof.ctrl.mpc, "fast_path_off", "")
        run.resolves = count_resolves(run_notes)
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


def summaries(runs: list[RunResult], extra: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    for run in runs:
        plain = next((r for r in runs if r.backend == run.backend and r.formulation == "plain"), None)
        row = dict(extra)
        row.update({"backend": run.backend, "formulation": run.formulation, "status": run.status,
                    "build_s": run.build_s, "build_cpu_s": run.build_cpu_s,
                    "times_ms": {name: _stats(vals) for name, vals in run.times.items()},
                    "max_abs_dv_vs_plain": _max_dv(run, plain) if plain is not None and plain is not run else None,
                    "fast_path": run.fast_path, "resolves": run.resolves})
        out.append(row)
    return out


__all__ = ["FORMULATION_OPTIONS", "TIME_KEYS", "RunResult", "lockstep", "summaries"]
