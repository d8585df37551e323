"""Proposition 9 (prediction tube): the tube of every QP solution contains the measured state,
the realised successor, and the one-step image of each cross-section under every vertex of Θ_k
and W, and satisfies the constraints (5a)-(5c); checked by vertex enumeration, not through Λ."""

from __future__ import annotations

from hypothesis import given

from . import nversion, profiles
from .failures import require
from .suite import CLOSED_LOOP, observe


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_proposition9_tube_contains_every_one_step_image(case, backend, runner, coverage):
    """x_k ∈ X_{0|k}, x_{k+1} ∈ X_{1|k}, and A(θ)x + B(θ)(Kx + v_l) + w ∈ X_{l+1|k} for every vertex x
    of X_{l|k}, θ of Θ_k, w of W, and (x, Kx + v_l) ∈ Z on X_{l|k}, at every step and l."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_proposition9_tube_contains_every_one_step_image", backend, coverage)
    ids = ("tube_contains_state", "tube_contains_next_state", "tube_propagation", "tube_constraints")
    for result in nversion.check(ids, traj):
        require(result, test="proposition9", backend=backend, case=case, traj=traj)
