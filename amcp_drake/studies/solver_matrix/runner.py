"""The conformance matrix: every (solver configuration, corpus problem) solved in its own child process
with a time limit, and classified.

Isolation: each solve runs in a fresh process forked from a ``forkserver`` that has imported pydrake
and cvxpy once (:data:`PRELOAD`), so a solver that aborts the process (SIGABRT from a Rust panic that
crosses C++), segfaults, raises or hangs takes down only its child. The parent waits at most
``time_limit`` seconds and then kills the child.

Verdicts (:func:`classify`), with the tolerances of :data:`TOLERANCES` for the settings used:

* ``correct``: success reported, the answer feasible (largest violation, relative to 1 + |bound|, at most
  ``feas``) and optimal (f(x) − f* at most ``opt`` · (1 + |f*|)); on an infeasible reference: the solver
  reported infeasibility;
* ``honest failure``: no success reported (any other status, "inaccurate" included);
* ``wrong``: success reported, but the answer infeasible or suboptimal beyond the tolerances, no x, or
  success on a problem whose reference is infeasible;
* ``crash``: the child raised (a Python exception, a Rust panic) or died (abort, signal);
* ``timeout``: no answer within the time limit;
* ``n/a``: the solver does not take this problem class (not counted).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import tempfile
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.studies.solver_matrix.corpus import CorpusProblem

VERDICTS = ("correct", "honest failure", "wrong", "crash", "timeout", "n/a")
#: Verdict tolerances per settings: feasibility (relative violation) and optimality (relative gap).
#: "default" asks what a user gets from the solver as installed; 1e-6 is the accuracy the MPC's answer
#: checks need (two orders below the tube margins). "tight" asks for 1e-9-1e-10 and is judged at 1e-8.
TOLERANCES = {"default": {"feas": 1e-6, "opt": 1e-6}, "tight": {"feas": 1e-8, "opt": 1e-8}}
#: Seconds a solve may take before its child is killed.
DEFAULT_TIME_LIMIT = 20.0
#: Modules the forkserver imports once, so each child starts in milliseconds.
PRELOAD = ["amcp_drake.studies.solver_matrix.solvers", "pydrake.solvers", "cvxpy"]


@dataclass
class Cell:
    """One (solver, problem) of the matrix."""

    problem: str
    solver: str
    verdict: str
    status: str = ""
    wall_s: float | None = None
    cpu_s: float | None = None
    violation: float | None = None
    gap: float | None = None
    x_error: float | None = None
    detail: str = ""


def classify(pr: CorpusProblem, message: dict[str, Any] | None, exitcode: int | None, timed_out: bool,
             settings: str) -> tuple[str, dict[str, Any]]:
    """(verdict, measures) of one solve from what its child sent (``message``) and how it ended."""
    tol = TOLERANCES[settings]
    if timed_out:
        return "timeout", {"detail": "no answer within the time limit; child killed"}
    if message is None or "crash" in message:
        if message is not None:
            return "crash", {"detail": message["crash"]}
        name = signal.Signals(-exitcode).name if exitcode is not None and exitcode < 0 else f"exit code {exitcode}"
        return "crash", {"detail": f"child process died ({name}) without an answer"}
    if message.get("unavailable"):
        return "n/a", {"detail": message["unavailable"]}
    out = message["outcome"]
    if not out["supported"]:
        return "n/a", {"detail": out["status"]}
    ref = pr.reference
    if ref.get("status") == "infeasible":
        if out["success"]:
            return "wrong", {"detail": "success reported on a problem with a verified infeasibility certificate"}
        if "infeasible" in out["status"].lower():
            return "correct", {"detail": "reported infeasible"}
        return "honest failure", {"detail": f"status {out['status']} (the problem is infeasible)"}
    if not out["success"]:
        return "honest failure", {"detail": f"status {out['status']}"}
    x = out.get("x")
    if x is None or len(x) != pr.n or not np.all(np.isfinite(x)):
        return "wrong", {"detail": "success reported without a finite solution"}
    x = np.asarray(x, float)
    violation = pr.violation(x)
    f_star = float(ref["objective"])
    gap = (pr.objective(x) - f_star) / (1.0 + abs(f_star))
    x_ref = pr.reference_x()
    measures = {"violation": violation, "gap": gap,
                "x_error": None if x_ref is None else float(np.max(np.abs(x - x_ref), initial=0.0))}
    problems = []
    if violation > tol["feas"]:
        problems.append(f"infeasible by {violation:.2e} (tol {tol['feas']:.0e})")
    if gap > tol["opt"]:
        problems.append(f"suboptimal by {gap:.2e} (tol {tol['opt']:.0e})")
    if problems:
        return "wrong", {**measures, "detail": "success reported but " + " and ".join(problems)}
    return "correct", {**measures, "detail": ""}


def _child(conn, config: str, problem: dict[str, Any], settings: str, log: str) -> None:
    """Runs in the child: solve, send {"outcome", "wall_s", "cpu_s"} or {"crash": text}. The child's
    stdout and stderr go to ``log`` (a panic's or abort's message is read from there)."""
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    try:
        from amcp_drake.studies.solver_matrix.solvers import Unavailable, solve

        pr = CorpusProblem.from_dict(problem)
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            outcome = solve(config, pr, settings)
        except Unavailable as exc:
            conn.send({"unavailable": str(exc)})
            return
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        conn.send({"outcome": asdict(outcome), "wall_s": outcome.detail.get("solve_wall_s", wall),
                   "cpu_s": outcome.detail.get("solve_cpu_s", cpu)})
    except BaseException as exc:  # noqa: BLE001 - a panic (pyo3 PanicException) is a BaseException
        conn.send({"crash": f"{type(exc).__name__}: {exc}"[:500] + " | " + traceback.format_exc(limit=2)[-300:]})
    finally:
        conn.close()


def run_one(ctx, config: str, pr: CorpusProblem, settings: str, time_limit: float) -> Cell:
    """One solve in a child process; never raises for anything the child does."""
    parent, child = ctx.Pipe(duplex=False)
    fd, log = tempfile.mkstemp(prefix="amcp-solve-", suffix=".log")
    os.close(fd)
    proc = ctx.Process(target=_child, args=(child, config, pr.to_dict(), settings, log), daemon=True)
    proc.start()
    child.close()
    message, timed_out = None, False
    deadline = time.monotonic() + time_limit
    try:
        if parent.poll(time_limit):
            message = parent.recv()
        elif proc.is_alive():
            timed_out = True
    except (EOFError, OSError):
        message = None
    if timed_out or proc.is_alive():
        proc.join(max(0.0, min(1.0, deadline - time.monotonic())))
    if proc.is_alive():
        proc.kill()
        timed_out = message is None
    proc.join()
    parent.close()
    verdict, measures = classify(pr, message, proc.exitcode, timed_out, settings)
    try:
        tail = Path(log).read_text(errors="replace")[-400:].strip()
    finally:
        Path(log).unlink(missing_ok=True)
    if verdict == "crash" and tail:
        measures["detail"] = f"{measures['detail']}; output: {tail}"
    outcome = (message or {}).get("outcome", {})
    return Cell(problem=pr.id, solver=config, verdict=verdict, status=outcome.get("status", ""),
                wall_s=(message or {}).get("wall_s"), cpu_s=(message or {}).get("cpu_s"),
                violation=measures.get("violation"), gap=measures.get("gap"), x_error=measures.get("x_error"),
                detail=measures.get("detail", ""))


def context(preload: list[str] | None = None):
    """The multiprocessing context of the children (forkserver with :data:`PRELOAD` where the platform
    has it, spawn otherwise)."""
    if "forkserver" in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD if preload is None else preload)
        return ctx
    return multiprocessing.get_context("spawn")


@dataclass
class MatrixRun:
    settings: str
    time_limit: float
    configurations: list[str]
    problems: list[CorpusProblem]
    cells: list[Cell] = field(default_factory=list)
    wall_s: float = 0.0


def run_matrix(problems: list[CorpusProblem], configurations: list[str], settings: str = "default",
               time_limit: float = DEFAULT_TIME_LIMIT, progress: Callable[[Cell], None] | None = None) -> MatrixRun:
    """Every configuration on every problem, one child process at a time (the machine is shared)."""
    if settings not in TOLERANCES:
        raise ValueError(f"settings {settings!r}: expected one of {sorted(TOLERANCES)}")
    stacks = {c.split(":", 1)[0] for c in configurations}
    ctx = context([PRELOAD[0], *(m for m, stack in zip(PRELOAD[1:], ("drake", "cvxpy")) if stack in stacks)])
    run = MatrixRun(settings, time_limit, list(configurations), list(problems))
    start = time.perf_counter()
    for pr in problems:
        for config in configurations:
            cell = run_one(ctx, config, pr, settings, time_limit)
            run.cells.append(cell)
            if progress is not None:
                progress(cell)
    run.wall_s = time.perf_counter() - start
    return run


def summary(run: MatrixRun) -> dict[str, dict[str, Any]]:
    """Per configuration: the count of each verdict and the median wall/CPU time of the correct solves."""
    out = {}
    for config in run.configurations:
        cells = [c for c in run.cells if c.solver == config]
        counts = {v: sum(c.verdict == v for c in cells) for v in VERDICTS}
        correct = [c for c in cells if c.verdict == "correct"]
        out[config] = {"counts": counts,
                       "median_wall_s": float(np.median([c.wall_s for c in correct])) if correct else None,
                       "median_cpu_s": float(np.median([c.cpu_s for c in correct])) if correct else None}
    return out


__all__ = ["DEFAULT_TIME_LIMIT", "PRELOAD", "TOLERANCES", "VERDICTS", "Cell", "MatrixRun", "classify", "context", "run_matrix",
           "run_one", "summary"]
