"""``amcp coverage``: the feasible region of the tube QP (20) on a grid of initial states, robust Θ
and (``--adapt STEPS``) the Θ_T learned on a closed loop; every point confirmed by an independent LP."""

from __future__ import annotations

import sys

import click

from amcp_drake.cli.common import (
    backend_option,
    bad_input_exits_2,
    candidate_budget_option,
    check_run_size,
    design_budget,
    design_file_option,
    echo,
    exit_verdict,
    interruptible,
    load_design_file,
    load_problem_spec,
    max_memory_option,
    nonempty_path_callback,
    output_dir_callback,
    problem_options,
    progress_every_option,
    update_options,
)


@click.command("coverage")
@problem_options(x0_template=False)
@design_file_option
@backend_option
@click.option("--formulation", type=click.Choice(["auto", "plain", "vertex"]), default="auto", show_default=True,
              help="Tube QP: auto (the size rule of --formulation in amcp run), plain (15) with multipliers, or the "
                   "exact vertex form.")
@click.option("--grid", type=click.IntRange(min=1), default=None,
              help="Grid values per axis (default 21; with --points FILE holding a polytope, its grid).")
@click.option("--box", "box_text", default=None, metavar="LO:HI,LO:HI,...",
              help="Grid box, one interval per state (default: the state bounds of Z, else design.mu_state_bound).")
@click.option("--points", "points_file", default=None, type=click.Path(dir_okay=False), callback=nonempty_path_callback,
              help='JSON file: {"points": [[..], ..]} or {"polytope": {"H": [[..]], "h": [..]}} (grid points inside).')
@click.option("--adapt", "adapt_steps", type=click.IntRange(min=1), default=None,
              help="Also evaluate the region for Θ_T learned on a closed loop of this many steps (the scenario).")
@click.option("--adapt-x0", "adapt_x0", default=None, metavar="X1,X2,...",
              help="Initial state of the --adapt run (default: the problem file's scenario x0).")
@update_options
@click.option("--out", "out_dir", default="amcp-out", show_default=True, type=click.Path(file_okay=False),
              callback=output_dir_callback,
              help="Folder for coverage.json and coverage.png.")
@click.option("--no-progress", is_flag=True, help="No progress bar (and no design progress lines).")
@max_memory_option
@candidate_budget_option
@progress_every_option
@interruptible(lambda kw, exc: f"nothing new written to {kw['out_dir']} (each file is written whole or not at all); "
               "run the command again")
@bad_input_exits_2
def coverage_cmd(problem_file, example, design_file, backend, formulation, grid, box_text, points_file, adapt_steps, adapt_x0,
                 update, window, projection, out_dir, no_progress, max_memory, candidate_budget, progress_every):
    """Feasible fraction of a grid of initial states (QP (20), confirmed by an LP).

    Writes coverage.json (every point, both verdicts, every disagreement) and coverage.png (n <= 2).
    Exit code 0 when every point's QP verdict is confirmed, 1 on a disagreement (or an undecided QP,
    a failed LP, a point feasible for Θ but not for Θ_T), 2 on bad input."""
    import numpy as np

    from amcp_drake.cli.common import resolve_online
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.offline.design import design
    from amcp_drake.online.run_size import run_formulation
    from amcp_drake.studies.coverage import (
        DEFAULT_GRID,
        default_box,
        grid_points,
        load_points,
        parse_box,
        run_coverage,
        write_coverage,
    )

    if box_text and points_file:
        raise ProblemError("--box, --points", "at most one of them", "both")
    spec = load_problem_spec(problem_file, example)
    pr = spec.problem
    online = resolve_online(spec, update=update, window=window, projection=projection)
    if points_file:
        points, source = load_points(points_file, pr.n, grid or DEFAULT_GRID)
        axes = None
    else:
        box = parse_box(box_text, pr.n) if box_text else default_box(pr, spec.design.mu_state_bound)
        points, axes = grid_points(box, grid or DEFAULT_GRID)
        source = "grid " + " x ".join(f"[{lo:g}, {hi:g}]" for lo, hi in box) + f", {grid or DEFAULT_GRID} per axis"
    if adapt_x0 is not None:
        try:
            adapt_x0 = [float(v) for v in adapt_x0.split(",")]
        except ValueError:
            raise ProblemError("--adapt-x0", f"{pr.n} numbers separated by commas", repr(adapt_x0)) from None
        if len(adapt_x0) != pr.n:
            raise ProblemError("--adapt-x0", f"{pr.n} numbers separated by commas", f"{len(adapt_x0)} numbers")
    d = load_design_file(spec, design_file, quiet=no_progress)
    if d is None:
        check_run_size(spec, 1, online, max_memory, formulation=formulation)
        d = design(pr, spec.design, backend=backend,
                   budget=design_budget(max_memory, candidate_budget, quiet=no_progress, progress_every=progress_every))
    check_run_size(spec, 1, online, max_memory, design=d, formulation=formulation)  # the QPs' size with the design
    formulation = run_formulation(formulation, pr, d, online)  # auto resolved: every QP of the grid in one form

    def progress_factory(total, label):
        if no_progress:
            return None
        from tqdm import tqdm

        return tqdm(total=total, desc=label, unit="pt", file=sys.stderr, leave=False)

    res = run_coverage(spec, d, points, source=source, axes=axes, adapt_steps=adapt_steps, backend=backend,
                       formulation=formulation, options=online, adapt_x0=adapt_x0, progress_factory=progress_factory)
    js, png = write_coverage(res, out_dir)
    s = res.summary()
    echo(f"{pr.name}: {s['points']} initial states ({source}); backend {backend}, formulation {formulation}")
    di = res.design_info
    echo(f"design: X0 {di['x0_template'] or str(di['x0_facets']) + ' facets'}, lambda_bar {di['lambda_bar']:.4f}, "
               f"X_f {di['terminal_rows']} rows")
    echo(f"robust Θ: feasible fraction {s['robust_fraction']:.4f}")
    if adapt_steps:
        info = res.adapt_info
        echo(f"Θ_T after {info['steps_run']}/{adapt_steps} steps ({info['update']} update, stop: "
                   f"{info['stop_reason']}): feasible fraction {s['adaptive_fraction']:.4f} "
                   f"(feasible only after adaptation {s['adaptive_only_fraction']:.4f})")
        if info["steps_run"] < adapt_steps:
            echo(f"WARNING: the adaptive run from x0 = {info['x0']} stopped after {info['steps_run']} of "
                       f"{adapt_steps} steps ({info['stop_reason']}); Θ_T is the set of its last step. Choose a "
                       "feasible start with --adapt-x0.")
    t = res.timings
    echo("timings: " + ", ".join(f"{k} {v:.2f}" for k, v in t.items()))
    issues = res.issues()
    echo(f"QP/LP: {s['disagree_count']} disagreements, {s['borderline_count']} borderline (|t| <= tol), "
               f"{s['qp_undecided_count']} undecided QPs, {s['lp_failed_count']} failed LPs, "
               f"{s['monotonicity_count']} monotonicity violations")
    for kind in ("disagree", "qp_undecided", "lp_failed", "monotonicity", "borderline"):
        for row in issues[kind]:
            x0 = np.array2string(np.asarray(row["x0"]), precision=4, separator=", ")
            detail = {k: v for k, v in row.items() if k not in ("index", "x0")}
            echo(f"  {kind}: x0 = {x0} {detail}")
    echo(f"wrote {js}" + (f" and {png}" if png else " (no PNG for n >= 3)"))
    exit_verdict(res.passed)
