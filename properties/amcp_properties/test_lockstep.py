"""The two backends agree in lockstep: fed the same x_k, Θ_{k-1}, θ̂_{k-1} and data, the Drake
and cvxpy formulations (both with Clarabel at the same accurate tolerances, lockstep.ACCURATE)
return the same Θ_k, θ̂_k and v within tolerances: the plain form (15) of (20), and its vertex form
(Drake's condensed program against cvxpy's compiled route, amcp_reference.compiled_clarabel)."""

from __future__ import annotations

from hypothesis import given

from . import profiles
from .failures import require
from .lockstep import accurate_run, backends_agree, vertex_case
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


@profiles.shared_seed
@profiles.examples("lockstep")
@given(case=CLOSED_LOOP)
def test_vertex_forms_agree_in_lockstep(case, backend, both_backends, coverage):
    """The same comparison for the vertex form of (20), on the case with the options that
    form takes (:func:`amcp_properties.lockstep.vertex_case`: the CE cost, constant θ, no PE). A saved
    failure replays with the vertex form: ``AdaptiveMPC(..., formulation="vertex")``."""
    follower = both_backends[1] if backend == both_backends[0] else both_backends[0]
    case = vertex_case(case)
    traj = accurate_run(case, backend, "vertex")
    observe(case, traj, "test_vertex_forms_agree_in_lockstep", backend, coverage)
    require(backends_agree(traj, case, follower, "vertex"), test="lockstep_vertex", backend=backend, case=case, traj=traj)
