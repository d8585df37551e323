"""The automatic design's fallback in normalised state units (session 7).

The design is not invariant under a change of state units x̃ = T x, T = diag(t_i), although every claim
of the paper is: the template directions of X0 are fixed unit vectors, the LMI objective and the
solvers' tolerances see the numbers as written. A system whose states are in very different units
(a position in m next to a velocity in mm/s) can then fail every candidate that the same system in
comparable units passes (measured: ``massera2017`` with x̃ = diag(100, 0.01, 0.01) x failed all 15).

When every candidate of the automatic design fails, it is run once more on the problem in the units
ξ = S x, S = diag(1/e_i), e_i = max_{w ∈ W} |w_i| (W's extent in state i: W transforms with the units,
so ξ is the same for the system in any diagonal units), and the design is mapped back to x:

    K = K_ξ S,  P = S P_ξ S,  H_x = H_ξ S,  x^j = S⁻¹ ξ^j,  A_z = S⁻¹ A_z,ξ S,  H_T = H_T,ξ S,

while w̄, f̄, h̄, λ̄, h_T, Θ0 and the terminal iterations are unit-free (each is a support of a set in
rows that are mapped with it). μ of (11) is recomputed in x, since the LMS step (12) runs in the
user's units. The mapped design must then pass every check of
:func:`~amcp_drake.offline.checks.verify_design` in x, independently of how it was found; it is the
user's problem that is certified, never the normalised one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from amcp_drake.model.problem import DesignOptions, Problem
from amcp_drake.model.state_units import scale_states
from amcp_drake.offline.result import OfflineDesign, regressor_bound

#: Units are left as they are when W's extents differ by less than this factor (the normalised
#: problem would be the same up to a common scale, for which the design is already unit-free).
UNIFORM_RATIO = 1.5


def w_extents(problem: Problem) -> np.ndarray:
    """e_i = max_{w ∈ W} |w_i| from the vertices of W (exact; W is bounded with 0 inside, so e_i > 0)."""
    return np.max(np.abs(problem.w_vertices()), axis=0)


def needs_units(problem: Problem) -> bool:
    """True when W's extents over the states differ by at least :data:`UNIFORM_RATIO`."""
    e = w_extents(problem)
    return bool(np.max(e) >= UNIFORM_RATIO * np.min(e))


def to_normalised(problem: Problem, options: DesignOptions) -> tuple[Problem, DesignOptions, np.ndarray]:
    """(the problem in ξ = S x, the options with a given K, P, X0 mapped into ξ, S as a vector)."""
    s = 1.0 / w_extents(problem)
    S_inv = np.diag(1.0 / s)
    changes = {}
    if options.K is not None:
        changes["K"] = np.asarray(options.K, float) @ S_inv
    if options.P is not None:
        changes["P"] = S_inv @ np.asarray(options.P, float) @ S_inv
    if options.x0_H is not None:
        changes["x0_H"] = np.asarray(options.x0_H, float) @ S_inv
    return scale_states(problem, s), replace(options, **changes), s


def from_normalised(design: OfflineDesign, s: np.ndarray, problem: Problem, options: DesignOptions) -> OfflineDesign:
    """The design of the problem in ξ = diag(s) x mapped back to x (module docstring); μ recomputed
    on ``problem`` (the user's units)."""
    S, S_inv = np.diag(s), np.diag(1.0 / s)
    mu_sup, region = regressor_bound(problem, options.mu_state_bound)
    info = dict(design.info, state_units={"normalised_by": "W extents", "xi_equals_diag_times_x": s.tolist()})
    return replace(design, K=design.K @ S, P=S @ design.P @ S, H_x=design.H_x @ S,
                   X0_vertices=design.X0_vertices @ S_inv, A_z=S_inv @ design.A_z @ S, H_T=design.H_T @ S,
                   mu=float(options.mu_fraction / mu_sup), mu_sup=float(mu_sup), mu_region=region, info=info)


__all__ = ["UNIFORM_RATIO", "from_normalised", "needs_units", "to_normalised", "w_extents"]
