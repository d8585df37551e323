"""The size table (``amcp bench --only size``): what the design and one online step cost as the
state dimension grows, one row per system, every row bounded in memory and time.

Rows: the chains of :mod:`amcp_drake.studies.chains` (actuated and integrator, n = 2 … 8 by
default; the mass-spring chains of 5, 6 and 8 masses, n = 10, 12, 16, by default), every built-in literature example with n >= :data:`MIN_EXAMPLE_N`, and any problem file
given (``--problem``). Each row runs in a child process of its own
(``python -m amcp_drake.studies.bench_size ROW.json OUT.json``):

1. the offline design at the file's settings (automatic mode unless the file fixes a template)
   under a :class:`~amcp_drake.offline.budget.DesignBudget` (``--max-memory``, ``--candidate-budget``):
   design CPU time (``time.process_time``, every thread of the child) beside wall time, the template
   chosen, X0's facets and vertices, X_f's rows;
2. the closed loop from the scenario's x0 (the largest multiple of it in
   :data:`~amcp_drake.studies.bench_scaling.X0_SCALES` whose first QP is feasible) with the plain
   form (15), the vertex form and the vertex form with the DAQP fast path, in lockstep
   (:func:`~amcp_drake.studies.bench_run.lockstep`: thread CPU and wall time per step, medians over the
   full steps), and the formulation ``formulation="auto"`` chooses
   (:func:`~amcp_drake.online.formulation_choice.choose_formulation`) beside the measured faster one.

Bounds. The child's address space is limited to ``--max-memory`` plus
:data:`ADDRESS_SPACE_OVERHEAD_MB` (the libraries' own mappings: Drake, BLAS and Python take about
1.5 GiB of address space before any work), so no row can exhaust the machine; a row that uses more
than ``row_seconds`` of CPU time (``RLIMIT_CPU``: on a shared machine wall time was 5–18× CPU time,
so a wall-time limit would measure the machine's load) or more than :data:`WALL_FACTOR` times that in
wall time is killed. Either way the row shows the reason and what was measured before it (the child writes its result after the design and again after the runs). Peak memory is
the child's peak resident set (``ru_maxrss`` from ``wait4``), CPU time the child's user + system time.

The table (:func:`size_markdown`) is ``size.md`` next to ``bench.json`` (key ``size``).
"""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: Built-in examples with at least this many states are rows of the default table.
MIN_EXAMPLE_N = 4
#: Address space (MiB) allowed to a row's child on top of ``--max-memory``: importing Drake, numpy's
#: BLAS and the solvers maps about 1.5 GiB before any work (measured with ``ulimit -v``).
ADDRESS_SPACE_OVERHEAD_MB = 2048
#: Default CPU-time limit of one row (design and runs), seconds.
DEFAULT_ROW_SECONDS = 600.0
#: A row is also killed after this many times its CPU-time limit in wall time.
WALL_FACTOR = 10.0
#: Configurations timed per row (bench_run.FORMULATION_OPTIONS).
SIZE_CONFIGS = (("drake", "plain"), ("drake", "vertex"), ("drake", "fast"))
#: How often the parent looks at a running child (seconds).
POLL_SECONDS = 0.2


@dataclass(frozen=True)
class SizeRow:
    """One row to run: a label, where the problem comes from ("chain", "example", "file") and the
    problem file's content."""

    label: str
    source: str
    problem: dict


