"""Verification campaigns on Dask distributed.

``run_campaign`` draws problem ``idx`` of campaign ``seed`` from the library's numpy generator
(:func:`amcp_drake.studies.random_problems.random_case`, seeded per problem by :func:`problem_seed`;
the property suite's Hypothesis strategies build on it), runs the closed loop on every requested
backend, certifies each run with the independent checks of :func:`amcp_drake.certificate.certify.certify`, and stores the result in SQLite as
soon as it arrives (:mod:`amcp_drake.studies.campaign_store`). The work fans out on a Dask
``LocalCluster`` (default) or an existing scheduler (``scheduler="tcp://..."``); no home-made
queue. A task whose worker dies is re-run by Dask (``retries``); an interrupted campaign resumes
with ``resume=True`` by skipping the indices already stored, and only with the settings the store
was made with (:func:`campaign_settings`, recorded in the store).

Replays. Each drawn case becomes a complete problem file first
(:func:`replay_spec`: problem, design options, ``online`` options, x0, θ*, steps and the explicit
disturbance array), which is serialised and parsed back; the campaign then runs *that* file through
:func:`amcp_drake.online.replay.run_scenario`, the function ``amcp certify PROBLEM`` runs, with the offline
design on :data:`DESIGN_BACKEND` and the formulation :data:`FORMULATION` (:data:`LARGE_FORMULATION`,
the automatic choice, for campaigns over other state dimensions). A failing problem is saved
as that very file plus ``replay.json`` (the commands, settings, library versions and the recorded
verdict and margins) and the trajectories; ``amcp certify D/problem.json --backend B
--design-backend drake --formulation plain`` repeats the same computation and prints the same
verdict and margins (tests/test_campaign_replay.py).
"""

from __future__ import annotations

import json
import shlex
import time
import traceback
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

#: Steps of every closed loop in a campaign (long enough for Θ_k to shrink, short enough for 1000s).
CAMPAIGN_STEPS = 15
#: A state/input constraint row within this of 1 counts as "active" in the coverage figures.
ACTIVE_TOL = 0.02
#: Dask re-runs a task this many times when its worker dies.
TASK_RETRIES = 2
#: The generator of campaign problems and its version: a store records it (``generator`` setting), so a
#: store made with another generator is never resumed. Change it whenever problem ``idx`` of a seed
#: would come out different (another generator, or a change of random_problems' draws).
#: Version 2: the online options draw the exact update (7) too (the problems are those of 1).
#: Version 3: 1/4 of the problems are written in badly scaled state units
#: (``ProblemShape.scaled_states``); every later draw of a seed moves.
#: Version 4: the same draws, but the design is made in state units normalised by W
#: (offline/units.py), so which draws design, their X0 and the initial states drawn from it move.
#: Version 5: problems with input uncertainty and p <= n are pinned too (w_0 chosen for the
#: controller's first input u_0, studies/pinning.py); the pin draw then moves every later draw of a seed.
#: Same version: a W whose largest extent is outside offline/units.EXTENT_BAND is designed at another
#: common scale (a scaled draw with every state in units 1e-2 and extents below 0.01).
GENERATOR_VERSION = "amcp_drake.studies.random_problems.random_case/5"
#: The offline design of every campaign problem is computed on this backend; every online backend
#: then runs on that design (as the property suite does), and the replay command names it.
DESIGN_BACKEND = "drake"
#: The tube QP formulation of campaign runs (``--formulation`` of the replay command).
FORMULATION = "plain"
#: The formulation of campaigns over other state dimensions than the default (``--state-dims``): the one
#: ``--formulation auto`` chooses (:mod:`amcp_drake.online.formulation_choice`). The cvxpy plain form
#: keeps every row of (15c) with its multipliers: on a generated problem of 6 states (X0 with 21 facets and
#: 199 vertices, N = 10, p = 3) compiling it took more than 4 minutes of CPU and 1.6 GB before its first
#: step, where the vertex form that "auto" chooses there takes seconds.
LARGE_FORMULATION = "auto"


def campaign_formulation(state_dims: tuple[int, int] | None) -> str:
    """The formulation of a campaign's runs: :data:`FORMULATION` for the default state dimensions,
    :data:`LARGE_FORMULATION` for any other range."""
    from amcp_drake.studies.random_problems import DEFAULT_STATE_DIMS

    return FORMULATION if state_dims is None or tuple(state_dims) == DEFAULT_STATE_DIMS else LARGE_FORMULATION
