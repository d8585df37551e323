"""The 2-D benchmark of the polytopic SLS-MPC comparison (Chen, Preciado, Morari & Matni,
"Robust model predictive control with polytopic model uncertainty through System Level
Synthesis", Automatica 2024; public code ShaoruChen/Polytopic-SLSMPC, examples/example_2d).

x⁺ = (A + ε_A θ_1 [1 0; 0 0]) x + (B + ε_B θ_2 [0; 1]) u + w, θ ∈ [−1, 1]², with
A = [1 0.15; 0.1 1], B = [0.1; 1.1], ‖w‖∞ <= 0.1, ‖x‖∞ <= 8, |u| <= 4, Q = 10 I, R = 1, N = 3.
In the notation of eq. (2): p = 2, A_1 = ε_A [1 0; 0 0], A_2 = 0, B_1 = 0, B_2 = ε_B [0; 1].

Reconstruction choices (docs/decisions.md, "SLS-MPC 2-D family"): θ̂0 = 0 (the centre of Θ);
the default scenario x0 = [−0.3, 3] (the first QP is feasible for the default design of every
ε_A of the sweep 0.05 … 0.45, margin >= 0.08 in the vertex-form LP; [−2, 1] is not at ε_A >= 0.35), θ* = [0.5, −0.5], 50 steps, uniform disturbance, seed 0; design options default.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec, Scenario

#: The ε_A values of the built-in sweep (the paper sweeps ε_A with ε_B = 0.1 fixed).
SLS_EPS_A_SWEEP = (0.05, 0.15, 0.25, 0.35, 0.45)


def sls_mpc_2d_problem(eps_A: float = 0.15, eps_B: float = 0.1) -> Problem:
    """The Problem of the SLS-MPC 2-D family for one (ε_A, ε_B); named ``sls_mpc_2d_eps<ε_A>``."""
    A0 = np.array([[1.0, 0.15], [0.1, 1.0]])
    B0 = np.array([[0.1], [1.1]])
    A = np.array([eps_A * np.array([[1.0, 0.0], [0.0, 0.0]]), np.zeros((2, 2))])
    B = np.array([np.zeros((2, 1)), eps_B * np.array([[0.0], [1.0]])])
    H_w = np.vstack([np.eye(2), -np.eye(2)]) / 0.1
    H_theta = np.vstack([np.eye(2), -np.eye(2)])
    F = np.vstack([np.eye(2) / 8.0, -np.eye(2) / 8.0, np.zeros((2, 2))])
    G = np.vstack([np.zeros((4, 1)), [[1.0 / 4.0], [-1.0 / 4.0]]])
    return Problem(A0=A0, B0=B0, A=A, B=B, H_w=H_w, H_theta=H_theta, h_theta=np.ones(4), F=F, G=G,
                   Q=10.0 * np.eye(2), R=np.eye(1), N=3, theta_hat0=np.zeros(2),
                   name=f"sls_mpc_2d_eps{eps_A:g}")


def sls_mpc_2d_spec(eps_A: float = 0.15, eps_B: float = 0.1) -> ProblemSpec:
    """The ProblemSpec (problem, default design options, default scenario) of the family."""
    scenario = Scenario(x0=np.array([-0.3, 3.0]), theta_star=np.array([0.5, -0.5]), steps=50,
                        disturbance="uniform", seed=0)
    return ProblemSpec(problem=sls_mpc_2d_problem(eps_A, eps_B), design=DesignOptions(), scenario=scenario)
