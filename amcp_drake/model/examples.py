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


def _data_spec(name: str) -> ProblemSpec:
    """The problem file ``amcp_drake/data/<name>.json`` (a copy is in examples/)."""
    with resources.as_file(resources.files("amcp_drake") / "data" / f"{name}.json") as path:
        return load_spec(path)


def lorenzen2019_spec() -> ProblemSpec:
    """Example 1 with its design options and scenario (x0 = [2, 3], θ* = [0.8, 0.2, -0.5])."""
    return _data_spec("lorenzen2019")


def parsi2020_siso_spec() -> ProblemSpec:
    """Parsi, Iannelli & Smith, "Active exploration in adaptive MPC" (CDC 2020), single-input system of
    their public code (anilparsi/RobustAdaptiveMPC @ 1e4a283): n = 2, m = 1, p = 2, Θ = [−1, 1]²,
    |w_i| <= 0.05, x_i >= −10, |u| <= 2, N = 10, θ* = [0.95, 0.5]. Choices: docs/decisions.md."""
    return _data_spec("parsi2020_siso")


def parsi2020_mimo_spec() -> ProblemSpec:
    """Parsi et al. (CDC 2020), two-input system of the same code (@ 0ed4014): n = 2, m = 2, p = 2,
    |w_i| <= 0.1, x_i >= −10, −0.5 <= u1 <= 1, |u2| <= 2, N = 8, θ* = [0.95, 0.3]."""
    return _data_spec("parsi2020_mimo")


def bujarbaruah2022_spec() -> ProblemSpec:
    """Bujarbaruah, Rosolia, Stürz, Zhang & Borrelli, robust MPC with parametric and additive
    uncertainty (arXiv:2007.00930), public code monimoyb/RMPC_MixedUncertainty @ da50968:
    A = [1 0.15; 0.1 1] + ΔA, B = [0.1; 1.1] + ΔB, ΔA = ε_A [0 θ1; θ2 0] (box), ΔB = ε_B [θ3; θ4]
    (|θ3| + |θ4| <= 1, the convex hull of the code's four ΔB vertices), ε_A = ε_B = 0.1, |w_i| <= 0.1,
    |x_i| <= 8, |u| <= 4, Q = 10 I, R = 2, N = 3; p = 4. X0 with 24 facets (8 to 16 fail: divergent
    template iteration or no finite terminal set; docs/decisions.md)."""
    return _data_spec("bujarbaruah2022")


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
    return _data_spec("lorenzen2019_ex2")


def lorenzen2019_ex2_theta_star(steps: int = 100, amplitude: float = 0.3, period: int = 100):
    """θ*_k = θ*_0 − amplitude·(1 − cos(2πk/period))/2 · e_1, k = 0..steps (θ*_0 = [0.8, 0.2, −0.5]):
    θ1 drifts from 0.8 to 0.5 and back, stays in Θ, and moves at most amplitude·π/period ≈ 0.0094
    per step, within d_θ = 0.01 (Assumption 17)."""
    import numpy as np

    k = np.arange(steps + 1)
    seq = np.tile(np.array([0.8, 0.2, -0.5]), (steps + 1, 1))
    seq[:, 0] -= amplitude * (1.0 - np.cos(2.0 * np.pi * k / period)) / 2.0
    return seq


#: ε_A of the SLS-MPC family built in as ``slsmpc2d_eps<ε_A>`` (issue 14's sweep).
SLSMPC2D_EPS_A = (0.05, 0.15, 0.25, 0.35, 0.45)
#: Facet count of the minimal-RPI template X0 that designs for each ε_A of the sweep (issue 14's
#: measurement: 8 facets diverge beyond ε_A = 0.05, and at 0.25 12-16 facets leave X_f empty). An
#: ε_A outside the sweep gets the count of the next larger ε_A of the sweep (96 beyond 0.45).
SLSMPC2D_FACETS = {0.05: 8, 0.15: 12, 0.25: 20, 0.35: 48, 0.45: 96}