#: Packages whose versions are recorded with a store and a replay (they determine the numbers).
RESULT_PACKAGES = ("amcp-drake", "drake", "cvxpy", "clarabel", "numpy", "scipy", "hypothesis")
#: The file format of the replay manifest written next to a failing problem's problem.json.
REPLAY_FORMAT, REPLAY_VERSION = "amcp-campaign-replay", 1


def problem_seed(campaign_seed: int, idx: int) -> int:
    """The numpy seed of problem ``idx`` (reproducible, distinct across campaigns)."""
    return (int(campaign_seed) * 1_000_003 + int(idx)) % (2**32)


def draw_case(campaign_seed: int, idx: int, steps: int = CAMPAIGN_STEPS, state_dims: tuple[int, int] | None = None,
              max_memory_mb: float | None = None):
    """Problem ``idx`` of campaign ``campaign_seed``: the library's numpy generator
    (:func:`amcp_drake.studies.random_problems.random_case`, the one the property suite's strategies
    build on) with the generator seeded by :func:`problem_seed` (reproducible per (seed, index)).

    ``state_dims`` = (min n, max n) (``--state-dims``; None: the generator's default 1 … 3, drawn as
    always). With other dimensions every design of the draws runs under a budget (``max_memory_mb``
    and :data:`~amcp_drake.offline.budget.DEFAULT_CANDIDATE_SECONDS` per candidate of the automatic
    design), so that no draw can hold a worker for long."""
    from amcp_drake.studies.random_problems import DEFAULT_STATE_DIMS, random_case

    rng = np.random.default_rng(problem_seed(campaign_seed, idx))
    if state_dims is None or tuple(state_dims) == DEFAULT_STATE_DIMS:
        return random_case(rng, steps)
    from amcp_drake.offline.budget import DEFAULT_CANDIDATE_SECONDS, DesignBudget

    budget = DesignBudget(candidate_seconds=DEFAULT_CANDIDATE_SECONDS) if max_memory_mb is None else \
        DesignBudget(max_memory_mb, DEFAULT_CANDIDATE_SECONDS)
    return random_case(rng, steps, state_dims=tuple(state_dims), budget=budget)


def library_versions() -> dict[str, str]:
    """Installed versions of :data:`RESULT_PACKAGES` ("not installed" for a missing one)."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in RESULT_PACKAGES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "not installed"
    return out


def campaign_settings(seed: int, systems: int, backends: Iterable[str], steps: int,
                      state_dims: tuple[int, int] | None = None) -> dict[str, Any]:
    """Everything that determines a campaign's results, as recorded in its store:
    a store made with other settings is never resumed (scheduler and workers do not change results
    and are not recorded). ``state_dims`` is recorded only when it is not the default (1, 3), so that
    stores made before the option keep their settings."""
    from amcp_drake.studies.random_problems import DEFAULT_STATE_DIMS

    settings = {"seed": int(seed), "systems": int(systems), "backends": list(backends), "steps": int(steps),
                "generator": GENERATOR_VERSION, "design_backend": DESIGN_BACKEND,
                "formulation": campaign_formulation(state_dims), "versions": library_versions()}
    if state_dims is not None and tuple(state_dims) != DEFAULT_STATE_DIMS:
        settings["state_dims"] = [int(state_dims[0]), int(state_dims[1])]
    return settings


def replay_spec(case):
    """The complete problem file of a drawn case
    (:func:`amcp_drake.studies.random_problems.complete_spec`: problem, design options, the online
    options of the run, and a scenario with x0, θ*, steps and the explicit disturbance array), so
    that the file alone determines the run."""
    from amcp_drake.studies.random_problems import complete_spec

    return complete_spec(case)


def round_trip(spec) -> tuple[Any, str]:
    """``spec`` written as problem-file JSON and parsed back: (the parsed spec, the exact text). The
    campaign runs the parsed spec, so what it saves is what it ran."""
    from amcp_drake.model.problem_io import spec_from_dict, spec_to_dict

    text = json.dumps(spec_to_dict(spec), indent=1, allow_nan=False)
    return spec_from_dict(json.loads(text)), text


def replay_command(folder: str | Path, backend: str, formulation: str = FORMULATION) -> str:
    """The shell command that replays ``backend``'s run of the failing problem saved in ``folder``."""
    folder = Path(folder)
    return shlex.join(["amcp", "certify", str(folder / "problem.json"), "--backend", backend, "--design-backend",
                       DESIGN_BACKEND, "--formulation", formulation, "--out", str(folder / f"replay-{backend}")])


