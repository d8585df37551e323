"""``amcp compare``: the Drake and cvxpy backends side by side."""

from __future__ import annotations

from collections import defaultdict

import click

# What the commands share (options, loading, exit codes) is defined once in cli/common.py; the import
# list and the decorators below only name it, with this command's own defaults and help texts.
from amcp_drake.cli.common import (
    bad_input_exits_2,
    design_file_option,
    echo,
    exit_verdict,
    formulation_option,
    max_memory_option,
    online_options,
    output_file_callback,
    prepare_run,
    problem_options,
    scenario_options,
    seed_option,
    simulate_function,
    simulator_option,
    steps_option,
)


@click.command("compare")
@problem_options()
@design_file_option
@scenario_options
@steps_option("Steps (default: the scenario's).")
@seed_option("Disturbance seed (default: the scenario's).")
@click.option("--mode", type=click.Choice(["lockstep", "independent"]), default="lockstep", show_default=True)
@click.option("--drake-solver", default="clarabel", show_default=True, help="Drake solver (clarabel, osqp, scs, ...).")
@click.option("--cvxpy-solver", default="CLARABEL", show_default=True, help="cvxpy solver (CLARABEL, OSQP, SCS, ...).")
@click.option("--accurate", is_flag=True,
              help="Both backends' Clarabel at tolerances 1e-10 instead of its defaults (1e-8), as the property "
                   "suite's lockstep comparison: at the defaults v is determined only to about 1e-5 where the "
                   "optimum is flat, which can exceed the v tolerance. Clarabel only.")
@online_options
@click.option("--out", "out_file", type=click.Path(), default="amcp-out/compare.json", show_default=True,
              callback=output_file_callback,
              help="JSON file with every difference.")
@formulation_option
@click.option("--allow-fallbacks", is_flag=True,
              help="Accept steps where one backend's answer failed its check and a re-solve or fallback answered "
                   "(by default such a step is a disagreement, exit 1, naming the step, the backend and the check).")
