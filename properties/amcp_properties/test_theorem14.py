"""Theorem 14 (closed-loop properties): (i) recursive feasibility, (ii) θ* ∈ Θ_k and θ̂_k ∈ Θ,
(iii) (x_k, u_k) ∈ Z, on random problems from initial states on or near the boundary of the
feasible set of (20), with θ* anywhere in Θ and disturbances uniform on W, at its vertices, or zero."""

from __future__ import annotations

import pytest
from hypothesis import given

from . import nversion, profiles
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
    for result in nversion.check("recursive_feasibility", traj):
        require(result, test="theorem14_i", backend=backend, case=case, traj=traj)


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_theorem14_ii_theta_star_in_theta_k_and_estimate_in_theta(case, backend, runner, coverage):
    """θ* ∈ Θ_k for every k (set membership never excludes the true parameter), and θ̂_k ∈ Θ."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_theorem14_ii_theta_star_in_theta_k_and_estimate_in_theta", backend, coverage)
    for result in nversion.check(("theta_star_in_Theta_k", "theta_hat_in_Theta"), traj):
        require(result, test="theorem14_ii", backend=backend, case=case, traj=traj)


@profiles.shared_seed
@profiles.examples("closed_loop")
@given(case=CLOSED_LOOP)
def test_theorem14_iii_state_and_input_constraints_hold(case, backend, runner, coverage):
    """F x_k + G u_k <= 1 at every applied input, eq. (4)."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_theorem14_iii_state_and_input_constraints_hold", backend, coverage)
    for result in nversion.check("state_input_constraints", traj):
        require(result, test="theorem14_iii", backend=backend, case=case, traj=traj)


#: Minimum fractions of the closed-loop runs that reach the hard cases (both profiles);
#: measured from the runs by :mod:`amcp_properties.coverage` (see there for the definitions).
#: Among them the problems in badly scaled state units (ci: 20 % of the 56 runs).
MIN_HARD_CASE_COVERAGE = {"theta_k_lower_dim": 0.10, "theta_star_vertex": 0.10, "theta_star_facet": 0.10,
                          "scaled_units": 0.10}
#: The property whose runs are measured (every closed-loop claim shares them under ci).
MEASURED_TEST = "test_theorem14_i_recursive_feasibility"


def test_hard_cases_are_reached(backend, coverage):
    """Runs after the closed-loop properties of the same backend (pytest groups the session-scoped
    backend parameter): at least 10 % of their runs had a lower-dimensional Θ_k, θ* at a vertex of
    Θ, and θ* on a facet, so the claims were checked on the degenerate sets, not only on nice ones;
    some of the problems are in badly scaled state units."""
    data = coverage.summary().get(f"{MEASURED_TEST}[{backend}]")
    if data is None or not data["examples"]:
        pytest.skip(f"{MEASURED_TEST}[{backend}] did not run in this session (deselected)")
    fractions = data["fractions"]
    print(f"hard-case coverage [{backend}] over {data['examples']} runs: "
          + ", ".join(f"{k}={fractions.get(k, float('nan')):.2f}" for k in MIN_HARD_CASE_COVERAGE))
    low = {k: fractions.get(k, 0.0) for k, minimum in MIN_HARD_CASE_COVERAGE.items() if fractions.get(k, 0.0) < minimum}
    assert not low, f"hard-case coverage below the minimum {MIN_HARD_CASE_COVERAGE} on {backend}: {low}"