def slsmpc2d_spec(eps_a: float = 0.05) -> ProblemSpec:
    """The 2-D system of the polytopic SLS-MPC comparison (Chen, Preciado, Morari & Matni, Automatica
    2024; public code ShaoruChen/Polytopic-SLSMPC, examples/example_2d/main_feasibility_comparison_2d_eps_A.m
    @ 4ae465a): x⁺ = (A + ε_A θ1 E11) x + (B + ε_B θ2 e2) u + w with A = [1 0.15; 0.1 1], B = [0.1; 1.1],
    θ ∈ [−1, 1]² (the code's four vertices (±ΔA, ±ΔB)), ε_B = 0.1, ‖w‖∞ <= 0.1, ‖x‖∞ <= 8, |u| <= 4,
    Q = 10 I, R = 1, N = 3. Reconstruction choices (docs/decisions.md, "Literature examples"): θ̂0 = 0;
    the scenario x0 = [0, 2] (inside the robust feasible region for every ε_A of the sweep; the code's
    x0 = [3, 0] is not for ε_A >= 0.25), θ* = [0.5, −0.5], 30 steps, uniform disturbances, seed 0;
    X0 facets per ε_A from :data:`SLSMPC2D_FACETS`."""
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.problem import DesignOptions, Scenario

    if isinstance(eps_a, bool) or not isinstance(eps_a, (int, float)) or not 0.0 < eps_a < 1.0:
        raise ProblemError("eps_a", "a number in (0, 1) (ε_A of the SLS-MPC family)", repr(eps_a))
    eps_b = 0.1
    problem = Problem(
        A0=[[1.0, 0.15], [0.1, 1.0]], B0=[[0.1], [1.1]],
        A=[[[eps_a, 0.0], [0.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]]], B=[[[0.0], [0.0]], [[0.0], [eps_b]]],
        H_w=[[10.0, 0.0], [0.0, 10.0], [-10.0, 0.0], [0.0, -10.0]],
        H_theta=[[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]], h_theta=[1.0, 1.0, 1.0, 1.0],
        F=[[0.125, 0.0], [0.0, 0.125], [-0.125, 0.0], [0.0, -0.125], [0.0, 0.0], [0.0, 0.0]],
        G=[[0.0], [0.0], [0.0], [0.0], [0.25], [-0.25]],
        Q=[[10.0, 0.0], [0.0, 10.0]], R=[[1.0]], N=3, theta_hat0=[0.0, 0.0], name=f"slsmpc2d_eps{eps_a:g}")
    facets = next((f for e, f in sorted(SLSMPC2D_FACETS.items()) if eps_a <= e + 1e-12), 96)
    scenario = Scenario(x0=[0.0, 2.0], theta_star=[0.5, -0.5], steps=30, disturbance="uniform", seed=0)
    return ProblemSpec(problem=problem, design=DesignOptions(x0_facets=facets), scenario=scenario)


EXAMPLES = {"lorenzen2019": lorenzen2019_spec, "lorenzen2019_ex2": lorenzen2019_ex2_spec,
            "parsi2020_siso": parsi2020_siso_spec, "parsi2020_mimo": parsi2020_mimo_spec,
            "bujarbaruah2022": bujarbaruah2022_spec,
            **{f"slsmpc2d_eps{e:g}": (lambda e=e: slsmpc2d_spec(e)) for e in SLSMPC2D_EPS_A}}
#: The built-in systems taken from other publications than Lorenzen et al. (2019) (issue 14).
LITERATURE_EXAMPLES = ("parsi2020_siso", "parsi2020_mimo", "bujarbaruah2022")
#: The SLS-MPC family (Chen et al. 2024) at the ε_A of issue 14's sweep.
SLSMPC2D_EXAMPLES = tuple(f"slsmpc2d_eps{e:g}" for e in SLSMPC2D_EPS_A)


def get_example(name: str) -> ProblemSpec:
    """A built-in example by name; raises ProblemError listing the names."""
    from amcp_drake.model.errors import ProblemError

    if name not in EXAMPLES:
        raise ProblemError("--example", f"one of {sorted(EXAMPLES)}", repr(name))
    return EXAMPLES[name]()