def default_rows(chain_ns: tuple[int, ...] = tuple(range(2, 9)), chain_kinds: tuple[str, ...] | None = None,
                 examples: tuple[str, ...] | None = None, problem_files: tuple[str, ...] = (),
                 mass_chains: tuple[int, ...] = ()) -> list[SizeRow]:
    """The rows of the table: each chain kind at each n, the built-in ``examples`` (None: every
    literature example with n >= :data:`MIN_EXAMPLE_N`), then each problem file (read and validated
    here: a bad file is refused before anything runs)."""
    from amcp_drake.model.examples import EXAMPLES, get_example
    from amcp_drake.model.problem_io import load_spec, spec_to_dict
    from amcp_drake.studies.chains import CHAIN_KINDS, chain, mass_chain

    rows = [SizeRow(f"{kind} chain n={n}", "chain", chain(kind, n))
            for kind in (chain_kinds or CHAIN_KINDS) for n in chain_ns]
    rows += [SizeRow(f"mass chain {k} masses (n={2 * k})", "chain", mass_chain(k)) for k in mass_chains]
    names = examples
    if names is None:
        names = tuple(name for name in EXAMPLES if get_example(name).problem.n >= MIN_EXAMPLE_N)
    rows += [SizeRow(name, "example", spec_to_dict(get_example(name))) for name in names]
    for path in problem_files:
        spec = load_spec(path)
        rows.append(SizeRow(Path(path).stem, "file", spec_to_dict(spec)))
    return rows


# -- parent: one child per row ---------------------------------------------------------------------------

def run_row(row: SizeRow, steps: int, seed: int, max_memory_mb: float, candidate_seconds: float,
            row_seconds: float, progress: Callable[[str], None] = lambda s: None) -> dict[str, Any]:
    """Run ``row`` in a child process under the memory and time limits (module docstring); the
    child's result with ``status``, ``peak_rss_mib``, ``cpu_s`` and ``wall_s`` of the whole row."""
    limit_mb = float(max_memory_mb) + ADDRESS_SPACE_OVERHEAD_MB
    with tempfile.TemporaryDirectory(prefix="amcp-size-") as tmp:
        job, out = Path(tmp) / "row.json", Path(tmp) / "out.json"
        job.write_text(json.dumps({"label": row.label, "source": row.source, "problem": row.problem, "steps": steps,
                                   "seed": seed, "max_memory_mb": max_memory_mb,
                                   "candidate_seconds": candidate_seconds}))
        started = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "amcp_drake.studies.bench_size", str(job), str(out)],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                text=True, preexec_fn=lambda: _limit_child(limit_mb, row_seconds))
        tail: deque[str] = deque(maxlen=6)
        reader = threading.Thread(target=_relay, args=(proc.stderr, row.label, progress, tail), daemon=True)
        reader.start()
        killed = ""
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.perf_counter() - started > WALL_FACTOR * row_seconds:
                proc.kill()
                killed = f"killed after {WALL_FACTOR * row_seconds:g} s of wall time ({WALL_FACTOR:g} x the CPU limit)"
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(POLL_SECONDS)
        proc.returncode = os.waitstatus_to_exitcode(status)
        reader.join(timeout=5)
        result = json.loads(out.read_text()) if out.exists() else {"label": row.label, "source": row.source}
    result.update(wall_s=time.perf_counter() - started, cpu_s=usage.ru_utime + usage.ru_stime,
                  peak_rss_mib=usage.ru_maxrss / 1024.0, address_space_limit_mib=limit_mb)
    last = f"; last output: {tail[-1]}" if tail else ""
    if killed:
        result["status"] = killed + last
    elif proc.returncode == -signal.SIGXCPU or (proc.returncode == -signal.SIGKILL
                                                   and usage.ru_utime + usage.ru_stime >= row_seconds):
        result["status"] = f"killed after the row's CPU-time limit of {row_seconds:g} s" + last
    elif proc.returncode != 0 and result.get("status") in (None, "running"):
        how = (f"killed by {signal.Signals(-proc.returncode).name}" if proc.returncode < 0
               else f"exit code {proc.returncode}")
        result["status"] = f"child {how} (address space limit {limit_mb:,.0f} MiB); last output: " + " | ".join(tail)
    return result