@click.option("--quiet", is_flag=True, help="Only the summary, no per-step table.")
@max_memory_option
@simulator_option
@bad_input_exits_2
def compare_cmd(problem_file, example, x0_template, design_file, x0, theta_star, steps, seed, mode, drake_solver,
                cvxpy_solver, accurate, online, out_file, formulation, allow_fallbacks, quiet, max_memory, simulator):
    """Compare u, v, cost, h_theta and theta_hat (and report z, alpha) of both backends per step."""
    from amcp_drake.comparison.compare import ACCURATE_CLARABEL, INFORMATIONAL, TOLERANCES, independent, lockstep
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.problem_io import write_json_atomic

    if accurate and (drake_solver.lower(), cvxpy_solver.upper()) != ("clarabel", "CLARABEL"):
        raise ProblemError("--accurate", "Clarabel in both backends (--drake-solver clarabel --cvxpy-solver CLARABEL)",
                           f"--drake-solver {drake_solver} --cvxpy-solver {cvxpy_solver}")
    if simulator != "builtin" and mode == "lockstep":
        raise ProblemError("--simulator", "builtin with --mode lockstep (both controllers are fed one state of amcp's "
                           "simulator; --mode independent runs each closed loop in Drake)", simulator)

    spec, steps, options, offline = prepare_run(problem_file, example, x0_template, steps, online, max_memory,
                                                formulation=formulation, design_file=design_file, x0=x0,
                                                theta_star=theta_star)
    seed = spec.scenario.seed if seed is None else seed
    tolerances = {"solver_options": dict(ACCURATE_CLARABEL)} if accurate else {}
    backend_options = ({"solver": drake_solver, "formulation": formulation, **tolerances},
                       {"solver": cvxpy_solver, "formulation": formulation, **tolerances})
    if mode == "lockstep":
        comp = lockstep(spec, steps, seed, options=options, backend_options=backend_options,
                        allow_fallbacks=allow_fallbacks, offline=offline)
    else:
        comp = independent(spec, steps, seed, options=options, backend_options=backend_options,
                           allow_fallbacks=allow_fallbacks, offline=offline, simulate=simulate_function(simulator))

    if not quiet:
        per_step: dict[int, dict[str, float]] = defaultdict(dict)
        for d in comp.differences + comp.informational:
            if d.step is not None:
                per_step[d.step][d.quantity] = d.difference
        quantities = [q for q in ("u", "v", "cost", "h_theta", "theta_hat", *INFORMATIONAL)
                      if any(q in row for row in per_step.values())]
        head = [f"{q + '*' if q in INFORMATIONAL else q:>10s}" for q in quantities]
        echo(f"{'k':>3}  {'status a/b':22s} " + " ".join(head))
        statuses = {k: (a, b) for k, a, b in comp.statuses}
        for k in sorted(per_step):
            a, b = statuses.get(k, ("-", "-"))
            flag = "" if a == b else "  <- status differs"
            cells = " ".join(f"{per_step[k][q]:10.2e}" if q in per_step[k] else f"{'-':>10s}" for q in quantities)
            echo(f"{k:3d}  {a[:10] + '/' + b[:10]:22s} {cells}{flag}")
        if any(q in INFORMATIONAL for q in quantities):
            echo("* information only, never compared: z and alpha are not unique minimisers of (20) (the cost "
                       "depends on v alone), so their differences have no tolerance")
        echo("")
    echo(f"{comp.mode} comparison, backends {comp.backends[0]} ({drake_solver}) vs {comp.backends[1]} ({cvxpy_solver}), "
               f"{steps} steps, seed {seed}" + (", Clarabel at 1e-10 (--accurate)" if accurate else ""))
    echo(f"{'quantity':14s} {'largest diff':>13s} {'at step':>8s} {'tolerance':>11s}  (abs + rel*scale)   verdict")
    worst = comp.worst()
    for q, d in sorted(worst.items()):
        if q in INFORMATIONAL:
            continue
        abs_tol, rel_tol = TOLERANCES[q]
        step = "design" if d.step is None else str(d.step)
        verdict = "agree" if d.agree else "DISAGREE"
        echo(f"{q:14s} {d.difference:13.3e} {step:>8s} {d.tolerance:11.3e}  ({abs_tol:g} + {rel_tol:g}*{d.scale:.3g})  {verdict}")
    info = [(q, worst[q]) for q in INFORMATIONAL if q in worst]
    if info:
        echo("information only, no tolerance, never a disagreement (z and alpha are not unique minimisers of "
                   "(20): the cost depends on v alone): "
                   + ", ".join(f"{q} largest diff {d.difference:.3e} at step {d.step}" for q, d in info))
    for name in comp.backends:
        counts = comp.answer_counts.get(name, {})
        if counts:
            parts = [f"{p}: {c['first'] + c['resolved']} of {sum(c.values())} its own"
                     + "".join(f", {c[o]} {o}" for o in ("resolved", "fallback", "not_solved") if c[o])
                     for p, c in counts.items()]
            echo(f"answers of {name}: " + "; ".join(parts))
    for m in comp.answer_mismatches:
        how = {"resolved": "re-solved", "fallback": "fallback", "not_solved": "not solved"}[m["outcome"]]
        echo(f"{'accepted (--allow-fallbacks)' if allow_fallbacks else 'DISAGREE'}: step {m['step']}: {m['backend']} "
                   f"needed help on its {m['problem']} answer ({how}{' by ' + m['kind'] if m['kind'] else ''}; failed "
                   f"check: {m['check'] or '-'}), the other backend answered first")
    if comp.drift:
        k_max = max(range(len(comp.drift)), key=comp.drift.__getitem__)
        echo(f"state drift |x_a - x_b|: max {comp.drift[k_max]:.3e} at step {k_max}")
    status_diffs = [(k, a, b) for k, a, b in comp.statuses if a != b]
    for k, a, b in status_diffs:
        echo(f"status differs at step {k}: {a} vs {b}")
    for note in comp.notes:
        echo(f"note: {note}")
    if comp.answer_mismatches and not allow_fallbacks:
        by_backend = sorted({m["backend"] for m in comp.answer_mismatches})
        first = comp.answer_mismatches[0]
        echo(f"DISAGREE: {len(comp.answer_mismatches)} step answer(s) needed a re-solve or fallback in "
                   f"{', '.join(by_backend)} only; first: step {first['step']}, {first['backend']}, {first['problem']}, "
                   f"failed check {first['check'] or '-'} (--allow-fallbacks accepts this)")
    bad = comp.disagreements()
    if bad:
        first = min(bad, key=lambda d: (d.step if d.step is not None else -1))
        echo(f"DISAGREE: {len(bad)} differences over tolerance; first: {first.quantity} at step {first.step} "
                   f"(diff {first.difference:.3e} > tol {first.tolerance:.3e})")
    flat = comp.flat_optimum_steps()
    if flat and not accurate:
        listed = ", ".join(map(str, flat[:5])) + (", ..." if len(flat) > 5 else "")
        echo(f"hint: at step {listed} v differs while the cost agrees: the optimum may be flat, where the "
                   "solvers' default tolerances fix the cost but not v; --accurate compares both backends with "
                   "Clarabel at 1e-10 (the property suite's setting)")
    write_json_atomic({**comp.to_dict(), "simulator": simulator}, out_file)
    echo(f"all differences written to {out_file}")
    echo("backends agree" if comp.agree else "backends DISAGREE")
    exit_verdict(comp.agree)
