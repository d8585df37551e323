"""``amcp verify``: the Hypothesis property suite (package ``amcp_properties``) and its mutants.

The suite runs in a child ``python -m pytest --pyargs amcp_properties`` (so it works after a plain
install, from any directory), with the profile and backends passed through the environment
(``AMCP_PROFILE``, ``AMCP_BACKENDS``); its JUnit XML and coverage JSON are read back to print one
row per claim and backend: examples run, coverage fractions, result. ``--mutants`` then runs the
seeded bugs of :mod:`amcp_properties.mutants` on targeted scenarios and prints which claim caught
each. Exit 0 only when every property passes (and, with ``--mutants``, the unmutated baseline
passes and every claim-breaking mutant is caught).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import click

from amcp_drake.cli.common import bad_input_exits_2, exit_verdict, interruptible

#: property test -> the claim it checks (table order)
CLAIMS = {
    "test_theorem14_i_recursive_feasibility": "Theorem 14 (i) recursive feasibility",
    "test_theorem14_ii_theta_star_in_theta_k_and_estimate_in_theta": "Theorem 14 (ii) θ* ∈ Θk, θ̂k ∈ Θ",
    "test_theorem14_iii_state_and_input_constraints_hold": "Theorem 14 (iii) (xk, uk) ∈ Z",
    "test_lemma3_update_is_consistent_with_data_and_nested": "Lemma 3 Θk ∩ Δk+1 ⊆ Θk+1 ⊆ Θk",
    "test_lemma5_lms_error_energy_is_bounded_for_every_m": "Lemma 5 LMS inequality, (11)",
    "test_proposition9_tube_contains_every_one_step_image": "Proposition 9 prediction tube",
    "test_assumption11_terminal_set_is_robustly_invariant": "Assumption 11 X_f invariant",
    "test_corollary16_state_converges_when_disturbance_vanishes": "Corollary 16 xk → 0",
    "test_finite_gain_l2_ratio_stays_bounded": "(22) finite ℓ2 gain",
    "test_backends_agree_in_lockstep": "Drake and cvxpy agree (lockstep)",
    "test_claim_checks_catch_seeded_bug": "checks catch seeded bug",
}
FRACTIONS = (("constraints_active", "Z act"), ("theta_shrank", "Θ shr"), ("theta_star_on_boundary", "θ*∈∂"),
             ("theta_star_near_boundary", "θ*≈∂"), ("theta_k_lower_dim", "Θk↓d"), ("theta_star_vertex", "θ*vx"),
             ("theta_star_facet", "θ*fc"))


def _results(junit: Path) -> dict[str, tuple[str, str]]:
    """test id "name[backend]" -> (outcome, message) from pytest's JUnit XML."""
    out: dict[str, tuple[str, str]] = {}
    if not junit.exists():
        return out
    for case in ET.parse(junit).getroot().iter("testcase"):
        outcome, message = "passed", ""
        for tag in ("failure", "error", "skipped"):
            node = case.find(tag)
            if node is not None:
                outcome = {"failure": "FAILED", "error": "ERROR", "skipped": "skipped"}[tag]
                message = (node.get("message") or "").splitlines()[0][:100] if node.get("message") else ""
                break
        out[case.get("name", "")] = (outcome, message)
    return out


def _print_table(results: dict[str, tuple[str, str]], coverage: dict) -> None:
    tests = coverage.get("tests", {})
    header = f"{'claim':52s} {'backend':8s} {'examples':>8s} " + " ".join(f"{h:>6s}" for _, h in FRACTIONS) + "  result"
    click.echo(header)
    click.echo("-" * len(header))
    for test_id in sorted(results, key=lambda t: (list(CLAIMS).index(t.split("[")[0]) if t.split("[")[0] in CLAIMS
                                                  else 99, t)):
        name, _, backend = test_id.partition("[")
        backend = backend.rstrip("]")
        label = CLAIMS.get(name, name)
        if backend not in ("drake", "cvxpy"):  # parametrised by something else (a mutant)
            label, backend = f"{label}: {backend}", "drake"
        data = tests.get(test_id, {})
        fr = data.get("fractions", {})
        cells = " ".join(f"{fr[k]:6.2f}" if k in fr else f"{'-':>6s}" for k, _ in FRACTIONS)
        outcome, message = results[test_id]
        tail = f"  ({message})" if outcome != "passed" and message else ""
        click.echo(f"{label[:52]:52s} {backend:8s} {data.get('examples', 0):8d} {cells}  {outcome}{tail}")
    gen = coverage.get("distinct_rejection_rate")
    if gen is not None:
        click.echo(f"\ngenerator: {coverage.get('distinct_problems', 0)} distinct problems, "
                   f"{gen:.1%} rejected by the offline design; closed-loop runs "
                   f"{coverage.get('runs', {}).get('simulated', 0)} simulated, "
                   f"{coverage.get('runs', {}).get('reused', 0)} reused")
    _print_answers(coverage.get("answers", {}))
    click.echo("coverage: Z act = a constraint of Z active in the run; Θ shr = Θk shrank; θ*∈∂ / θ*≈∂ = θ* within "
               "1e-6 / 1e-2 of the boundary of Θk; Θk↓d = some Θk lower-dimensional (Chebyshev radius <= 1e-5); "
               "θ*vx / θ*fc = θ* at a vertex of Θ / elsewhere on its boundary (fractions of the examples)")


