"""Lemma 5 (point estimate): the exact inequality proved by (13), for every m, and its
precondition, the gain condition (11)."""

from __future__ import annotations

from hypothesis import given

from . import nversion, profiles
from .failures import require
from .suite import CLOSED_LOOP, observe


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_lemma5_lms_error_energy_is_bounded_for_every_m(case, backend, runner, coverage):
    """(1/μ)‖θ̂_{m+1} − θ*‖² + Σ_{k<=m}‖x̃_{1|k}‖² <= (1/μ)‖θ̂_0 − θ*‖² + Σ_{k<=m}‖w_k‖² for all m,
    with μ satisfying (11) on Z and μ‖D_k‖² <= 1 along the run."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_lemma5_lms_error_energy_is_bounded_for_every_m", backend, coverage)
    for result in nversion.check(("mu_precondition", "lemma5"), traj):
        require(result, test="lemma5", backend=backend, case=case, traj=traj)
