"""A problem written in other state units: x̃ = T x with T = diag(scales).

Used by the automatic design's fallback in normalised units (:mod:`amcp_drake.offline.units`) and by
the generator's badly scaled problems (``random_problems.ProblemShape.scaled_states``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from amcp_drake.model.problem import Problem


def scale_states(problem: Problem, scales) -> Problem:
    """``problem`` in the coordinates x̃ = T x, T = diag(scales): x̃⁺ = T A(θ) T⁻¹ x̃ + T B(θ) u + w̃,
    w̃ = T w ∈ T W = {H_w T⁻¹ w̃ <= 1}, Z = {F T⁻¹ x̃ + G u <= 1}, stage cost x̃ᵀ T⁻ᵀ Q T⁻¹ x̃. Θ, θ*,
    the inputs and every claim of the paper are unchanged; an initial state x0 becomes T x0."""
    scales = np.asarray(scales, float)
    T, T_inv = np.diag(scales), np.diag(1.0 / scales)
    return replace(problem, A0=T @ problem.A0 @ T_inv, B0=T @ problem.B0,
                   A=np.array([T @ A_i @ T_inv for A_i in problem.A]), B=np.array([T @ B_i for B_i in problem.B]),
                   H_w=problem.H_w @ T_inv, F=problem.F @ T_inv, Q=T_inv @ problem.Q @ T_inv)


__all__ = ["scale_states"]
