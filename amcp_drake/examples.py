"""Built-in problems. ``lorenzen2019()`` is Example 1 of the paper (spec §9).

Data: A0, B0, A_i, B_i, Θ, W, N, Q, R, θ̂0, θ* from the paper [SEED]; the constraints
x2 >= -0.3, |u| <= 1, x0 = [2, 3] from the third-party replication SRC-1 (spec §9).
Z is unbounded in x1, so μ is evaluated on the box |x_i| <= 3 (as SRC-1 does); the closed loop
is checked to stay inside that box (Lemma 5 precondition, design.md Pitfalls).
"""

from __future__ import annotations

from importlib import resources

from .problem import Problem, ProblemSpec
from .problem_io import load_spec


def lorenzen2019_spec() -> ProblemSpec:
    """Example 1 with its design options and scenario (x0 = [2, 3], θ* = [0.8, 0.2, -0.5])."""
    with resources.as_file(resources.files("amcp_drake") / "data" / "lorenzen2019.json") as path:
        return load_spec(path)


def lorenzen2019() -> Problem:
    """Example 1 of Lorenzen, Cannon & Allgöwer (2019), spec §9."""
    return lorenzen2019_spec().problem


EXAMPLES = {"lorenzen2019": lorenzen2019_spec}


def get_example(name: str) -> ProblemSpec:
    """A built-in example by name; raises ProblemError listing the names."""
    from .errors import ProblemError

    if name not in EXAMPLES:
        raise ProblemError("--example", f"one of {sorted(EXAMPLES)}", repr(name))
    return EXAMPLES[name]()
