"""Built-in problems. ``lorenzen2019()`` is Example 1 of the paper (docs/explanation/paper.md §9); ``lorenzen2019_ex2``
is Example 2 (Section 4 extensions: PE input and time-varying parameters, choices documented).

Data: A0, B0, A_i, B_i, Θ, W, N, Q, R, θ̂0, θ* from the paper [SEED]; the constraints
x2 >= -0.3, |u| <= 1, x0 = [2, 3] from the third-party replication SRC-1 (docs/explanation/paper.md §9).
Z is unbounded in x1, so μ is evaluated on the box |x_i| <= 3 (as SRC-1 does); the closed loop
is checked to stay inside that box (Lemma 5 precondition, design.md Pitfalls).
"""

from __future__ import annotations

from importlib import resources

from amcp_drake.model.problem import Problem, ProblemSpec
from amcp_drake.model.problem_io import load_spec
from amcp_drake.model.sls_mpc_2d import SLS_EPS_A_SWEEP, sls_mpc_2d_spec


def example_file(name: str):
    """The packaged problem file ``amcp_drake/data/<name>.json`` a built-in example is loaded from (a copy is in
    examples/), or None for an example built in code (the SLS-MPC family)."""
    packaged = resources.files("amcp_drake") / "data" / f"{name}.json"
    return packaged if name in EXAMPLES and packaged.is_file() else None


def _data_spec(name: str) -> ProblemSpec:
    """The problem file :func:`example_file` of ``name``."""
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


def massera2017_spec() -> ProblemSpec:
    """Massera, Terra & Wolf, guaranteed-cost robust MPC (ACC 2017), the paper's example of its public
    code (cmassera/gcmpc @ 5033d89): x⁺ = (F + Hδ E1)x + (G + Hδ E2)u, |δ| <= 1, so n = 3, m = 2,
    p = 1, A1 = H E1, B1 = H E2 (open loop unstable, B uncertain); |x_i| <= 1, Q = I, R = I, N = 10.
    Added (the paper has neither): W = {|w_i| <= 0.05} and |u_j| <= 2 (Z must bound u for μ of (11)).
    θ̂0 = 0, θ* = 0.5, x0 = [0.5, 0.5, 0.5] (the paper's [1, 1, 1] is outside the feasible set of (20)
    here). Default design (automatic X0). Choices: docs/decisions.md."""
    return _data_spec("massera2017")


def kothare1996_spec() -> ProblemSpec:
    """Kothare, Balakrishnan & Morari, robust constrained MPC using LMIs (Automatica 1996), Example 1,
    the angular positioning system: x⁺ = [1 0.1; 0 1 − 0.1α] x + [0; 0.1κ] u, κ = 0.787,
    α ∈ [0.1, 10], |u| <= 2, R = 2e-5; read from the public reproductions juanmoreira20/LMI-studies
    @ 5795e7b and gabrielfreitasm/ERMPC @ e097619 (the MUP toolbox's variant has another B). Here
    θ = α, a constant unknown parameter: A(θ) = A0 + θ A1, A1 = [0 0; 0 −0.1], B fixed, p = 1,
    n = 2, m = 1. Added (the paper has none of them for this setting): W = {|w_i| <= 0.001},
    |x_i| <= 1, Q = I (MUP's Wx; the paper's C'C is only semidefinite), N = 10, θ̂0 = 5.05 (centre of
    Θ), θ* = 9, x0 = [0.05, 0]. Default design. Choices: docs/decisions.md."""
    return _data_spec("kothare1996")


def tranos2022_spec() -> ProblemSpec:
    """Tranos, Russo & Proutiere, self-tuning tube-based MPC (STT-MPC), the paper's example in its public
    code (rssalessio/SelfTuningTubeBasedMPC @ 172cc75, known_B/mpc_problem.py): x⁺ = A x + B u + w,
    A = [0.6 0.2; −0.1 0.4] unknown in all four entries, B = [1; 0.5] known. Here θ = vec(A) (row-major,
    the code's ``A.flatten()``): A0 = 0, A_i = the unit matrices E_11, E_12, E_21, E_22, B_i = 0, so
    n = 2, m = 1, p = 4; Θ = the code's box of half side 0.07 around [0.57, 0.17, −0.12, 0.42]
    (16 vertices), W = {|w_i| <= 3(1 + ‖B‖₂)·0.01}, x1 >= −0.15, x2 >= −1.1, u <= 1/2, Q = I, R = 1,
    N = 6, x0 = [6, 3], θ* = vec(A) = [0.6, 0.2, −0.1, 0.4], θ̂0 = the centre of Θ (the code's first
    estimate), 6 steps (the code's TOTAL_HORIZON). Added: |x_i| <= 7 for μ (Z bounds x only from below;
    u is bounded only above, which (11) allows since B is known), w uniform on W, a 12-facet X0 (with
    8 facets x0 is outside the feasible set of (20)). Choices: docs/decisions.md."""
    return _data_spec("tranos2022")


def mass_chain3_spec() -> ProblemSpec:
    """A chain of 3 unit masses on a line (reconstruction; the structure of the mass-spring chain in the public
    code of Köhler's certainty-equivalent adaptive MPC study, KohlerJohannes/Adaptive @ 1bad2fd): the first
    mass tied to the wall by a known spring (1 N/m), the 2 springs between masses unknown in [0.5, 1.5] N/m
    (θ, p = 2), a force on every mass (m = 3), forward Euler with h = 0.1 s (A affine in θ), so n = 6;
    |p_i| <= 1, |v_i| <= 1, |u_i| <= 3, |w_p| <= 1e-4, |w_v| <= 1e-3, Q = I, R = I, N = 10, θ̂0 = [1, 1],
    θ* = [0.7, 1.3], x0 = [0.2, 0, 0, 0, −0.2, 0], 50 steps. No design section (automatic design).
    Choices: docs/decisions.md."""
    return _data_spec("mass_chain3")


