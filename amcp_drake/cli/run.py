"""``amcp run``: one closed-loop run with a per-step table (the README's Example 1 table)."""

from __future__ import annotations

import click
import numpy as np

# What the commands share (options, loading, exit codes) is defined once in cli/common.py; the import
# list and the decorators below only name it, with this command's own defaults and help texts.
from amcp_drake.cli.common import (
    backend_option,
    bad_input_exits_2,
    candidate_budget_option,
    check_run_size,
    design_budget,
    design_file_option,
    echo,
    exit_verdict,
    formulation_option,
    interruptible,
    max_memory_option,
    online_options,
    output_file_callback,
    prepare_run,
    problem_options,
    progress_every_option,
    scenario_options,
    seed_option,
    simulate_function,
    simulator_option,
    steps_option,
    write_error,
)


@click.command("run")
@problem_options()
@design_file_option
@backend_option
@formulation_option
@scenario_options
@steps_option("Number of steps (default: the problem's scenario).")
@seed_option("Disturbance seed (default: the scenario's).")
@click.option("--disturbance", type=click.Choice(["uniform", "vertices", "zero"]), default=None)
@online_options
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True, help="Print every n-th step.")
@click.option("--save", type=click.Path(), default=None, callback=output_file_callback,
              help="Save the trajectory (JSON, .gz allowed).")
@max_memory_option
@candidate_budget_option
@progress_every_option
@simulator_option
@interruptible(lambda kw, exc: "the run stopped" + (f"; nothing saved to {kw['save']}" if kw.get("save") else "")
               + "; run the command again")
@bad_input_exits_2
def run_cmd(problem_file, example, x0_template, design_file, backend, formulation, x0, theta_star, steps, seed,
            disturbance, online, every, save, max_memory, candidate_budget, progress_every, simulator):
    """Design (or load --design), then run the adaptive MPC closed loop and print one line per step."""
    from amcp_drake.cli.summary import format_table, step_table
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC

    spec, steps, options, d = prepare_run(problem_file, example, x0_template, steps, online, max_memory,
                                          formulation=formulation, design_file=design_file, x0=x0,
                                          theta_star=theta_star)
    sc, pr = spec.scenario, spec.problem
    if d is None:  # no --design: design, then the run's size with the design found
        d = design(pr, spec.design, backend=backend,
                   budget=design_budget(max_memory, candidate_budget, progress_every=progress_every))
        check_run_size(spec, steps, options, max_memory, design=d, formulation=formulation)
    update = options.update
    ctrl = AdaptiveMPC(pr, d, backend=backend, options=options, formulation=formulation, max_memory_mb=max_memory)
    if ctrl.formulation_choice is not None:
        echo(f"formulation auto: {ctrl.formulation_choice.formulation} ({ctrl.formulation_choice.reason})")
    traj = simulate_function(simulator)(ctrl, sc.x0, sc.theta_star_for(steps), steps, disturbance or sc.disturbance_for(steps),
                    seed=sc.seed if seed is None else seed, progress=False, mu_state_bound=spec.design.mu_state_bound)
    theta_text = (f"theta*_k sequence from {traj.theta_star_at(0).tolist()} (max step {sc.max_theta_rate():.3g})"
                  if sc.time_varying else f"theta* = {np.asarray(sc.theta_star).tolist()}")
    echo(f"{pr.name}: x0 = {np.asarray(sc.x0).tolist()}, {theta_text}, "
               f"{traj.steps} steps, disturbance {disturbance or ('array' if sc.explicit_disturbance else sc.disturbance)} (seed {sc.seed if seed is None else seed}), "
               f"backend {backend}, update {update}, simulator {simulator}")
    echo(format_table(step_table(traj, every), pr))
    z_margin = max(pr.in_Z(x, u) for x, u in zip(traj.x, traj.u)) if traj.steps else float("nan")
    theta_margin = max(float(np.max(r.H_theta @ traj.theta_star_at(r.k) - r.h_theta)) for r in traj.records)
    solver = np.array([r.times.get("solver", np.nan) for r in traj.records])
    echo("")
    echo(f"QPs solved: {sum(r.status.value == 'optimal' for r in traj.records)}/{len(traj.records)}; "
               f"max_k (F x + G u - 1) = {z_margin:.4f} (<= 0: in Z); max_k (H θ* - h)_k = {theta_margin:.2e} "
               f"(<= 0: θ*_k ∈ Θ_k); median QP solve {1e3 * np.nanmedian(solver):.1f} ms")
    echo(f"stop: {traj.stop_reason}")
    if save:
        try:
            traj.save(save)
        except OSError as exc:  # a full disk or a read-only folder: the atomic write left nothing behind
            raise write_error("--save", save, exc) from None
        echo(f"trajectory saved to {save}")
    exit_verdict(traj.all_solved and traj.stop_reason == "completed")