def _print_answers(answers: dict) -> None:
    """Fallback and re-solve rates per backend and kind over every closed-loop run of the suite."""
    if not answers:
        return
    click.echo("\nsolver answers over the suite's runs (not the backend's first answer: re-solved / fallback / not solved):")
    for backend in sorted(answers):
        for problem, c in sorted(answers[backend].items()):
            n = c.get("answers", 0)
            kinds = ", ".join(f"{k} {v} ({v / n:.2%})" for k, v in sorted(c.items())
                              if k not in ("answers", "first", "resolved", "fallback", "not_solved") and v)
            click.echo(f"  {backend:6s} {problem:13s} {n:7d} answers: resolved {c.get('resolved', 0)}, fallback "
                       f"{c.get('fallback', 0)} ({c.get('fallback', 0) / max(n, 1):.2%}), not solved "
                       f"{c.get('not_solved', 0)}" + (f"; {kinds}" if kinds else ""))


def _run_mutants(backends: list[str]) -> bool:
    """The seeded bugs of :mod:`amcp_properties.mutants`, run in a child process like the suite
    (the library does not import the test package); True when every claim-breaking mutant is caught."""
    return subprocess.call([sys.executable, "-m", "amcp_properties.mutants", *backends]) == 0


@click.command("verify")
@click.option("--profile", type=click.Choice(["ci", "thorough"]), default="ci", show_default=True,
              help="Hypothesis profile: ci (derandomized, ~6 min for both backends) or thorough (thousands of examples).")
@click.option("--backend", type=click.Choice(["drake", "cvxpy", "both"]), default="both", show_default=True,
              help="Online backend(s) under test; the lockstep comparison needs both.")
@click.option("--mutants", "with_mutants", is_flag=True, help="Also run the seeded bugs and report which claim caught each.")
@click.option("--pytest-arg", "pytest_args", multiple=True, help="Extra argument for pytest (repeatable), e.g. -x.")
@interruptible(lambda kw, exc: "the property suite was stopped (its pytest process too); nothing was written; "
               "run the command again")
@bad_input_exits_2
def verify_cmd(profile, backend, with_mutants, pytest_args):
    """Run the property suite (one test per claim of the paper) and print claim, examples, coverage, result."""
    backends = ["drake", "cvxpy"] if backend == "both" else [backend]
    with tempfile.TemporaryDirectory(prefix="amcp-verify-") as tmp:
        junit, cov = Path(tmp) / "junit.xml", Path(tmp) / "coverage.json"
        env = dict(os.environ, AMCP_PROFILE=profile, AMCP_BACKENDS=",".join(backends), AMCP_COVERAGE_FILE=str(cov))
        cmd = [sys.executable, "-m", "pytest", "--pyargs", "amcp_properties", "-q", "-p", "no:cacheprovider",
               f"--junitxml={junit}", *pytest_args]
        click.echo(f"running: {' '.join(cmd)}  (AMCP_PROFILE={profile}, AMCP_BACKENDS={','.join(backends)})")
        code = subprocess.call(cmd, env=env)
        results = _results(junit)
        coverage = json.loads(cov.read_text()) if cov.exists() else {}
    click.echo("")
    if results:
        _print_table(results, coverage)
    suite_ok = code == 0 and bool(results)
    click.echo(f"\nproperty suite: {'all properties hold' if suite_ok else f'FAILED (pytest exit code {code})'}")
    mutants_ok = True
    if with_mutants:
        mutants_ok = _run_mutants(backends)
        click.echo(f"\nmutants: {'every claim-breaking mutant caught' if mutants_ok else 'NOT ALL CAUGHT'}")
    exit_verdict(suite_ok and mutants_ok)
