"""``amcp pe-figure``: Proposition 23 measured (diameter of Θ_k with and without PE, over seeds)."""

from __future__ import annotations

import click

# What the commands share (options, loading, exit codes) is defined once in cli/common.py; the import
# list and the decorators below only name it, with this command's own defaults and help texts.
from amcp_drake.cli.common import (
    backend_option,
    bad_input_exits_2,
    check_run_size,
    echo,
    exit_verdict,
    load_problem_spec,
    max_memory_option,
    output_dir_callback,
    problem_options,
    seeds_option,
    steps_option,
)


@click.command("pe-figure")
@problem_options(x0_template=False)
@backend_option
@seeds_option("Disturbance seeds 0..seeds-1.", default=5)
@steps_option("Closed-loop steps per run.", default=500, minimum=2, show_default=True)
@click.option("--update", type=click.Choice(["exact", "window", "fixed"]), default="exact", show_default=True,
              help="Set update: (7) (Proposition 23's setting), (9) over a moving window, or (9).")
@click.option("--pe-window", type=click.IntRange(min=1), default=10, show_default=True, help="PE window P.")
@click.option("--pe-level", type=click.FloatRange(min=0.0, min_open=True), default=1.0, show_default=True,
              help="PE level ρ.")
@click.option("--out", "out_dir", default="amcp-out", show_default=True, type=click.Path(file_okay=False),
              callback=output_dir_callback)
@max_memory_option
@bad_input_exits_2
def pe_figure_cmd(problem_file, example, backend, seeds, steps, update, pe_window, pe_level, out_dir, max_memory):
    """Write pe_diameter.png and pe_diameter.json: diam Θ_k vs k with and without PE (Proposition 23).

    Exit code 0 when every run completed, 1 otherwise (the figure is still written)."""
    from amcp_drake.offline.design import design
    from amcp_drake.studies.pe_figure import run_pe_figure, write_pe_figure

    spec = load_problem_spec(problem_file, example)
    check_run_size(spec, steps, None, max_memory, formulation="plain")  # the PE constraint is the plain form's
    d = design(spec.problem, spec.design, backend=backend)
    check_run_size(spec, steps, None, max_memory, design=d, formulation="plain")

    def progress(label, seed):
        echo(f"  {label} seed {seed} ...", err=True)

    res = run_pe_figure(spec, d, seeds=seeds, steps=steps, update=update, pe_window=pe_window, pe_level=pe_level,
                        backend=backend, progress=progress)
    js, png = write_pe_figure(res, out_dir)
    ks = res["checkpoints"]
    echo(f"{res['problem']}: update {update}, {seeds} seeds, {steps} steps, PE window {pe_window}, level {pe_level:g}")
    echo("diam Θ_k, median [min, max] over seeds")
    echo("| k | " + " | ".join(str(k) for k in ks) + " |")
    echo("|---|" + "---|" * len(ks))
    for label, name in (("no_pe", "no PE"), ("pe", "PE")):
        r = res["runs"][label]
        cells = [f"{r['median_diameter'][k]:.3f} [{r['min_diameter'][k]:.3f}, {r['max_diameter'][k]:.3f}]" for k in ks]
        echo(f"| {name} | " + " | ".join(cells) + " |")
    for label, name in (("no_pe", "no PE"), ("pe", "PE")):
        r = res["runs"][label]
        echo(f"{name}: completed {r['completed']}/{seeds}; realised input Gram λ_min (median, 2nd half) per seed "
                   f"{[round(v, 4) for v in r['input_gram_lambda_min_median_second_half_per_seed']]}; "
                   f"regressor PE λ_min (Definition 21) {[float(f'{v:.3g}') for v in r['regressor_pe_lambda_min_median_second_half_per_seed']]}; "
                   f"PE status {r['pe_status_counts']}")
    echo(f"final diameter smaller with PE in {res['seeds_pe_smaller_at_end']}/{seeds} seeds")
    echo(f"Assumption 20 (rank Ξ = p): {res['assumption20']['holds']}")
    echo(f"wrote {js} and {png}")
    done = all(res["runs"][k]["completed"] == seeds for k in ("no_pe", "pe"))
    exit_verdict(done)
