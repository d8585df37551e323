"""Corollary 16: with a finite-energy disturbance (here w_k = 0 from a step k1 on), x_k → 0."""

from __future__ import annotations

from hypothesis import given

from . import claims, profiles
from .failures import require
from .suite import VANISHING, observe


@profiles.shared_seed
@profiles.examples("long")
@given(case=VANISHING)
def test_corollary16_state_converges_when_disturbance_vanishes(case, backend, runner, coverage):
    """After w stops at k1 (drawn in [0, 15]; k1 = 0 means w ≡ 0), the state decays by the factor
    max(1e-6, ρ̄^((T−k1−N)/2)) within the remaining T − k1 steps (claims.CONVERGENCE_TARGET).

    Corollary 16 states no rate, so a finite run can only show decay by some factor in some time;
    the factor and time are tied to the rate ρ̄ that Assumption 8 guarantees for u = Kx alone. A
    failure therefore means either no convergence or convergence much slower than u = Kx."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_corollary16_state_converges_when_disturbance_vanishes", backend, coverage)
    require(claims.convergence_after_disturbance(traj, case.zero_from), test="corollary16", backend=backend,
            case=case, traj=traj)