def _limit_child(limit_mb: float, cpu_seconds: float) -> None:
    """In the child, before exec: RLIMIT_AS = ``limit_mb`` MiB, RLIMIT_CPU = ``cpu_seconds`` (SIGXCPU;
    SIGKILL one second later)."""
    limit = int(limit_mb * 2**20)
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    cpu = max(1, int(np.ceil(cpu_seconds)))
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))


def _relay(stream, label: str, progress: Callable[[str], None], tail: deque) -> None:
    """Hand every line the child writes to stderr to ``progress`` (prefixed) and keep the last few."""
    for line in stream:
        line = line.rstrip()
        if line:
            tail.append(line)
            progress(f"size: {label}: {line}")


def size_benchmark(settings, progress: Callable[[str], None] = lambda s: None) -> list[dict[str, Any]]:
    """Every row of ``settings`` (:class:`~amcp_drake.studies.bench.BenchSettings`: ``size_chain_ns``,
    ``size_chain_kinds``, ``size_examples``, ``size_problems``, ``scaling_steps``, ``max_memory_mb``,
    ``candidate_seconds``, ``row_seconds``), one child process each."""
    rows = default_rows(settings.size_chain_ns, settings.size_chain_kinds, settings.size_examples,
                        settings.size_problems, settings.size_mass_chains)
    out = []
    for number, row in enumerate(rows, start=1):
        progress(f"size: row {number}/{len(rows)}: {row.label} ...")
        result = run_row(row, settings.scaling_steps, settings.seed, settings.max_memory_mb,
                         settings.candidate_seconds, settings.row_seconds, progress)
        progress(f"size: row {number}/{len(rows)}: {row.label}: {result.get('status')} "
                 f"[{result['cpu_s']:.1f} s CPU, {result['wall_s']:.1f} s wall, {result['peak_rss_mib']:.0f} MiB]")
        out.append(result)
    return out


# -- child: one row --------------------------------------------------------------------------------------

def measure_row(job: dict[str, Any], out_path: str | Path, log: Callable[[str], None]) -> dict[str, Any]:
    """Design and run one row (in the child); the result is written to ``out_path`` after the design
    and again at the end, so a row killed during its runs still shows its design."""
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.model.problem_io import spec_from_dict, write_json_atomic
    from amcp_drake.offline.budget import DesignBudget
    from amcp_drake.offline.design import design

    result: dict[str, Any] = {"label": job["label"], "source": job["source"], "status": "running"}

    def save() -> None:
        write_json_atomic(_jsonable(result), out_path)

    spec = spec_from_dict(job["problem"])
    pr = spec.problem
    result.update(n=pr.n, m=pr.m, p=pr.p, N=pr.N)
    save()
    budget = DesignBudget(job["max_memory_mb"], job["candidate_seconds"], progress=log)
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        d = design(pr, spec.design, backend="drake", budget=budget)
    except AmcpError as exc:
        attempts = [a.to_dict() for a in getattr(exc, "attempts", [])]
        status = ("no design candidate passed; the first: " + _attempt_text(attempts[0]) if attempts
                  else "design refused or failed: " + _first_lines(exc))
        result.update(design_cpu_s=time.process_time() - cpu, design_s=time.perf_counter() - wall,
                      design_peak_rss_mib=_peak_mib(), status=status, attempts=attempts)
        save()
        return result
    result.update(design_cpu_s=time.process_time() - cpu, design_s=time.perf_counter() - wall,
                  design_peak_rss_mib=_peak_mib(), template=(d.info or {}).get("x0_template", spec.design.x0_template),
                  x0_facets=int(len(d.H_x)), x0_vertices=int(len(d.X0_vertices)), xf_rows=int(len(d.H_T)),
                  attempts=(d.info or {}).get("attempts", []), status="designed; running the closed loop")
    save()
    _run_loops(result, spec, d, job["steps"], job["seed"], job["max_memory_mb"], log)
    save()
    return result


