"""The two backends agree in lockstep: fed the same x_k, Θ_{k-1}, θ̂_{k-1} and data, the Drake
and cvxpy formulations (both with Clarabel at the same accurate tolerances, lockstep.ACCURATE)
return the same Θ_k, θ̂_k and v within tolerances."""

from __future__ import annotations

from hypothesis import given

from . import profiles
from .failures import require
from .lockstep import accurate_run, backends_agree
from .suite import CLOSED_LOOP, observe


@profiles.shared_seed
@profiles.examples("lockstep")
@given(case=CLOSED_LOOP)
def test_backends_agree_in_lockstep(case, backend, both_backends, coverage):
    """``backend`` leads (its own run at accurate tolerances, not the shared one), the other backend
    follows step by step."""
    follower = both_backends[1] if backend == both_backends[0] else both_backends[0]
    traj = accurate_run(case, backend)
    observe(case, traj, "test_backends_agree_in_lockstep", backend, coverage)
    require(backends_agree(traj, case, follower), test="lockstep", backend=backend, case=case, traj=traj)