def save_replay(folder: str | Path, text: str, result: dict[str, Any], trajs: dict,
                formulation: str = FORMULATION) -> list[str]:
    """Write a failing problem's replay into ``folder`` (problem.json, replay.json, one trajectory per
    backend), each file atomically; return the replay commands of the backends that did not pass."""
    from amcp_drake.model.problem_io import write_json_atomic, write_text_atomic

    folder = Path(folder)
    write_text_atomic(text, folder / "problem.json")
    for backend, traj in trajs.items():
        traj.save(folder / f"trajectory-{backend}.json.gz")
    runs = {}
    for backend, claims in result["claims"].items():
        runs[backend] = {"command": replay_command(folder, backend, formulation), "backend": backend,
                         "design_backend": DESIGN_BACKEND, "formulation": formulation,
                         "backend_options": {"formulation": formulation},
                         "verdict": result["verdicts"][backend], "claims": claims}
    failing = [b for b, claims in result["claims"].items() if any(c["status"] != "pass" for c in claims.values())]
    manifest = {"format": REPLAY_FORMAT, "version": REPLAY_VERSION, "campaign_seed": result["campaign_seed"],
                "idx": result["idx"], "generator": GENERATOR_VERSION, "digest": result.get("digest"),
                "labels": result.get("labels", {}), "failing_backends": failing, "runs": runs,
                "versions": library_versions()}
    write_json_atomic(manifest, folder / "replay.json")
    return [runs[b]["command"] for b in failing]


def _coverage(traj) -> dict[str, float]:
    """Did the run exercise the claims? Constraints active, Θ_k shrinking, θ* near ∂Θ_k, and the
    hard cases (:func:`~amcp_drake.studies.random_problems.hard_case_coverage`: a
    lower-dimensional Θ_k, θ* at a vertex / on a facet of Θ)."""
    from amcp_drake.studies.random_problems import hard_case_coverage, theta_shrank

    pr = traj.problem
    z = max((pr.in_Z(x, u) for x, u in zip(traj.x, traj.u)), default=-np.inf)
    closeness = min(float(np.min(r.h_theta - r.H_theta @ traj.theta_star)) for r in traj.records)
    return {"constraints_active": float(z > -ACTIVE_TOL), "theta_shrank": float(theta_shrank(traj)),
            "theta_star_near_boundary": float(closeness < 1e-2), **hard_case_coverage(traj)}


def _resolve_counts(traj, backend: str, formulation: str = FORMULATION) -> dict[str, float]:
    """How many steps of the run needed more than the first solve, per kind of
    :data:`amcp_drake.studies.resolves.RESOLVE_KINDS` that can occur in a campaign run: the vertex
    form's fall back to the plain form only with :data:`FORMULATION` "vertex", the reduced plain
    form's fall back to every row of (15c) only in the Drake backend's plain form (the cvxpy plain
    form always has every row), the min–max QP's re-solve at the default tolerances only in a run with
    the min–max cost (19) (the campaign draws the certainty-equivalence cost), the fall back from the
    compiled route to ``Problem.solve`` only in the cvxpy vertex form, the optimality re-solve only in
    the cvxpy plain form. Keys ``resolve_<kind>``;
    the summary shows the fraction of problems with at least one such step (for every_row: how often
    the campaign did not test the reduced program alone). With ``formulation`` "auto" the form the
    controller chose (the trajectory's ``meta["formulation"]``) decides."""
    from amcp_drake.studies.resolves import count_resolves, step_kinds

    if formulation == "auto":
        formulation = (getattr(traj, "meta", None) or {}).get("formulation", FORMULATION)

    counts = count_resolves([step_kinds(r) for r in traj.records])
    minmax = getattr(getattr(traj, "options", None), "cost", "certainty_equivalence") == "minmax"
    applies = {"plain_fallback": formulation == "vertex", "every_row": formulation == "plain" and backend == "drake",
               "minmax_default_tolerances": minmax,
               "compiled_route_fallback": formulation == "vertex" and backend == "cvxpy",
               "optimality_resolve": formulation == "plain" and backend == "cvxpy"}
    return {f"resolve_{kind}": float(n) for kind, n in counts.items() if applies.get(kind, True)}


