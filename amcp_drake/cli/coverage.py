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
              help="Grid box, one interval per state (with --plane: one per state or one per state of the plane; "
                   "default: the state bounds of Z, else design.mu_state_bound).")
@click.option("--plane", "plane_text", default=None, metavar="I,J",
              help="A slice: the grid over two states (by index from 1 or by name, e.g. 2,4 or phi,omega), every "
                   "other state fixed (--fix, else 0); coverage.png then maps that plane for any n.")
@click.option("--fix", "fix_text", default=None, metavar="NAME=VALUE,...",
              help="With --plane: the values of states outside the plane (by index from 1 or name); the others are 0.")
@click.option("--max-points", "max_points", type=click.IntRange(min=1), default=None,
              help="Largest number of initial states to evaluate (default 10000; a larger grid is refused with its "
                   "counts before anything is solved).")
@click.option("--yes", "yes", is_flag=True, help="Run any grid up to 250000 points (no --max-points limit).")
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
def coverage_cmd(problem_file, example, design_file, backend, formulation, grid, box_text, plane_text, fix_text,
                 max_points, yes, points_file, adapt_steps, adapt_x0, update, window, projection, out_dir, no_progress,
                 max_memory, candidate_budget, progress_every):
    """Feasible fraction of a grid of initial states (QP (20), confirmed by an LP).

    Each point costs one QP (20) and one LP (two of each with --adapt). The counts are printed before
    the grid runs, with a time estimated from a short timed probe; more than --max-points points (10000
    by default) are refused with exit 2 before anything is solved (--yes lifts the limit). At n > 2, use
    a slice: --plane I,J grids two states with the others fixed (--fix NAME=VALUE,..., else 0).

    Writes coverage.json (every point, both verdicts, every disagreement, the estimate) and coverage.png
    (n <= 2, or a slice). Exit code 0 when every point's QP verdict is confirmed, 1 on a disagreement (or
    an undecided QP, a failed LP, a point feasible for Θ but not for Θ_T), 2 on bad input or a grid above
    the limit."""
    import numpy as np

    from amcp_drake.cli.common import resolve_online
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.state_plane import parse_fixed, parse_plane
    from amcp_drake.offline.design import design
    from amcp_drake.online.run_size import run_formulation
    from amcp_drake.studies.coverage import (
        DEFAULT_GRID,
        DEFAULT_MAX_POINTS,
        MAX_POINTS,
        default_box,
        grid_cost,
        grid_points,
        load_points,
        parse_box,
        require_within_limit,
        run_coverage,
        slice_points,
        write_coverage,
    )

    if box_text and points_file:
        raise ProblemError("--box, --points", "at most one of them", "both")
    if plane_text and points_file:
        raise ProblemError("--plane, --points", "at most one of them (a slice is a grid)", "both")
    if fix_text and not plane_text:
        raise ProblemError("--fix", "--plane with it (--fix gives the states outside the plane)", "--fix alone")
    if max_points is not None and max_points > MAX_POINTS:
        raise ProblemError("--max-points", f"at most {MAX_POINTS}", str(max_points))
    limit = MAX_POINTS if yes else (max_points or DEFAULT_MAX_POINTS)
    spec = load_problem_spec(problem_file, example)
    pr = spec.problem
    online = resolve_online(spec, update=update, window=window, projection=projection)
    plane = parse_plane("--plane", plane_text, pr) if plane_text else None
    fixed = parse_fixed("--fix", fix_text, pr, plane) if plane else None
    per_axis = grid or DEFAULT_GRID
    if points_file:
        points, source = load_points(points_file, pr.n, per_axis)
        axes = None
        require_within_limit(grid_cost(len(points), adapt_steps), limit, "--points", f"{source}")
    else:
        dims = 2 if plane else pr.n
        require_within_limit(grid_cost(per_axis ** dims, adapt_steps), limit, "--grid",
                             f"{per_axis} values per axis in {dims} dimensions ({per_axis}^{dims})")
        if plane:
            box = _plane_box(box_text, pr, plane, spec.design.mu_state_bound)
            points, axes = slice_points(box, per_axis, plane, fixed)
            others = [f"{pr.state_names[i]} = {fixed[i]:g}" for i in range(pr.n) if i not in plane]
            source = (f"slice {pr.state_names[plane[0]]} x {pr.state_names[plane[1]]} = "
                      + " x ".join(f"[{lo:g}, {hi:g}]" for lo, hi in box) + f", {per_axis} per axis"
                      + (f"; {', '.join(others)}" if others else ""))
        else:
            box = parse_box(box_text, pr.n) if box_text else default_box(pr, spec.design.mu_state_bound)
            points, axes = grid_points(box, per_axis)
            source = "grid " + " x ".join(f"[{lo:g}, {hi:g}]" for lo, hi in box) + f", {per_axis} per axis"
    cost = grid_cost(len(points), adapt_steps)
    echo(f"cost: {cost['points']} initial states x {cost['parameter_sets']} parameter set(s) = {cost['qps']} QPs (20) "
         f"and {cost['lps']} LPs" + (f", plus a closed loop of {adapt_steps} steps" if adapt_steps else ""), err=True)
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

    def on_estimate(estimate):
        echo(f"estimate: {1e3 * estimate['probe_s_per_point']:.1f} ms per point (QP + LP, timed on "
             f"{estimate['probe_points']} points) -> about {_duration(estimate['estimate_s'])} for {estimate['qps']} "
             "QPs and LPs", err=True)

    res = run_coverage(spec, d, points, source=source, axes=axes, adapt_steps=adapt_steps, backend=backend,
                       formulation=formulation, options=online, adapt_x0=adapt_x0, progress_factory=progress_factory,
                       plane=plane, fixed=fixed, on_estimate=on_estimate)
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
    echo(f"wrote {js}" + (f" and {png}" if png else " (no PNG for n >= 3 without a slice: --plane I,J)"))
    exit_verdict(res.passed)


def _plane_box(box_text, problem, plane, state_bound):
    """The (2, 2) intervals of a slice: from --box (one interval per state, or one per state of the plane),
    else the state bounds of Z along the plane's states."""
    from amcp_drake.studies.coverage import default_box, parse_box

    if not box_text:
        return default_box(problem, state_bound)[list(plane)]
    if len(box_text.split(",")) == 2:
        return parse_box(box_text, 2)
    return parse_box(box_text, problem.n)[list(plane)]


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"
