"""The finite ℓ2 gain (22) of Theorem 14."""

from __future__ import annotations

from hypothesis import given

from . import claims, profiles
from .failures import require
from .suite import LONG, observe


@profiles.shared_seed
@profiles.examples("long")
@given(case=LONG)
def test_finite_gain_l2_ratio_stays_bounded(case, backend, runner, coverage):
    """r_K = Σ_{k<=K}‖x_k‖² / (‖x_0‖² + ‖θ̂_0 − θ*‖² + Σ_{k<=K}‖w_k‖²) stays below a ceiling for every
    K of long runs (persistent disturbances uniform on W, at its vertices or zero, or finite-energy
    ones that stop at a random step).

    What this does: (22) says r_K <= max(c0, c1, c2) for all K. The ceiling is 10 times the ℓ2
    gain bound 2κ(P)/(1−γ)² that (16) gives the linear loop under u = Kx alone
    (:func:`claims.linear_gain_yardstick`); a closed loop whose gain grows with K (drift, limit
    cycles under finite-energy disturbances, divergence) exceeds it.

    What this does not prove: that constants c0, c1, c2 exist; no finite run can. The paper's
    constants are not computable from its proof (they involve ĉ_θ and c_A of (23)), so the
    ceiling is a yardstick, not the theorem's bound: a gain above it is suspicious, not a
    counterexample by itself, and a loop with a large but finite gain below it passes."""
    traj = runner.run(case, backend)
    observe(case, traj, "test_finite_gain_l2_ratio_stays_bounded", backend, coverage)
    require(claims.finite_gain(traj), test="finite_gain", backend=backend, case=case, traj=traj)