def _answer_counts(traj) -> dict[str, float]:
    """How the run's solver answers were obtained (:func:`amcp_drake.online.answers.counts`), as coverage keys
    ``answers_<problem>_<count>`` (``answers_tube_qp_answers``, ``answers_tube_qp_fallback_vertex_form``, ...):
    the summary reports, per backend and kind, the share of answers that were not the backend's own."""
    from amcp_drake.online import answers

    return {f"answers_{problem}_{key.replace(' ', '_')}": float(n)
            for problem, per in answers.counts(traj.records).items() for key, n in per.items()}


def run_problem(campaign_seed: int, idx: int, backends: tuple[str, ...], failure_dir: str,
                steps: int = CAMPAIGN_STEPS, draw: Callable | None = None,
                max_memory_mb: float | None = None, state_dims: tuple[int, int] | None = None) -> dict[str, Any]:
    """Draw, run and certify problem ``idx`` on each backend (a Dask task; also callable directly).

    ``draw(campaign_seed, idx, steps)`` returns the case (default :func:`draw_case`); the run is that
    of the case's complete problem file (:func:`replay_spec`, :func:`round_trip`), through the same
    :func:`~amcp_drake.online.replay.run_scenario` as ``amcp certify``. ``max_memory_mb``: the memory limit
    of the design's stages (``--max-memory``; None: the default limit); a problem above it is recorded as an
    error naming the stage. ``state_dims``: the state dimensions drawn (:func:`draw_case`)."""
    from amcp_drake.certificate.certify import certify
    from amcp_drake.offline.budget import DEFAULT_CANDIDATE_SECONDS, DesignBudget
    from amcp_drake.offline.design import design
    from amcp_drake.online.replay import run_scenario
    from amcp_drake.online.run_size import check_run_size
    from amcp_drake.studies.random_problems import DEFAULT_STATE_DIMS, built_scaled

    start = time.perf_counter()
    formulation = campaign_formulation(state_dims)
    result: dict[str, Any] = {"campaign_seed": campaign_seed, "idx": idx, "claims": {}, "coverage": {},
                              "verdicts": {}}
    try:
        if draw is not None:
            case = draw(campaign_seed, idx, steps)
        else:
            case = draw_case(campaign_seed, idx, steps, state_dims, max_memory_mb)
        result["labels"] = {k: str(v) for k, v in getattr(case, "labels", {}).items()}
        spec, text = round_trip(replay_spec(case))
        result["digest"] = _digest(text)
        budget = DesignBudget() if max_memory_mb is None else DesignBudget(max_memory_mb)
        if state_dims is not None and tuple(state_dims) != DEFAULT_STATE_DIMS:  # as the draw was designed
            budget = DesignBudget(budget.max_memory_mb, DEFAULT_CANDIDATE_SECONDS)
        offline = design(spec.problem, spec.design, backend=DESIGN_BACKEND, budget=budget)
        # the run's size with the design found, before the controllers are built (as amcp certify)
        check_run_size(spec.problem, spec.design, spec.scenario.steps, spec.online, budget.max_memory_mb,
                       design=offline, formulation=formulation)
        trajs = {}
        for backend in backends:
            traj = run_scenario(spec, backend, design_backend=DESIGN_BACKEND, formulation=formulation,
                                offline=offline)
            trajs[backend] = traj
            cert = certify(traj, spec)
            result["claims"][backend] = {c.name: {"status": c.status, "margin": c.margin} for c in cert.claims}
            result["verdicts"][backend] = cert.verdict
            result["coverage"][backend] = {**_coverage(traj), **_resolve_counts(traj, backend, formulation),
                                           **_answer_counts(traj),
                                           # built, not reached: the generator's label is exact
                                           "scaled_units": float(bool(built_scaled(result["labels"])))}
        # a premise not met (x0 outside the feasible region of (20): a generator defect) fails the problem too,
        # although its claims that did not pass are then "not claimed" (certificate.premises)
        failed = (any(c["status"] != "pass" for claims in result["claims"].values() for c in claims.values())
                  or any(v != "pass" for v in result["verdicts"].values()))
        result["status"] = "fail" if failed else "pass"
        if failed:
            folder = Path(failure_dir) / f"{campaign_seed}-{idx}"
            result["replay"] = save_replay(folder, text, result, trajs, formulation)
            result["failure_dir"] = str(folder)
    except Exception as exc:  # noqa: BLE001 - any crash of one problem is a recorded result, not a lost one
        result["status"] = "error"
        result["message"] = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=5)}"
    result["seconds"] = time.perf_counter() - start
    return result


