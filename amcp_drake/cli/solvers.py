"""``amcp solvers``: the solver conformance matrix on the corpus of this scheme's problems; see
:mod:`amcp_drake.studies.solver_matrix`."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from amcp_drake.cli.common import (
    EXIT_OK,
    FiniteFloatRange,
    bad_input_exits_2,
    nonempty_path_callback,
    output_dir_callback,
    write_error,
)
from amcp_drake.model.errors import ProblemError


@click.command("solvers")
@click.option("--corpus", "corpus", type=click.Path(), multiple=True, callback=nonempty_path_callback,
              help="Corpus file(s) or folder(s) (*.json, *.json.gz; repeatable). Default: the corpus shipped with "
                   "the package.")
@click.option("--solvers", "solvers", default=None,
              help="Comma-separated configurations: drake:NAME (clarabel, osqp, scs, clp, csdp, ipopt, nlopt, snopt, "
                   "mosek, gurobi), cvxpy:NAME (CLARABEL, OSQP, SCS, ECOS, DAQP, PIQP, HIGHS, PROXQP, MOSEK) or "
                   "py:MODULE:FUNCTION. Default: every one installed and licensed here.")
@click.option("--settings", type=click.Choice(["default", "tight"]), default="default", show_default=True,
              help="Solver options: the solvers' defaults, or tolerances near 1e-9 (judged at 1e-8 instead of 1e-6).")
@click.option("--kind", "kinds", multiple=True, help="Only problems of this kind (repeatable), e.g. tube_qp_plain.")
@click.option("--time-limit", type=FiniteFloatRange(min=0.1, max=3600), default=20.0, show_default=True,
              help="Seconds per solve before its child process is killed (verdict: timeout).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="amcp-out/solvers", show_default=True,
              callback=nonempty_path_callback,
              help="Directory for solvers.json, solvers.html and reproducers/ (with its manifest.json), written "
                   "all at once when the matrix has run.")
@click.option("--no-reproducers", is_flag=True, help="Do not write the standalone reproducers.")
@click.option("--recheck", "recheck_dir", type=click.Path(), default=None, callback=nonempty_path_callback,
              help="Only re-run the reproducers of this folder that its manifest.json vouches for (written by amcp "
                   "solvers, unchanged) and say which still reproduce; any other file is reported and not run.")
@click.option("--export-corpus", "export_dir", type=click.Path(file_okay=False), default=None,
              callback=output_dir_callback,
              help="Only export the corpus from recorded runs of the shipped examples (the built-in ones and "
                   "every file of --examples), of --generated generated problems and of the hard cases of "
                   "--hard-cases, and generated projections (12) onto each example's Θ, into this folder (each "
                   "reference verified).")
@click.option("--steps", type=click.IntRange(min=1, max=200), default=6, show_default=True,
              help="With --export-corpus: closed-loop steps per run.")
@click.option("--hard-cases", type=click.Path(file_okay=False), default="tests/data", show_default=True,
              callback=nonempty_path_callback,
              help="With --export-corpus: the folder of recorded hard cases (skipped if absent).")
@click.option("--examples", "examples_dir", type=click.Path(file_okay=False), default="examples", show_default=True,
              callback=nonempty_path_callback,
              help="With --export-corpus: a folder of problem files <name>.json exported besides the built-in "
                   "examples (skipped if absent).")
@click.option("--generated", type=click.IntRange(min=0, max=1000), default=4, show_default=True,
              help="With --export-corpus: how many generated problems (problems 0 … N-1 of --generated-seed, "
                   "drawn as amcp campaign draws them).")
@click.option("--generated-seed", type=click.IntRange(min=0, max=2**31 - 1), default=0, show_default=True,
              help="With --export-corpus: the campaign seed of the generated problems.")
@bad_input_exits_2
def solvers_cmd(corpus, solvers, settings, kinds, time_limit, out_dir, no_reproducers, recheck_dir, export_dir, steps,
                hard_cases, examples_dir, generated, generated_seed):
    """Solve every corpus problem with every solver reachable through Drake and through cvxpy, each in its
    own child process with a time limit, and classify each (solver, problem): correct, honest failure,
    wrong (success reported, answer infeasible or suboptimal beyond the tolerance), crash, timeout.
    Prints the matrix; writes solvers.json, solvers.html and one standalone reproducer per wrong/crash
    class. The matrix is a study: the exit code is 0 whatever it finds (2 for bad input: a corpus file
    malformed or whose reference does not verify again, an output that cannot be written)."""
    if recheck_dir is not None:
        _recheck(Path(recheck_dir))
    if export_dir is not None:
        _export(Path(export_dir), steps, Path(hard_cases), Path(examples_dir), generated, generated_seed)
    from amcp_drake.model.problem_io import check_output_dir
    from amcp_drake.studies.solver_matrix.corpus import KINDS, shipped_corpus_dir
    from amcp_drake.studies.solver_matrix.reference import load_checked_corpus
    from amcp_drake.studies.solver_matrix.report import terminal_table, to_json, write_outputs
    from amcp_drake.studies.solver_matrix.reproducers import previous_reproducers, write_reproducers
    from amcp_drake.studies.solver_matrix.runner import run_matrix
    from amcp_drake.studies.solver_matrix.solvers import available_configurations
    from amcp_drake.studies.solver_matrix.staging import staged

    out = check_output_dir("--out", out_dir)   # before the matrix runs, not after

    for kind in kinds:
        if kind not in KINDS:
            raise ProblemError("--kind", f"one of {sorted(KINDS)}", repr(kind))
    configs = None if solvers is None else [s.strip() for s in solvers.split(",") if s.strip()]
    for config in configs or ():
        stack, _, name = config.partition(":")
        if stack not in ("drake", "cvxpy", "py") or not name:
            raise ProblemError("--solvers", "drake:NAME, cvxpy:NAME or py:MODULE:FUNCTION, comma-separated", repr(config))
    problems = load_checked_corpus(list(corpus) or shipped_corpus_dir())
    if kinds:
        problems = [p for p in problems if p.kind in kinds]
    if configs is None:
        configs = available_configurations()
    if not configs or not problems:
        raise ProblemError("--solvers/--corpus", "at least one solver configuration and one problem",
                           f"{len(configs)} configurations, {len(problems)} problems")
    click.echo(f"{len(problems)} problems x {len(configs)} solver configurations, settings {settings}, "
               f"time limit {time_limit:g} s per solve", err=True)
    run = run_matrix(problems, configs, settings, time_limit,
                     progress=lambda c: click.echo(f"  {c.problem} {c.solver}: {c.verdict}", err=True))
    extra = {}
    previous = [] if no_reproducers else previous_reproducers(out / "reproducers")
    try:  # every file complete before any is in place; a failure leaves nothing (staging.py)
        with staged(out) as stage:
            if not no_reproducers:
                repros = write_reproducers(run, stage / "reproducers")
                extra["reproducers"] = [{"solver": r.solver, "verdict": r.verdict, "problem": r.problem,
                                         "file": r.path.name} for r in repros]
            data = to_json(run, {**extra, "command": " ".join(["amcp", *sys.argv[1:]])})
            write_outputs(stage, data)
    except OSError as exc:
        raise write_error("--out", out_dir, exc) from None
    json_path, html_path = out / "solvers.json", out / "solvers.html"
    if extra.get("reproducers"):   # an earlier run's own, unchanged scripts that this run did not write again
        for path in previous:
            if path.name not in {r["file"] for r in extra["reproducers"]}:
                try:
                    path.unlink(missing_ok=True)
                except OSError:   # left in place: a recheck lists it as not in the manifest
                    pass
    click.echo(terminal_table(run))
    click.echo(f"matrix wall time {run.wall_s:.1f} s; results: {json_path}, {html_path}")
    for r in extra.get("reproducers", []):
        click.echo(f"reproducer: {out / 'reproducers' / r['file']}")
    sys.exit(EXIT_OK)


def _recheck(folder: Path):
    from amcp_drake.studies.solver_matrix.reproducers import printable, recheck

    if not folder.is_dir():
        raise ProblemError("--recheck", "a folder of reproducers written by amcp solvers", str(folder))
    try:
        results = recheck(folder)
    except OSError as exc:
        raise ProblemError("--recheck", "a readable folder of reproducers", f"{folder}: {exc.strerror or exc}") from None
    for r in results:
        click.echo(f"{r.outcome:<22} {printable(r.script)}: {printable(r.last_line)}")
    ran = [r for r in results if r.outcome != "refused"]
    still = sum(r.outcome == "reproduces" for r in ran)
    click.echo(f"{still} of {len(ran)} reproducers still reproduce on the installed versions; "
               f"{sum(r.outcome == 'error' for r in ran)} ended in an error; "
               f"{len(results) - len(ran)} files refused (not run)")
    sys.exit(EXIT_OK)


def _export(folder: Path, steps: int, hard_cases: Path, examples: Path, generated: int, generated_seed: int):
    from amcp_drake.studies.solver_matrix.export import (
        example_names,
        example_sources,
        export_corpus,
        generated_sources,
        hard_case_sources,
        projection_sources,
    )

    names = example_names(examples)
    sources = list(example_sources(names, steps=steps, folder=examples))
    sources += list(example_sources(("lorenzen2019",), steps, backend="cvxpy"))
    sources += list(generated_sources(generated, generated_seed, steps))
    sources += list(projection_sources(names))
    if hard_cases.is_dir():
        sources += list(hard_case_sources(hard_cases))
    from amcp_drake.studies.solver_matrix.staging import staged

    try:  # every file complete before any is in place; a failure leaves nothing (staging.py)
        with staged(folder) as stage:
            index = export_corpus(stage, sources, progress=lambda msg: click.echo(msg, err=True))
    except OSError as exc:
        raise write_error("--export-corpus", folder, exc) from None
    click.echo(f"{len(index['problems'])} problems written to {folder} "
               f"({sum(p['bytes'] for p in index['problems'])} bytes); {len(index['left_out'])} left out "
               f"(reasons in {folder / 'index.json'})")
    sys.exit(EXIT_OK)
