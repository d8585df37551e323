"""Built-in problems. ``lorenzen2019()`` is Example 1 of the paper (spec §9); ``lorenzen2019_ex2``
is Example 2 (Section 4 extensions: PE input and time-varying parameters, choices documented).

Data: A0, B0, A_i, B_i, Θ, W, N, Q, R, θ̂0, θ* from the paper [SEED]; the constraints
x2 >= -0.3, |u| <= 1, x0 = [2, 3] from the third-party replication SRC-1 (spec §9).
Z is unbounded in x1, so μ is evaluated on the box |x_i| <= 3 (as SRC-1 does); the closed loop
is checked to stay inside that box (Lemma 5 precondition, design.md Pitfalls).
"""

from __future__ import annotations

from importlib import resources

from amcp_drake.model.problem import Problem, ProblemSpec
from amcp_drake.model.problem_io import load_spec


def lorenzen2019_spec() -> ProblemSpec:
    """Example 1 with its design options and scenario (x0 = [2, 3], θ* = [0.8, 0.2, -0.5])."""
    with resources.as_file(resources.files("amcp_drake") / "data" / "lorenzen2019.json") as path:
        return load_spec(path)


def lorenzen2019() -> Problem:
    """Example 1 of Lorenzen, Cannon & Allgöwer (2019), spec §9."""
    return lorenzen2019_spec().problem


def lorenzen2019_ex2_spec() -> ProblemSpec:
    """Example 2 of the paper (spec §9): Example 1's system with a persistently exciting input and
    time-varying parameters. The paper's d_θ, θ*_k trajectory and PE parameters are not recoverable;
    the choices (docs/decisions.md, "Section 4 extensions", Example 2) are: the same system, Θ, W, Z,
    cost, x0 and design as Example 1; online section update "fixed" (9), d_θ = 0.01, PE window
    P = n + 1 = 3 and level ρ = 0.8 (SRC-1's values), certainty-equivalence cost; scenario 100 steps.
    The scenario holds the drifting θ*_0 … θ*_100 of :func:`lorenzen2019_ex2_theta_star` (a test
    checks that the file and the function agree)."""
    with resources.as_file(resources.files("amcp_drake") / "data" / "lorenzen2019_ex2.json") as path:
        return load_spec(path)


def lorenzen2019_ex2_theta_star(steps: int = 100, amplitude: float = 0.3, period: int = 100):
    """θ*_k = θ*_0 − amplitude·(1 − cos(2πk/period))/2 · e_1, k = 0..steps (θ*_0 = [0.8, 0.2, −0.5]):
    θ1 drifts from 0.8 to 0.5 and back, stays in Θ, and moves at most amplitude·π/period ≈ 0.0094
    per step, within d_θ = 0.01 (Assumption 17)."""
    import numpy as np

    k = np.arange(steps + 1)
    seq = np.tile(np.array([0.8, 0.2, -0.5]), (steps + 1, 1))
    seq[:, 0] -= amplitude * (1.0 - np.cos(2.0 * np.pi * k / period)) / 2.0
    return seq


EXAMPLES = {"lorenzen2019": lorenzen2019_spec, "lorenzen2019_ex2": lorenzen2019_ex2_spec}


def get_example(name: str) -> ProblemSpec:
    """A built-in example by name; raises ProblemError listing the names."""
    from amcp_drake.model.errors import ProblemError

    if name not in EXAMPLES:
        raise ProblemError("--example", f"one of {sorted(EXAMPLES)}", repr(name))
    return EXAMPLES[name]()