def _run_loops(result: dict[str, Any], spec, d, steps: int, seed: int, max_memory_mb: float, log) -> None:
    """The closed loops of :data:`SIZE_CONFIGS` in lockstep, and auto's choice, into ``result``."""
    from amcp_drake.model.errors import AmcpError
    from amcp_drake.model.limits import check_run_size
    from amcp_drake.online.formulation_choice import choose_formulation
    from amcp_drake.studies.bench_run import lockstep, summaries
    from amcp_drake.studies.bench_scaling import feasible_x0

    pr = spec.problem
    choice = choose_formulation(pr, d, spec.online)
    result["auto"] = {"formulation": choice.formulation, "reason": choice.reason,
                      "vertex_size": choice.vertex_size, "plain_size": choice.plain_size}
    try:
        check_run_size(pr, spec.design, steps, spec.online, max_memory_mb)
    except AmcpError as exc:
        result["status"] = "run refused: " + _first_lines(exc)
        return
    x0, theta_star = _scenario(spec)
    x0, scale = feasible_x0(pr, d, x0)
    result["x0_scale"] = scale
    log(f"closed loop: {steps} steps of {', '.join(f'{b} {f}' for b, f in SIZE_CONFIGS)} in lockstep")
    runs = lockstep(pr, d, list(SIZE_CONFIGS), x0, theta_star, steps, seed)
    result["runs"] = summaries(runs, {})
    for run, row in zip(runs, result["runs"]):
        row["fast_path_off"] = run.fast_path_off
    result["status"] = "completed" if all(r.status == "completed" for r in runs) else "; ".join(
        f"{r.label}: {r.status}" for r in runs if r.status != "completed")


def _scenario(spec) -> tuple[np.ndarray, np.ndarray]:
    """(x0, θ*) of the file's scenario (θ*_0 of a sequence); without one, x0 = 0.5 e_1 and θ* = θ̂0."""
    pr = spec.problem
    sc = spec.scenario
    if sc is None:
        x0 = np.zeros(pr.n)
        x0[0] = 0.5
        return x0, np.asarray(pr.theta_hat0, float)
    theta = np.asarray(sc.theta_star, float)
    return np.asarray(sc.x0, float), theta[0] if theta.ndim == 2 else theta


def _attempt_text(attempt: dict[str, Any], chars: int = 160) -> str:
    """"label: outcome (reason)" of one recorded design candidate, the reason cut to ``chars``."""
    reason = attempt.get("reason", "")
    reason = reason if len(reason) <= chars else reason[: chars - 3] + "..."
    return f"{attempt['label']}: {attempt['outcome']} ({reason})"


def _peak_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _first_lines(exc: Exception, count: int = 1) -> str:
    return " ".join(str(exc).splitlines()[:count])


def _jsonable(value: Any) -> Any:
    from amcp_drake.model.problem_io import jsonable

    return jsonable(value)


# -- table -----------------------------------------------------------------------------------------------

def _median(row: dict[str, Any] | None, key: str = "cpu_total") -> float | None:
    return None if row is None else ((row.get("times_ms") or {}).get(key) or {}).get("median")


def _fmt(value: float | None, digits: int = 2) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _step(row: dict[str, Any] | None) -> str:
    """"CPU (wall)" medians of a run's full step, ms."""
    if row is None:
        return "-"
    return f"{_fmt(_median(row))} ({_fmt(_median(row, 'total'))})"


def faster_form(result: dict[str, Any]) -> str | None:
    """"plain" or "vertex": the form with the smaller median step CPU time in the row (None when
    either did not run)."""
    runs = {r["formulation"]: r for r in result.get("runs", []) if r.get("status") == "completed"}
    plain, vertex = _median(runs.get("plain")), _median(runs.get("vertex"))
    if plain is None or vertex is None:
        return None
    return "plain" if plain < vertex else "vertex"