def mass_chain4_spec() -> ProblemSpec:
    """The chain of :func:`mass_chain3_spec` with 4 masses: n = 8, m = 4, p = 3 (the 3 springs between
    masses), N = 6, θ̂0 = [1, 1, 1], θ* = [0.7, 1.3, 1.0], x0 = [0.2, 0, 0, 0, 0, 0, −0.2, 0], 50 steps."""
    return _data_spec("mass_chain4")


def ji2022_quadrotor_spec() -> ProblemSpec:
    """The quadrotor of Ji et al., robust MPC with set-membership state estimation, in its public code
    (tianchenji/Robust-SM-MPC @ de286b9, sm_mpc_qr.py): of the 12-state linearised quadrotor (sampling time
    0.2 s), the x-axis subsystem the code's A and B leave decoupled, states [x, pitch, ẋ, pitch rate]
    (the code's indices 0, 4, 6, 10), input the pitch torque (index 2): n = 4, m = 1. Here θ = the
    torque's effectiveness, B(θ) = θ B, θ ∈ [0.8, 1.2], p = 1 (the code has no parametric uncertainty);
    |pitch| <= π/9 (the code's), |w_i| <= 0.03 (the box around the code's ellipsoid), N = 15 (the code's);
    added: |x| <= 6, |ẋ| <= 3, |pitch rate| <= 1, |u| <= 0.5, Q = I, R = 1, θ̂0 = 1, θ* = 1.1,
    x0 = [4, 0, 0, 0], 50 steps. No design section. Choices: docs/decisions.md."""
    return _data_spec("ji2022_quadrotor")


def lorenzen2019() -> Problem:
    """Example 1 of Lorenzen, Cannon & Allgöwer (2019), docs/explanation/paper.md §9."""
    return lorenzen2019_spec().problem


def lorenzen2019_ex2_spec() -> ProblemSpec:
    """Example 2 of the paper (docs/explanation/paper.md §9): Example 1's system with a persistently exciting input and
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


EXAMPLES = {"lorenzen2019": lorenzen2019_spec, "lorenzen2019_ex2": lorenzen2019_ex2_spec,
            "parsi2020_siso": parsi2020_siso_spec, "parsi2020_mimo": parsi2020_mimo_spec,
            "bujarbaruah2022": bujarbaruah2022_spec, "massera2017": massera2017_spec,
            "kothare1996": kothare1996_spec, "tranos2022": tranos2022_spec,
            "mass_chain3": mass_chain3_spec, "mass_chain4": mass_chain4_spec, "ji2022_quadrotor": ji2022_quadrotor_spec,
            **{f"sls_mpc_2d_eps{e:g}": (lambda e=e: sls_mpc_2d_spec(e)) for e in SLS_EPS_A_SWEEP}}
#: The built-in systems taken from other publications than Lorenzen et al. (2019).
LITERATURE_EXAMPLES = ("parsi2020_siso", "parsi2020_mimo", "bujarbaruah2022", "massera2017", "kothare1996",
                       "tranos2022", "mass_chain3", "mass_chain4", "ji2022_quadrotor")
#: Built-in systems measured in docs/results.md ("Literature systems of four to eight states") whose full
#: per-example backend runs (properties/amcp_properties/test_shipped_answers.py: 5 steps, each backend, both
#: formulations) do not fit the suite: mass_chain4 (n = 8, 256 vertices of X0) takes 5-18 s per cvxpy
#: plain-form step, the quadrotor's 102-facet X0 ~45 s CPU and GiBs per cvxpy plain-form step. They run there
#: with SHORT_RUN_STEPS steps and without the cvxpy plain form (MEASURED_SKIPPED_FORMS); mass_chain3 runs in full.
MEASURED_EXAMPLES = ("mass_chain4", "ji2022_quadrotor")
#: (example, backend, formulation) runs of MEASURED_EXAMPLES left out of the suite's short runs, with the reason.
MEASURED_SKIPPED_FORMS = {("mass_chain4", "cvxpy", "plain"): "5-18 s CPU per step (n = 8, every row of (15c) kept)",
                          ("ji2022_quadrotor", "cvxpy", "plain"): "~45 s CPU and GiBs per step (102-facet X0)"}
#: Closed-loop steps of the short per-example runs of MEASURED_EXAMPLES (the first steps, from x0, are the hard ones).
SHORT_RUN_STEPS = 2
#: The SLS-MPC 2-D family (Chen et al. 2024; constructor amcp_drake.model.sls_mpc_2d) at the ε_A of
#: the sweep SLS_EPS_A_SWEEP; any ε_A through ``sls_mpc_2d_spec(eps_A)``.
SLSMPC2D_EXAMPLES = tuple(f"sls_mpc_2d_eps{e:g}" for e in SLS_EPS_A_SWEEP)


def get_example(name: str) -> ProblemSpec:
    """A built-in example by name; raises ProblemError listing the names."""
    from amcp_drake.model.errors import ProblemError

    if name not in EXAMPLES:
        raise ProblemError("--example", f"one of {sorted(EXAMPLES)}", repr(name))
    return EXAMPLES[name]()
