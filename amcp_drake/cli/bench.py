"""``amcp bench``: per-step times of the online loop; see :mod:`amcp_drake.studies.bench`."""

from __future__ import annotations

import sys

import click

from amcp_drake.cli.common import (
    EXIT_BAD_INPUT,
    EXIT_OK,
    bad_input_exits_2,
    candidate_budget_option,
    max_memory_option,
    output_dir_callback,
    parse_range,
)


@click.command("bench")
@click.option("--quick", is_flag=True, help="Short runs and small sweeps (a minute or less; for CI and tests).")
@click.option("--steps", type=int, default=None, help="Steps per Example 1 run (default 50, quick 10).")
@click.option("--scaling-steps", type=int, default=None, help="Steps per sweep point (default 30, quick 3).")
@click.option("--only", type=click.Choice(["example", "scaling", "section4", "size", "drake"]), default=None,
              help="Run only Example 1, only the sweeps over N, the facets of X0, p and n (one at a time around "
                   "Example 1; writes scaling.md, the table of benchmarks/README.md), only the Section 4 "
                   "options (PE, min-max cost, time-varying parameters) against the CE cost, or only the size "
                   "table (size.md: design and step cost of chains of n states, of the built-in examples with "
                   "n >= 4 and of --problem files, each row in a process of its own under --max-memory and "
                   "--row-limit; not part of a run without --only), or only the closed loop of Example 1 in a "
                   "Drake Diagram against amcp's simulator (drake: CPU per step, interleaved; not part of a run "
                   "without --only).")
@click.option("--problem", "problems", type=click.Path(exists=True, dir_okay=False), multiple=True,
              help="Size table: a problem file to add as a row (repeatable).")
@click.option("--example", "examples", multiple=True,
              help="Size table: the built-in examples to include (repeatable; default every one with n >= 4).")
@click.option("--chains", default="2-8", show_default=True,
              help="Size table: the state dimensions of the chain systems, A-B or one n (2..12).")
@click.option("--chain-kind", "chain_kinds", type=click.Choice(["actuated", "integrator"]), multiple=True,
              help="Size table: chain families (repeatable; default both).")
@click.option("--mass-chain", "mass_chains", type=click.IntRange(min=2, max=12), multiple=True,
              help="Size table: a mass-spring chain with this many masses (n = 2 x masses; repeatable; default 5, 6 "
                   "and 8, none with --no-chains).")
@click.option("--no-chains", is_flag=True, help="Size table: no chain rows (only examples and --problem files).")
@max_memory_option
@candidate_budget_option
@click.option("--row-limit", "row_limit", type=click.FloatRange(min=1.0), default=None,
              help="Size table: CPU-time limit in seconds of one row (design and runs; 10 times as much wall time "
                   "at most); a row over it is killed and shows the reason (default 600).")
@click.option("--backend", "backends", type=click.Choice(["drake", "cvxpy"]), multiple=True,
              help="Backend(s) to time (repeatable; default both for Example 1, Drake for the sweeps).")
@click.option("--formulation", "formulations", type=click.Choice(["plain", "vertex", "fast"]), multiple=True,
              help="Tube QP formulation(s): plain (15) with Λ, (5b) at Θ_k's vertices, or fast = the vertex form "
                   "with the DAQP fast path (Drake only) (repeatable; default all three).")
@click.option("--target-repeats", type=int, default=None,
              help="How often the performance targets are timed on runs of their own (default 5, quick 1); a target "
                   "counts as met only when every repeat meets it.")
@click.option("--seed", type=int, default=0, show_default=True, help="Disturbance seed.")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="amcp-out/bench", show_default=True,
              callback=output_dir_callback,
              help="Directory for bench.json and bench.png.")
@click.option("--no-plot", is_flag=True, help="Write the JSON only.")
@bad_input_exits_2
def bench_cmd(quick, steps, scaling_steps, only, problems, examples, chains, chain_kinds, mass_chains, no_chains,
              max_memory,
              candidate_budget, row_limit, backends, formulations, target_repeats, seed, out_dir, no_plot):
    """Performance benchmarks of the online loop (medians, ratios).

    Times the online loop, CPU (thread time) and wall: set update, LMS, QP, QP solver, everything
    outside the solvers and the total per step (median, p90), Example 1 with X0 of 4 and 8 facets,
    both backends, plain / vertex / fast path, run in lockstep (ratios from the same run); then sweeps
    over N, the facets of X0, p and n with design times. Writes JSON, a PNG and scaling.md.

    ``--only size`` writes the size table (size.md): per system (chains of n = 2..8 states, the built-in
    examples with n >= 4, --problem files) the design's CPU time, template, X0 facets and vertices, X_f
    rows, the step CPU time of the plain form, the vertex form and the DAQP fast path, the form
    formulation='auto' chooses, and the peak memory; each row in a child process limited by --max-memory
    (plus the libraries' own address space) and --row-limit."""
    from amcp_drake.studies.bench import BenchSettings, format_summary, run_benchmarks, write_outputs

    changes = {"seed": seed, "only": only}
    if steps is not None:
        changes["steps"] = steps
    if scaling_steps is not None:
        changes["scaling_steps"] = scaling_steps
    if target_repeats is not None:
        changes["target_repeats"] = target_repeats
    if backends:
        changes["backends"] = changes["scaling_backends"] = tuple(dict.fromkeys(backends))
    if formulations:
        changes["formulations"] = tuple(dict.fromkeys(formulations))
    if only == "size":
        from amcp_drake.model.examples import get_example

        for name in examples:
            get_example(name)  # ProblemError naming --example for an unknown name
        changes.update(size_chain_ns=() if no_chains else parse_range("--chains", chains, 2, 12),
                       size_chain_kinds=tuple(dict.fromkeys(chain_kinds)) or None,
                       size_examples=tuple(dict.fromkeys(examples)) or None, size_problems=tuple(problems),
                       size_mass_chains=tuple(dict.fromkeys(mass_chains)) or (() if no_chains else (5, 6, 8)),
                       max_memory_mb=max_memory, candidate_seconds=candidate_budget)
        if row_limit is not None:
            changes["row_seconds"] = row_limit
    for name in ("steps", "scaling_steps", "target_repeats"):
        if name in changes and changes[name] < 1:
            click.echo(f"error: --{name.replace('_', '-')} must be >= 1, got {changes[name]}", err=True)
            sys.exit(EXIT_BAD_INPUT)
    settings = BenchSettings.quick_settings(**changes) if quick else BenchSettings(**changes)
    result = run_benchmarks(settings, progress=lambda msg: click.echo(msg, err=True))
    paths = write_outputs(result, out_dir, plot=not no_plot)
    click.echo(format_summary(result))
    click.echo(f"results: {', '.join(str(p) for p in paths.values())}")
    sys.exit(EXIT_OK)
