"""``amcp baseline``: adaptive vs robust (Θ_k ≡ Θ, θ̂_k ≡ θ̂0) on a problem, as a markdown table."""

from __future__ import annotations

import click

# What the commands share (options, loading, exit codes) is defined once in cli/common.py; the import
# list and the decorators below only name it, with this command's own defaults and help texts.
from amcp_drake.cli.common import (
    backend_option,
    bad_input_exits_2,
    check_run_size,
    design_file_option,
    echo,
    exit_verdict,
    load_design_file,
    load_problem_spec,
    max_memory_option,
    problem_options,
    require_scenario,
    seeds_option,
    steps_option,
)


@click.command("baseline")
@problem_options(x0_template=False)
@design_file_option
@backend_option
@seeds_option("Number of disturbance seeds (0..seeds-1).", default=20)
@steps_option("Steps per run (default: the problem's scenario).")
@click.option("--update", type=click.Choice(["fixed", "exact", "window"]), default="fixed", show_default=True,
              help="Set update of the adaptive controller.")
@click.option("--formulation", type=click.Choice(["auto", "plain", "vertex"]), default="auto", show_default=True,
              help="Tube QP formulation: auto (the size rule of --formulation in amcp run), plain (15), or vertex "
                   "(same optimum, no multipliers).")
@click.option("--grid", type=click.IntRange(2, 401), default=None,
              help="Grid points per axis for the feasible region (default 31).")
@max_memory_option
@bad_input_exits_2
def baseline_cmd(problem_file, example, design_file, backend, seeds, steps, update, formulation, grid, max_memory):
    """Closed-loop cost, tube size and feasible region of x0: adaptive vs robust, over many seeds."""
    import numpy as np

    from amcp_drake.model.errors import ProblemError
    from amcp_drake.offline.design import design
    from amcp_drake.online.run_size import run_formulation
    from amcp_drake.studies.baseline import DEFAULT_BOX, DEFAULT_GRID, run_baseline

    spec = load_problem_spec(problem_file, example)
    if spec.problem.n != 2:
        raise ProblemError("problem", "a problem with n = 2 (the feasible region is gridded in the plane)",
                           f"n = {spec.problem.n}")
    require_scenario(spec)
    run_steps = spec.scenario.steps if steps is None else steps
    d = load_design_file(spec, design_file)
    if d is None:
        check_run_size(spec, run_steps, None, max_memory, formulation=formulation)
        d = design(spec.problem, spec.design, backend=backend)
    check_run_size(spec, run_steps, None, max_memory, design=d, formulation=formulation)
    formulation = run_formulation(formulation, spec.problem, d, None)  # auto resolved: both controllers in one form
    res = run_baseline(spec, d, seeds=seeds, steps=steps, backend=backend, formulation=formulation, update=update,
                       grid=grid or DEFAULT_GRID)
    (a1, b1), (a2, b2) = DEFAULT_BOX
    n_grid = grid or DEFAULT_GRID
    echo(f"{spec.problem.name}: {len(res.seeds)} seeds, {steps or spec.scenario.steps} steps, x0 = "
               f"{np.asarray(spec.scenario.x0).tolist()}, update {update}, backend {backend} ({formulation}); "
               f"x0 grid {n_grid}x{n_grid} on [{a1}, {b1}] x [{a2}, {b2}]")
    echo("")
    echo(res.markdown())
    contained = all(bool(np.all(fa[res.feasible_robust])) for fa in res.feasible_adaptive)
    echo("")
    echo(f"robust feasible region ⊆ adaptive region at every grid point and seed: {contained}")
    ok = contained and all(r.completed for r in res.adaptive + res.robust)
    exit_verdict(ok)