def candidates_text(attempts: list[dict[str, Any]] | None) -> str:
    """The automatic design's candidates of a row by outcome ("3: 1 pass, 2 time budget"); '-' when
    the row has no record of them (a fixed template, or killed before the design ended)."""
    if not attempts:
        return "-"
    outcomes: dict[str, int] = {}
    for a in attempts:
        outcomes[a["outcome"]] = outcomes.get(a["outcome"], 0) + 1
    return f"{len(attempts)}: " + ", ".join(f"{count} {outcome}" for outcome, count in outcomes.items())


def size_markdown(rows: list[dict[str, Any]]) -> str:
    """The size table: one line per row (medians of the full step in ms, CPU with wall in brackets;
    seconds of design CPU with wall time in brackets; peak resident memory of the row's process)."""
    lines = ["| system | n | m | p | design CPU s (wall) | template | design candidates | X0 facets / vertices "
             "| X_f rows | step ms CPU (wall): plain | vertex | fast path (DAQP / fallbacks) | auto chooses (faster) "
             "| peak memory MiB | row CPU s (wall) | status |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        runs = {x["formulation"]: x for x in r.get("runs", [])}
        fast = runs.get("fast")
        fast_text = "-"
        if fast is not None:
            fast_text = _step(fast)
            counts = fast.get("fast_path") or {}
            if counts:
                fast_text += f" ({counts.get('daqp', 0)} / {counts.get('fallback', 0)})"
            if fast.get("fast_path_off"):
                fast_text += f"; switched off: {fast['fast_path_off']}"
        auto = (r.get("auto") or {}).get("formulation")
        faster = faster_form(r)
        auto_text = "-" if auto is None else (auto + (f" ({faster})" if faster else ""))
        design = "-" if "design_cpu_s" not in r else f"{r['design_cpu_s']:.1f} ({r['design_s']:.1f})"
        x0 = "-" if "x0_facets" not in r else f"{r['x0_facets']} / {r['x0_vertices']}"
        scaled = "" if r.get("x0_scale", 1.0) == 1.0 else f" (x0 × {r['x0_scale']:g})"
        status = str(r.get("status", "")).replace("|", "/")
        lines.append(
            f"| {r['label']}{scaled} | {r.get('n', '-')} | {r.get('m', '-')} | {r.get('p', '-')} | {design} "
            f"| {r.get('template', '-')} | {candidates_text(r.get('attempts'))} | {x0} | {r.get('xf_rows', '-')} "
            f"| {_step(runs.get('plain'))} | {_step(runs.get('vertex'))} | {fast_text} "
            f"| {auto_text} | {r['peak_rss_mib']:.0f} | {r['cpu_s']:.1f} ({r['wall_s']:.1f}) | {status} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """The child: ``python -m amcp_drake.studies.bench_size ROW.json OUT.json``."""
    args = sys.argv[1:] if argv is None else argv
    job = json.loads(Path(args[0]).read_text())

    def log(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    try:
        measure_row(job, args[1], log)
    except MemoryError:
        _fail(args[1], job, "out of memory: the row's address space limit was reached")
        return 1
    except Exception as exc:  # noqa: BLE001 - a row's failure is its table entry, never a lost row
        _fail(args[1], job, f"error: {type(exc).__name__}: {_first_lines(exc)}")
        return 1
    return 0


def _fail(out_path: str, job: dict[str, Any], reason: str) -> None:
    """Keep what the row measured (the file written so far) and set its status to ``reason``."""
    from amcp_drake.model.problem_io import write_json_atomic

    path = Path(out_path)
    result = json.loads(path.read_text()) if path.exists() else {"label": job["label"], "source": job["source"]}
    result["status"] = reason
    write_json_atomic(result, path)


if __name__ == "__main__":
    sys.exit(main())


__all__ = ["ADDRESS_SPACE_OVERHEAD_MB", "DEFAULT_ROW_SECONDS", "MIN_EXAMPLE_N", "SIZE_CONFIGS", "SizeRow",
           "candidates_text", "default_rows", "faster_form", "measure_row", "run_row", "size_benchmark", "size_markdown"]
