"""The claim checks are not vacuous: seeded bugs (:mod:`amcp_properties.mutants`) make the claim
they break fail on the targeted scenarios, while the unmutated code passes every claim there.
A few representative mutants run here (Drake backend, ~40 s); ``amcp verify --mutants`` runs all."""

from __future__ import annotations

import pytest

from .mutants import MUTANTS, run_scenarios, targeted_scenarios

#: mutant -> a claim it must be caught by (one per family: tube data, set membership, LMS, projection, the tube QP's answers)
QUICK = {
    "w_bar_zero": "Proposition 9",
    "delta_sign_error": "Theorem 14 (ii) θ*",
    "lms_sign_flipped": "Lemma 5",
    "projection_skipped": "Theorem 14 (ii) θ̂",
    # the controller replaces the broken answers by checked fallbacks, so no claim of the paper fails
    "tube_lambda_nonneg_dropped": "answer checks",
    "tube_centre_deviation_dropped": "answer checks",
}
BACKEND = "drake"


@pytest.fixture(scope="module")
def scenarios():
    found = targeted_scenarios()
    baseline = run_scenarios(BACKEND, found)
    assert baseline == {}, f"the unmutated code fails claims on the targeted scenarios: {baseline}"
    return found


@pytest.mark.parametrize("name", sorted(QUICK))
def test_claim_checks_catch_seeded_bug(name, scenarios):
    mutant = next(m for m in MUTANTS if m.name == name)
    with mutant.patch():
        failures = run_scenarios(BACKEND, scenarios)
    assert QUICK[name] in failures, f"{name} ({mutant.bug}) was caught by {sorted(failures)}, not by {QUICK[name]}"
