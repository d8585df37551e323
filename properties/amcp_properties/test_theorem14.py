"""Theorem 14 (closed-loop properties): (i) recursive feasibility, (ii) θ* ∈ Θ_k and θ̂_k ∈ Θ,
(iii) (x_k, u_k) ∈ Z, on random problems from initial states on or near the boundary of the
feasible set of (20), with θ* anywhere in Θ and disturbances uniform on W, at its vertices, or zero."""

from __future__ import annotations

from hypothesis import given

from . import claims, profiles
from .failures import require
from .suite import CLOSED_LOOP, observe


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_theorem14_i_recursive_feasibility(case, backend, runner, coverage):
    """𝔻(x_0, Θ_0) ≠ ∅ (the generator guarantees it with an independent LP) implies
    𝔻(x_k, Θ_k) ≠ ∅ for every k: every step's QP (20) is solved, and its solution satisfies every
    constraint of 𝔻(x_k, Θ_k) when re-checked without the solver's multipliers."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_theorem14_i_recursive_feasibility", backend, coverage)
    require(claims.recursive_feasibility(traj), test="theorem14_i", backend=backend, case=case, traj=traj)


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_theorem14_ii_theta_star_in_theta_k_and_estimate_in_theta(case, backend, runner, coverage):
    """θ* ∈ Θ_k for every k (set membership never excludes the true parameter), and θ̂_k ∈ Θ."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_theorem14_ii_theta_star_in_theta_k_and_estimate_in_theta", backend, coverage)
    require(claims.theta_star_in_sets(traj), test="theorem14_ii", backend=backend, case=case, traj=traj)
    require(claims.theta_hat_in_prior(traj), test="theorem14_ii", backend=backend, case=case, traj=traj)


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_theorem14_iii_state_and_input_constraints_hold(case, backend, runner, coverage):
    """F x_k + G u_k <= 1 at every applied input, eq. (4)."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_theorem14_iii_state_and_input_constraints_hold", backend, coverage)
    require(claims.constraints_satisfied(traj), test="theorem14_iii", backend=backend, case=case, traj=traj)