def _digest(text: str) -> str:
    """SHA-1 of a problem file's text (identifies the run: the file determines it)."""
    import hashlib

    return hashlib.sha1(text.encode()).hexdigest()


#: Seconds to wait for an existing Dask scheduler to accept a connection (``--scheduler``).
SCHEDULER_TIMEOUT = 10
#: Address schemes of a Dask scheduler that ``--scheduler`` accepts.
SCHEDULER_SCHEMES = ("tcp", "tls", "ws", "wss")


def check_scheduler(address: str, timeout: float = SCHEDULER_TIMEOUT) -> None:
    """``address`` must be a Dask scheduler address (``tcp://host:port``) that accepts a TCP connection
    within ``timeout`` seconds; ProblemError naming ``--scheduler`` otherwise (checked before the store is
    touched, so a bad address writes nothing)."""
    import socket
    from urllib.parse import urlsplit

    from amcp_drake.model.errors import ProblemError

    expected = "an address of a Dask scheduler, scheme://host:port (e.g. tcp://host:port)"
    try:
        parts = urlsplit(address)
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise ProblemError("--scheduler", expected, f"{address!r} ({exc})") from None
    if parts.scheme not in SCHEDULER_SCHEMES or not host or port is None or parts.path not in ("", "/"):
        raise ProblemError("--scheduler", expected + f"; schemes {', '.join(SCHEDULER_SCHEMES)}", repr(address))
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as exc:
        raise ProblemError("--scheduler", "a reachable Dask scheduler",
                           f"{address}: {exc.strerror or exc or 'no answer'} (nothing was written)") from None


def _connect(scheduler: str):
    """A Dask Client of the scheduler at ``scheduler``; ProblemError naming ``--scheduler`` when it does
    not answer as a scheduler within :data:`SCHEDULER_TIMEOUT` seconds."""
    from dask.distributed import Client

    from amcp_drake.model.errors import ProblemError

    try:
        return Client(scheduler, timeout=SCHEDULER_TIMEOUT)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ProblemError("--scheduler", "a reachable Dask scheduler",
                           f"{scheduler}: {exc} (nothing was written)") from None


#: Loggers of the local Dask workers set to errors only: the worker state machine warns "Async instruction
#: ... ended with CancelledError" for the task a shutdown cancels.
QUIET_WORKER_LOGGERS = ("distributed.worker.state_machine",)


def _local_cluster(workers: int):
    """A LocalCluster whose worker processes ignore SIGINT (they inherit the ignored signal): Ctrl-C
    reaches this process, which shuts the workers down itself, instead of every worker printing a
    KeyboardInterrupt traceback. Its HTTP endpoints listen on a free loopback port (no dashboard)."""
    import signal
    import threading

    from dask.distributed import Client, LocalCluster

    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN) if main else None
    try:
        # no dashboard; the scheduler's HTTP endpoints on a free port of the loopback interface, so that
        # another Dask process on the machine (holding port 8787) causes no "port in use" warning
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               scheduler_kwargs={"dashboard": False, "dashboard_address": "127.0.0.1:0"})
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)
    try:
        client = Client(cluster)
        client.run(_quiet_worker_logs)
        return cluster, client
    except BaseException:
        cluster.close()
        raise


def _quiet_worker_logs() -> None:
    """Run in each local worker process: the loggers of :data:`QUIET_WORKER_LOGGERS` report errors only
    (a task cancelled by a shutdown is otherwise reported as a warning by every worker), and Drake's log
    below WARNING is dropped (:func:`~amcp_drake.backends.drake_log.drop_drake_info`)."""
    import logging

    from amcp_drake.backends.drake_log import drop_drake_info

    for name in QUIET_WORKER_LOGGERS:
        logging.getLogger(name).setLevel(logging.ERROR)
    drop_drake_info()


def _silence_worker_logs_for_shutdown() -> None:
    """Run in each local worker just before the cluster closes: Dask's loggers report nothing (a
    worker whose heartbeat reaches a scheduler that has just closed logs "Failed to communicate with
    scheduler during heartbeat" as an error, with a traceback, although nothing has failed)."""
    import logging

    names = ["distributed", *(name for name in logging.root.manager.loggerDict if name.startswith("distributed."))]
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL)


def store_write_error(store_path: str | Path, exc: BaseException):
    """A CampaignStoreError naming ``--store`` for a failed write of the store (a full disk, an I/O
    error): the transaction being written was rolled back, the problems stored before it are kept."""
    from amcp_drake.model.errors import CampaignStoreError

    return CampaignStoreError("--store", "a store on a disk it can be written to",
                              f"{store_path}: {exc} (the problem being written was not stored)",
                              "Free some space, then continue with --resume: every problem stored before is kept.")


