"""``amcp design``: the offline design and its independent checks, with margins."""

from __future__ import annotations

import json

import click
import numpy as np

# What the commands share (options, loading, exit codes) is defined once in cli/common.py; the import
# list and the decorators below only name it, with this command's own defaults and help texts.
from amcp_drake.cli.common import (
    backend_option,
    bad_input_exits_2,
    candidate_budget_option,
    design_budget,
    design_max_memory_option,
    echo,
    exit_verdict,
    load_problem_spec,
    output_file_callback,
    problem_options,
    progress_every_option,
    with_x0_template,
)


def _fmt(a) -> str:
    return np.array2string(np.asarray(a), precision=5, suppress_small=True, separator=", ")


def _vector_line(name: str, values, verbose: bool) -> str:
    """``name = [...]`` in full when ``verbose`` or when it has at most 8 entries, else its count and range."""
    v = np.asarray(values, float)
    if verbose or v.size <= 8:
        return f"{name} = {_fmt(v)}"
    return f"{name}: {v.size} values in [{v.min():.5g}, {v.max():.5g}] (all of them with -v)"


@click.command("design")
@problem_options()
@backend_option
@click.option("--json", "as_json", is_flag=True, help="Print the design and checks as JSON.")
@click.option("-v", "--verbose", is_flag=True,
              help="Also print P, the vectors w_bar and f_bar and every candidate's full reason.")
@click.option("--out", "out_file", type=click.Path(), default=None, callback=output_file_callback,
              help="Write the design, with the SHA-256 of the canonical problem it belongs to, to this JSON file "
                   "when every design check passes (run, certify, compare, coverage and baseline reuse it with "
                   "--design FILE).")
@design_max_memory_option
@candidate_budget_option
@progress_every_option
@bad_input_exits_2
def design_cmd(problem_file, example, x0_template, backend, as_json, verbose, out_file, max_memory, candidate_budget,
               progress_every):
    """Compute K, P, X0, w_bar, f_bar, Xf and mu ((11), (14), (16), Appendix A.1) and verify them independently.

    The automatic design prints one line per candidate as it ends (on stderr: what it tried and how it
    ended); ``-v`` adds P, the vectors w_bar and f_bar and each candidate's full reason to the report.
    ``--out FILE`` saves the design for ``--design FILE`` of the run commands."""
    from amcp_drake.model.limits import check_design_size
    from amcp_drake.offline.checks import verify_design
    from amcp_drake.offline.design import design

    spec = with_x0_template(load_problem_spec(problem_file, example), x0_template)
    pr = spec.problem
    check_design_size(pr, spec.design, max_memory)  # the design's own size; it builds no run
    d = design(pr, spec.design, backend=backend, budget=design_budget(max_memory, candidate_budget, progress_every=progress_every))
    checks = verify_design(pr, d, spec.design.mu_state_bound)
    ok = all(c.passed for c in checks)
    if as_json:
        echo(json.dumps({"design": d.to_dict(), "checks": [c.to_dict() for c in checks], "passed": ok}, indent=1))
    else:
        echo(f"problem {pr.name}: n={pr.n}, m={pr.m}, p={pr.p}, N={pr.N}; backend {backend}")
        if pr.describe_signals():
            echo(f"problem {pr.name}: {pr.describe_signals()}")
        echo(f"K ({d.gain_source}) = {_fmt(d.K)}")
        if verbose:
            echo(f"P = {_fmt(d.P)}")
        attempts = (d.info or {}).get("attempts", [])
        if verbose:
            for i, attempt in enumerate(attempts):
                reason = f" ({attempt['reason']})" if attempt["reason"] else ""
                echo(f"design attempt {i + 1}: {attempt['label']}: {attempt['outcome']}{reason} [{attempt['seconds']:.1f} s]")
        tried = f" (candidate {len(attempts)} of the automatic design)" if attempts else ""
        echo(f"X0 template: {(d.info or {}).get('x0_template', 'n/a')}{tried}")
        state_units = (d.info or {}).get("state_units")
        if state_units:  # offline/units.py: W's extents were unequal
            echo(f"designed in the state units xi = diag({_fmt(np.asarray(state_units['xi_equals_diag_times_x']))}) x "
                       "(W's extents equalised), mapped back and checked in the file's units")
        echo(f"X0: {len(d.H_x)} facets, {len(d.X0_vertices)} vertices, lambda_bar = {d.lambda_bar:.5f}")
        echo(_vector_line("w_bar", d.w_bar, verbose))
        echo(_vector_line("f_bar", d.f_bar, verbose))
        terminal = (d.info or {}).get("terminal_set", "recursion")
        echo(f"Xf: {len(d.H_T)} rows, " + (f"recursion of Appendix A.1 ({d.terminal_iterations} iterations)"
                                                 if terminal == "recursion" else "scaled copy of X0 (offline/terminal.py)"))
        echo(f"mu = {d.mu:.6g} (sup ||D||^2 {'=' if d.mu_method.startswith('exact') else '<='} {d.mu_sup:.6g} "
                   f"over {d.mu_region}; {d.mu_method})")
        echo(f"H_theta for (9): {len(d.H_theta)} rows")
        echo("")
        echo(f"{'check':28s} {'result':8s} {'margin':>12s} {'tol':>9s}  detail")
        for c in checks:
            margin = "n/a" if c.margin is None else f"{c.margin:.3e}"
            echo(f"{c.name:28s} {c.status:8s} {margin:>12s} {c.tolerance:9.1e}  {c.detail}")
        echo("")
        echo("all design checks pass" if ok else "SOME DESIGN CHECKS FAILED")
    if out_file is not None:
        _save(spec, d, out_file, ok)
    exit_verdict(ok)


def _save(spec, d, out_file: str, ok: bool) -> None:
    """Write the design file (offline/design_file.py) when every check passed; say so on stderr."""
    from amcp_drake.cli.common import write_error
    from amcp_drake.model.problem_hash import spec_hash
    from amcp_drake.offline.design_file import save_design

    if not ok:
        echo(f"design not written to {out_file}: a design check failed", err=True)
        return
    try:
        save_design(spec, d, out_file)
    except OSError as exc:
        raise write_error("--out", out_file, exc) from None
    echo(f"design written to {out_file} (problem SHA-256 {spec_hash(spec)})", err=True)
