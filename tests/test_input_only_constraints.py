"""Constraints on the input only (F = 0), uncertainty only in B, an unstable A0 and ``mu_state_bound`` set:
the terminal-set recursion runs on a set Z leaves unbounded, the system designs and certifies on both
backends; a Θ on which the input gain vanishes is refused with the advice to shrink Θ; identical failures
of several candidates are listed once with their count."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.backends import get_backend
from amcp_drake.cli import main
from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.offline.auto import Attempt, AutoDesignError, grouped_lines, vanishing_input_advice
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design_fixed


def input_only(theta_box: tuple[float, float] = (-1.0, 1.0), b0: float = 0.5) -> dict:
    """x⁺ = [[1.05, 0.2], [0, 0.95]] x + (b0 + 0.2 θ) e₂ u + w, |u| <= 1 the only constraint, |w_i| <= 0.01."""
    lo, hi = theta_box
    return {"format": "amcp-problem", "version": 1, "name": "input_only",
            "system": {"A0": [[1.05, 0.2], [0.0, 0.95]], "B0": [[0.0], [b0]], "A": [[[0, 0], [0, 0]]],
                       "B": [[[0.0], [0.2]]]},
            "W": {"H": [[100, 0], [-100, 0], [0, 100], [0, -100]]},
            "Theta": {"H": [[1], [-1]], "h": [hi, -lo]},
            "Z": {"F": [[0, 0], [0, 0]], "G": [[1], [-1]]},
            "cost": {"Q": [[1, 0], [0, 1]], "R": [[1]], "N": 10},
            "theta_hat0": [0.5 * (lo + hi)],
            "design": {"mu_state_bound": 5.0},
            "scenario": {"x0": [0.3, 0.0], "theta_star": [0.5 * hi], "steps": 10, "disturbance": "uniform", "seed": 0}}


def test_the_terminal_set_recursion_on_an_input_only_z_designs_and_passes_every_check():
    """The mrpi template's recursion starts from X_f^0 = {G K z + f̄ α <= 1}, unbounded in z: its redundancy LPs
    include unbounded ones, which must be told from failures."""
    spec = spec_from_dict(input_only())
    d = design_fixed(spec.problem, replace(spec.design, x0_template="mrpi"), backend="drake")
    assert [c.name for c in verify_design(spec.problem, d, spec.design.mu_state_bound) if not c.passed] == []


def test_an_unbounded_support_lp_is_infinite_not_failed():
    be = get_backend("drake")
    H = np.array([[1.0, 0.0], [0.0, -1.0]])  # x1 <= 1, x2 >= -1: unbounded above in x2
    values = be.support(H, np.ones(2), np.array([[0.0, 1.0], [1.0, 0.0], [0.3, 1.0]]))
    assert values[0] == np.inf and values[2] == np.inf
    assert values[1] == pytest.approx(1.0, abs=1e-8)
    assert be.last_support_failures == []


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_the_input_only_system_designs_and_certifies_ten_steps(tmp_path, backend):
    path = tmp_path / "input_only.json"
    path.write_text(json.dumps(input_only()))
    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["certify", str(path), "--backend", backend, "--steps", "10", "--out", str(out)],
                                catch_exceptions=False)
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "pass", cert["counts"]
    assert result.exit_code == 0, result.output


def test_a_theta_on_which_the_input_gain_vanishes_gets_the_advice_to_shrink_theta():
    """B(θ) = (0.5 + 0.2 θ) e₂ vanishes at θ = −2.5: Θ = [−3, 1] contains it (A unstable), Θ = [−1, 1] does not."""
    bad = spec_from_dict(input_only((-3.0, 1.0))).problem
    advice = vanishing_input_advice(bad)
    assert advice is not None and advice.startswith("shrink Theta") and "-2.5" in advice
    assert vanishing_input_advice(spec_from_dict(input_only()).problem) is None
    # a vanishing gain where A is stable is no reason to shrink Θ
    stable = input_only((-3.0, 1.0))
    stable["system"]["A0"] = [[0.5, 0.2], [0.0, 0.4]]
    assert vanishing_input_advice(spec_from_dict(stable).problem) is None


def test_identical_candidate_failures_are_listed_once_with_their_count():
    attempts = [Attempt(f"c{i}", "design failed", "gain LMI (16): solver status infeasible", 0.5) for i in range(13)]
    attempts.insert(2, Attempt("other", "too large", "X0 needs 9 GiB", 0.1))
    lines = grouped_lines(attempts)
    assert len(lines) == 2
    assert sum("gain LMI (16): solver status infeasible" in line for line in lines) == 1
    assert "(13 x" in lines[0] and lines[0].startswith("  1, 2, 4, ")
    text = str(AutoDesignError(attempts, "shrink Theta: because"))
    assert text.count("solver status infeasible") == 1 and text.rstrip().endswith("Next: shrink Theta: because")
