"""``amcp pe-figure``: Proposition 23 measured (mean diameter of Θ_k with and without PE)."""

from __future__ import annotations

import sys

import click

from .cli_common import EXIT_FAIL, EXIT_OK, backend_option, bad_input_exits_2, example_option, load_problem_spec, problem_argument


@click.command("pe-figure")
@problem_argument
@example_option
@backend_option
@click.option("--seeds", type=click.IntRange(min=1), default=5, show_default=True)
@click.option("--steps", type=click.IntRange(min=2), default=150, show_default=True)
@click.option("--update", type=click.Choice(["exact", "window", "fixed"]), default="exact", show_default=True)
@click.option("--pe-window", type=click.IntRange(min=1), default=10, show_default=True, help="PE window P.")
@click.option("--pe-level", type=click.FloatRange(min=0.0, min_open=True), default=0.2, show_default=True,
              help="PE level ρ.")
@click.option("--out", "out_dir", default="amcp-out", show_default=True, type=click.Path())
@bad_input_exits_2
def pe_figure_cmd(problem_file, example, backend, seeds, steps, update, pe_window, pe_level, out_dir):
    """Write pe_diameter.png and pe_diameter.json: mean diam Θ_k vs k with and without PE."""
    from .design import design
    from .pe_figure import run_pe_figure, write_pe_figure

    spec = load_problem_spec(problem_file, example)
    d = design(spec.problem, spec.design, backend=backend)
    res = run_pe_figure(spec, d, seeds=seeds, steps=steps, update=update, pe_window=pe_window, pe_level=pe_level,
                        backend=backend)
    js, png = write_pe_figure(res, out_dir)
    for label in ("no_pe", "pe"):
        r = res["runs"][label]
        md = r["mean_diameter"]
        click.echo(f"{label:6s}: mean diam Θ_k at k=0: {md[0]:.4f}, k={len(md) // 2}: {md[len(md) // 2]:.4f}, "
                   f"k={len(md) - 1}: {md[-1]:.4f}; completed {r['completed']}/{seeds}; PE status {r['pe_status_counts']}")
    click.echo(f"Assumption 20 (rank Ξ = p): {res['assumption20']['holds']}")
    click.echo(f"wrote {js} and {png}")
    done = all(res["runs"][k]["completed"] == seeds for k in ("no_pe", "pe"))
    sys.exit(EXIT_OK if done else EXIT_FAIL)
