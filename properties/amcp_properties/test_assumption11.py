"""Assumption 11 (terminal set): the X_f computed by the offline design of each backend is
non-empty, satisfies the constraints under u = Kx, and is robustly invariant for every vertex of Θ."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given, note

from amcp_drake.model.errors import DesignError
from amcp_drake.offline.design import design

from . import nversion, profiles
from .failures import require
from .suite import DESIGNS


@profiles.shared_seed
@profiles.examples("design")
@given(generated=DESIGNS)
def test_assumption11_terminal_set_is_robustly_invariant(generated, backend, coverage):
    """Checked on the backend's own X0 and X_f with an LP per vertex of X_f that looks for a
    successor (z⁺, α⁺) ∈ X_f, so the design's own witness (A_z, φ) is not trusted.

    The generator designed the problem with Drake; for another backend the problem is designed
    again by that backend with Drake's K and P given (as ``amcp compare`` does): Assumption 11 is
    about the terminal-set recursion and its LPs, and the gain SDP (16) is compared elsewhere."""
    problem = generated.problem
    if backend == "drake":
        offline = generated.design
    else:
        options = replace(generated.spec.design, K=generated.design.K, P=generated.design.P)
        try:
            offline = design(problem, options, backend=backend)
        except DesignError as exc:  # Drake's design of the same problem succeeded: a disagreement
            raise AssertionError(f"{backend} cannot compute X0/X_f for a problem that Drake designs "
                                 f"(with Drake's K, P): {exc}") from None
    coverage.count(f"test_assumption11_terminal_set_is_robustly_invariant[{backend}]")
    note(f"problem: n={problem.n} m={problem.m} p={problem.p} labels={generated.labels}; "
         f"X_f has {len(offline.H_T)} rows")
    for result in nversion.check(("design.x_f_non_empty", "design.x_f_invariant", "design.x_f_in_z"), problem, offline):
        require(result, test="assumption11", backend=backend, spec=generated.spec, design=offline)