def run_campaign(store_path: str | Path, systems: int, backends: Iterable[str] = ("drake", "cvxpy"),
                 seed: int = 0, scheduler: str | None = None, workers: int = 2, resume: bool = False,
                 steps: int = CAMPAIGN_STEPS, progress: bool = True, failure_dir: str | Path | None = None,
                 max_memory_mb: float | None = None, state_dims: tuple[int, int] | None = None) -> dict:
    """Run (or resume) a campaign; returns counts {"submitted", "stored", "skipped"}.

    The store is held exclusively while the campaign runs (:class:`CampaignStore` ``exclusive``): a
    second campaign on the same store is refused (CampaignStoreError, exit 2), so no problem is run
    twice. A bad ``scheduler`` is refused before the store is touched. An interrupt (KeyboardInterrupt,
    which the CLI raises on SIGTERM too) shuts the workers down and propagates with ``stored``: the
    number of problems of the campaign in the store. ``max_memory_mb``: the design's memory limit in
    every problem (:func:`run_problem`). ``state_dims``: (min n, max n) of the drawn problems (None: the
    generator's default)."""
    import sqlite3

    from dask.distributed import as_completed

    from amcp_drake.model.errors import ProblemError
    from amcp_drake.studies.campaign_store import CampaignStore

    backends = tuple(backends)
    if scheduler:
        check_scheduler(scheduler)
    store = CampaignStore(store_path, exclusive=True)  # CampaignStoreError (exit 2): damaged, foreign or in use
    try:
        try:
            store.require_settings(campaign_settings(seed, systems, backends, steps, state_dims))
        except (sqlite3.OperationalError, OSError) as exc:
            raise store_write_error(store_path, exc) from None
        done = store.done(seed)
        if done and not resume:
            raise ProblemError("--store", f"a new store, or --resume to continue campaign seed {seed}",
                               f"{store_path} already holds {len(done)} problems of that campaign")
        client, cluster = (_connect(scheduler), None) if scheduler else _local_cluster(workers)[::-1]
    except BaseException:
        store.close(discard_new=True)
        raise
    todo = [i for i in range(systems) if i not in done]
    failure_dir = str(failure_dir or Path(store_path).with_suffix("").as_posix() + "-failures")
    stored = 0
    bar = None
    try:
        futures = [client.submit(run_problem, seed, i, backends, failure_dir, steps, key=f"amcp-{seed}-{i}",
                                 retries=TASK_RETRIES, pure=False, max_memory_mb=max_memory_mb,
                                 state_dims=state_dims) for i in todo]
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=systems, initial=len(done), desc="campaign", unit="problem")
        failures = 0
        for future in as_completed(futures):
            result = future.result()
            try:
                stored += store.add(result)
            except (sqlite3.OperationalError, OSError) as exc:
                raise store_write_error(store_path, exc) from None
            failures += result["status"] != "pass"
            if bar is not None:
                bar.set_postfix(failures=failures)
                bar.update(1)
        if bar is not None:
            bar.close()
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):
            exc.stored = len(done) + stored
        if bar is not None:
            bar.close()  # ends the progress line, so that the CLI's message (interrupt, full disk) stands alone
        raise
    finally:
        _shut_down(client, cluster)
        store.close(discard_new=True)
    return {"submitted": len(todo), "stored": stored, "skipped": len(done)}


def _shut_down(client, cluster) -> None:
    """Close the client and the local cluster quietly (the workers' closing chatter on stderr is not an
    error); a second interrupt during the shutdown is ignored so that the workers are always stopped."""
    import logging
    import signal
    import threading

    main = threading.current_thread() is threading.main_thread()
    saved = {sig: signal.signal(sig, signal.SIG_IGN) for sig in (signal.SIGINT, signal.SIGTERM)} if main else {}
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        if cluster is not None:  # our own workers: their heartbeats to the closing scheduler fail, say nothing
            try:
                client.run(_silence_worker_logs_for_shutdown, wait=True)
            except Exception:  # noqa: BLE001 - a worker already gone needs no silencing
                pass
        client.close()
        if cluster is not None:
            cluster.close()
    finally:
        quiet.setLevel(level)
        for sig, handler in saved.items():
            signal.signal(sig, handler)
