"""``amcp certify``: run a closed loop (or load a saved one), check every claim independently, write the bundle.

Exit codes: 0 every claim holds and every solver answer was the backend's own; 1 a claim failed **or
could not be checked** (verdict ``incomplete``: a claim that did not run is not a pass), or the backend's
conformance failed (a check rejected one of its answers and a fallback answered); 2 bad input (unreadable or malformed
problem or trajectory file, bad option, --out naming a file); 3 a premise of the paper's results does not
hold on the run (verdict ``premise_not_met``: x_0 outside the feasible region of (20), Assumption 8 or (11)
broken by the design), so nothing is claimed. On exit 2 no output is written; on 0, 1 and 3 the bundle
(certificate.json, report.html, trajectory.json.gz) is written atomically into --out.
"""

from __future__ import annotations

import sys

import click

from amcp_drake.cli.common import (
    EXIT_PREMISE_NOT_MET,
    ONLINE_OPTION_NAMES,
    backend_option,
    bad_input_exits_2,
    candidate_budget_option,
    design_budget,
    design_file_option,
    echo,
    exit_verdict,
    formulation_option,
    interruptible,
    load_problem_spec,
    max_memory_option,
    nonempty_path_callback,
    online_options,
    output_dir_callback,
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


@click.command("certify")
@problem_options()
@design_file_option
@backend_option
@click.option("--design-backend", "design_backend", type=click.Choice(["drake", "cvxpy"]), default=None,
              help="Backend of the offline design (default: --backend). A campaign replay names the one the "
                   "campaign used.")
@formulation_option
@scenario_options
@steps_option("Closed-loop steps (default: the scenario's; 50 for Example 1).")
@seed_option("Seed of the disturbance sequence (default: the scenario's; 0 for Example 1).")
@click.option("--out", "out_dir", default="amcp-out", show_default=True, type=click.Path(), callback=output_dir_callback,
              help="Output directory (its other files are left alone).")
@click.option("--trajectory", "trajectory_file", default=None, type=click.Path(), callback=nonempty_path_callback,
              help="Re-check a saved trajectory (.json or .json.gz) instead of running the loop.")
@click.option("--plane", "plane_text", default=None, metavar="I,J",
              help="The two states of the report's tube plot, by index from 1 or by name (e.g. 2,4 or phi,omega; "
                   "default: the two whose constraints the recorded tubes come closest to, see amcp.plots).")
@online_options
@max_memory_option
@candidate_budget_option
@progress_every_option
@simulator_option
@click.pass_context
@interruptible(lambda kw, exc: f"nothing written to {kw['out_dir']} (its staging folder was removed); "
               "run the command again")
@bad_input_exits_2
def certify_cmd(ctx, problem_file, example, x0_template, design_file, backend, design_backend, formulation, x0,
                theta_star, steps, seed, out_dir, trajectory_file, plane_text, online, max_memory, candidate_budget,
                progress_every, simulator):
    """Run a closed loop and check every claim of the paper independently.

    Runs the adaptive MPC on PROBLEM (default: --example lorenzen2019, x0 = [2, 3],
    θ* = [0.8, 0.2, -0.5], 50 steps, uniform disturbance, seed 0), checks every claim of the paper
    from the recorded data with numpy/scipy only, and writes certificate.json, report.html and
    trajectory.json.gz into --out.

    Exit code 0: every claim holds and the backend answered every problem itself; 1: a claim failed or
    could not be checked, or a check rejected a backend answer (backend conformance failed; the bundle
    is still written); 2: bad input (nothing is written); 3: a premise of the paper's results does not
    hold (x0 outside the feasible region of (20), Assumption 8 or (11) broken by the design): nothing is
    claimed for the run (the bundle is written; when a gain design.K of the problem file breaks Assumption 8
    nothing is run). See docs/certificate.md."""
    from amcp_drake.certificate.certify import VERDICT_PREMISE_NOT_MET, certify
    from amcp_drake.certificate.report import check_out_dir, remove_stale_staging, write_outputs
    from amcp_drake.model.errors import DesignError, ProblemError

    remove_stale_staging(check_out_dir(out_dir))
    if trajectory_file is not None:
        from click.core import ParameterSource

        run_options = ("backend", "design_backend", "steps", "seed", *ONLINE_OPTION_NAMES, "max_memory", "x0_template",
                       "candidate_budget", "progress_every", "simulator", "design_file", "x0", "theta_star")
        flag = {"design_file": "design", "theta_star": "theta-star"}
        given = [f"--{flag.get(name, name.replace('_', '-'))}" for name in run_options
                 if ctx.get_parameter_source(name) is ParameterSource.COMMANDLINE]
        if given:
            raise ProblemError(", ".join(given), "no run options together with --trajectory (the run is not repeated)",
                               "both")
        traj, spec = _load_trajectory(trajectory_file, problem_file, example)
        plane = _plane(plane_text, traj.problem)
    else:
        if design_file is not None and design_backend is not None:
            raise ProblemError("--design-backend, --design", "at most one of them (the design file is not designed "
                               "again)", "both")
        spec, steps, options, offline = prepare_run(
            problem_file, example, x0_template, steps, online, max_memory,
            "a scenario (x0, theta_star, ...) in the problem file to run",
            "Add a \"scenario\" object, pass --x0 and --theta-star, or pass --trajectory.",
            formulation=formulation, design_file=design_file, x0=x0, theta_star=theta_star)
        seed = spec.scenario.seed if seed is None else seed
        plane = _plane(plane_text, spec.problem)  # checked before the run
        try:
            traj = _run(spec, backend, steps, seed, formulation, options, design_backend,
                        design_budget(max_memory, candidate_budget, progress_every=progress_every), simulator,
                        offline)
        except DesignError as exc:
            broken = _assumption_8_broken_by_the_given_gain(exc, spec)
            if broken is None:
                raise
            from amcp_drake.certificate.premises import DESIGN_HINT

            echo(f"PREMISE NOT MET: Assumption 8 (A_cl(θ) = A(θ) + B(θ)K Schur stable at every vertex of Θ): the "
                       f"gain design.K of the problem file breaks it ({broken}); nothing was run or written, nothing is "
                       "claimed")
            echo(f"                 next: {DESIGN_HINT}")
            sys.exit(EXIT_PREMISE_NOT_MET)
        if formulation == "auto":
            echo(f"formulation auto: {traj.meta.get('formulation', 'plain')}", err=True)
        if traj.stop_reason.startswith("inconsistent"):
            echo(f"warning: the run stopped: {traj.stop_reason}; certifying the partial trajectory", err=True)
    cert = certify(traj, spec)
    if trajectory_file is None and traj.options.update != "none":
        cert = _with_robust_baseline(traj, cert)
    try:
        out = write_outputs(out_dir, traj, cert, inputs=_provenance_inputs(problem_file, example, trajectory_file),
                            command_line=["amcp", *sys.argv[1:]], plane=plane)
    except OSError as exc:  # a full disk or a failing medium: write_outputs removed what it had staged
        raise write_error("--out", out_dir, exc) from None
    _print(cert, out, traj.problem)
    if cert.verdict == VERDICT_PREMISE_NOT_MET and cert.conformance != "fail":
        sys.exit(EXIT_PREMISE_NOT_MET)
    exit_verdict(cert.passed and cert.conformance != "fail")


def _plane(text, problem):
    """The --plane of the tube plot as 0-based indices (None: the default plane)."""
    if text is None:
        return None
    from amcp_drake.model.state_plane import parse_plane

    return parse_plane("--plane", text, problem)


def _with_robust_baseline(traj, cert):
    """The certificate with ``figures.robust_baseline``: the robust baseline (``--update none``) run beside
    ``traj`` on its recorded disturbance (:func:`amcp_drake.studies.baseline.robust_beside`). A measurement
    shown apart from the verdict; a failure to run it is reported there, never as a failed claim."""
    from dataclasses import replace

    from amcp_drake.studies.baseline import robust_beside

    echo("robust baseline (--update none) on the same disturbance ...", err=True)
    try:
        baseline = robust_beside(traj, progress=lambda line: echo(line, err=True))
    except Exception as exc:  # noqa: BLE001 - any failure is shown in the report; the verdict stands
        echo(f"warning: the robust baseline could not be run: {type(exc).__name__}: {exc}", err=True)
        baseline = {"error": f"{type(exc).__name__}: {exc}"}
    return replace(cert, figures={**cert.figures, "robust_baseline": baseline})


def _run(spec, backend: str, steps: int, seed: int, formulation: str = "plain", options=None,
         design_backend: str | None = None, budget=None, simulator: str = "builtin", offline=None):
    """Offline design (unless ``offline``, a loaded --design, is given), then the closed loop with a
    progress bar (Drake/cvxpy imported only here); the same path as a campaign run
    (:func:`amcp_drake.online.replay.run_scenario`), so a replay is exact. ``simulator``: who runs the
    plant (``--simulator``: builtin or drake)."""
    from amcp_drake.online.replay import run_scenario

    return run_scenario(spec, backend, design_backend=design_backend, formulation=formulation, steps=steps,
                        seed=seed, options=options, progress=True, design_budget=budget,
                        simulate=simulate_function(simulator), offline=offline)


def _assumption_8_broken_by_the_given_gain(exc: Exception, spec) -> str | None:
    """The design's reason when the problem file gives K (design.K) and every design attempt failed on
    Assumption 8 with it (a premise the user's design breaks, not a defect of the design); else None."""
    if getattr(spec.design, "K", None) is None:
        return None
    attempts = getattr(exc, "attempts", None)
    reasons = [a.reason for a in attempts if a.outcome == "design failed"] if attempts else [str(exc)]
    prefix = "Assumption 8 fails: "
    if reasons and all(r.startswith(prefix) for r in reasons):
        return reasons[0][len(prefix):]
    return None


def _provenance_inputs(problem_file, example, trajectory_file) -> dict:
    """The input files a certificate records the SHA-256 of: the problem file (a built-in example's packaged
    file when no PROBLEM is given) and the trajectory file certified with --trajectory."""
    from amcp_drake.model.examples import example_file

    files = {}
    if problem_file:
        files["problem"] = problem_file
    elif example or trajectory_file is None:
        packaged = example_file(example or "lorenzen2019")
        if packaged is not None:
            files["problem"] = packaged
    if trajectory_file:
        files["input_trajectory"] = trajectory_file
    return files


def _load_trajectory(path: str, problem_file, example):
    """The saved trajectory and the problem spec that goes with it: the one given, or a built-in example
    whose problem data are identical to the recorded ones (it supplies the μ box), or None."""
    from amcp_drake.certificate.certify import _require_same_problem
    from amcp_drake.model.examples import EXAMPLES
    from amcp_drake.online.simulate import Trajectory

    traj = Trajectory.load(path)
    if problem_file or example:
        return traj, load_problem_spec(problem_file, example)
    for make in EXAMPLES.values():
        spec = make()
        try:
            _require_same_problem(traj, spec)
        except ValueError:
            continue
        return traj, spec
    return traj, None


def _print(cert, out, problem) -> None:
    from amcp_drake.certificate.certify import RELATIVE_TOLERANCES, TOLERANCE_RULE
    from amcp_drake.cli.summary import signals_header

    for line in signals_header(problem):
        echo(f"{problem.name}: {line}")
    form = cert.run.get("formulation", "plain")
    reason = cert.run.get("formulation_reason")
    echo("solved form of (20): " + ("vertex form ((5b) at the vertices of Θ_k, no multipliers: the Λ claims are "
                                    "not applicable)" if form == "vertex" else "plain form (15), with the multipliers Λ")
         + (f" [{reason}]" if reason else ""))
    echo(f"how to read the table: {TOLERANCE_RULE}")
    width = 14 if cert.measured else 8  # "not_applicable"
    echo(f"{'claim':32s} {'status':{width}s} {'margin':>11s} {'tolerance':>10s} {'step':>5s}  statement")
    for c in cert.claims:
        margin = "n/a" if c.margin is None else f"{c.margin:.3e}"
        step = c.data.get("worst_step")
        mark = "r" if c.data["id"] in RELATIVE_TOLERANCES else " "
        why = f" ({c.detail})" if c.status == "not_applicable" else ""
        echo(f"{c.data['id']:32s} {c.status:{width}s} {margin:>11s} {c.tolerance:9.1e}{mark} "
                   f"{'' if step is None else step:>5}  {c.name}{why}")
    for c in cert.not_claimed:
        echo(f"{c['id']:32s} {'-':{width}s} {'':>11s} {'':10s} {'':>5s}  not claimed for this run: {c['reason']}")
    echo("")
    for p in cert.premises_not_met:
        margin = "n/a" if p["margin"] is None else f"{p['margin']:.3e}"
        echo(f"PREMISE NOT MET: {p['name']}: {p['premise']}; margin {margin} (tolerance {p['tolerance']:.0e}); "
                   f"{p['detail']}")
        echo(f"                 next: {p['hint']}")
    counts = cert.counts()
    for line in _consistency_lines(cert):
        echo(line)
    kind = " (measured run)" if cert.measured else ""
    need = f"; {counts['not_applicable']} need θ* and w" if cert.measured else ""
    if cert.premises_not_met and not counts["fail"]:
        echo(f"NOT CERTIFIED (premise not met): the paper's results assume {', '.join(p['name'] for p in cert.premises_not_met)}, "
                   f"which does not hold on this run; nothing is claimed for it ({counts['pass']} checks passed, "
                   f"{len(cert.not_claimed)} not claimed)")
    elif cert.passed:
        echo(f"CERTIFIED{kind}: all {counts['pass']} {'applicable ' if cert.measured else ''}claims hold{need}")
    elif counts["fail"]:
        echo(f"NOT CERTIFIED{kind}: {counts['fail']} claim(s) failed: {', '.join(cert.ids('fail'))}"
                   + (f"; {counts['not_run']} not run: {', '.join(cert.ids('not_run'))}" if counts["not_run"] else "")
                   + need)
    else:
        echo(f"NOT CERTIFIED{' (incomplete, measured run)' if cert.measured else ' (incomplete)'}: "
                   f"{counts['not_run']} claim(s) could not be checked: {', '.join(cert.ids('not_run'))}{need}")
    answers = cert.solver_answers
    for line in answers.get("summary", []):
        echo(f"solver answers: {line}" if not line.startswith(" ") else f"               {line}")
    if cert.conformance == "fail":
        echo(f"BACKEND CONFORMANCE FAILED: {answers['backend']}'s answers were rejected by the answer checks at "
                   f"step(s) {_steps(answers['rejected_steps'])}; the claims above are checked on the answers the "
                   "controller applied (the fallbacks'), so this is a defect of the backend, not of the paper's claims")
    elif cert.conformance == "pass":
        echo(f"backend conformance: pass ({answers['backend']} answered every problem itself)")
    else:
        echo("backend conformance: unknown (the trajectory has no record of how its solver answers were obtained)")
    baseline = cert.figures.get("robust_baseline") or {}
    if "adaptive" in baseline:
        a, r = baseline["adaptive"], baseline["robust"]
        echo(f"robust baseline (not part of the verdict): cost {_g(a['cost'])} adaptive vs {_g(r['cost'])} robust; "
                   f"mean one-step tube {_g(a['mean_one_step_tube'])} vs {_g(r['mean_one_step_tube'])} (report.html)")
    echo(f"wrote {out}/certificate.json, {out}/report.html, {out}/trajectory.json.gz")


def _consistency_lines(cert) -> list[str]:
    """The model-consistency line when ``data_consistency`` failed: the first step and what it means."""
    try:
        c = cert.claim("data_consistency")
    except KeyError:
        return []
    if c.status != "fail":
        return []
    return [f"DATA CONTRADICT THE MODEL: Θ_(k−1) ∩ Δ_k is empty first at step {c.data['first_failing_step']} "
            f"(signed Chebyshev radius {c.margin:.3e} < −{c.tolerance:.0e}): the disturbance left W, θ* is not in Θ, or "
            "the model (A_i, B_i) is wrong; the claims that rest on it are not run"]


def _g(value) -> str:
    return "n/a" if value is None else f"{value:.4g}"


def _steps(steps: list[int]) -> str:
    return ", ".join(map(str, steps[:10])) + (f", ... ({len(steps)} in all)" if len(steps) > 10 else "")
