"""Lemma 3, (10): the set-membership update keeps every parameter consistent with the new data
and never grows the set, Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1} ⊆ Θ_k (with Θ ⊆ Θ_0)."""

from __future__ import annotations

from hypothesis import given

from . import nversion, profiles
from .failures import require
from .suite import CLOSED_LOOP, observe


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_lemma3_update_is_consistent_with_data_and_nested(case, backend, runner, coverage):
    """Both inclusions of (10) at every step, Δ_{k+1} rebuilt from (x_k, u_k, x_{k+1}) by (6)
    (for the moving window of Remark 4, the intersection of the window's data sets)."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_lemma3_update_is_consistent_with_data_and_nested", backend, coverage)
    for result in nversion.check(("Theta0_contains_Theta", "Theta_k_nested", "Theta_k_lower_inclusion"), traj):
        require(result, test="lemma3", backend=backend, case=case, traj=traj)
