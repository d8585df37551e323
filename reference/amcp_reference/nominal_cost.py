"""The certainty-equivalence cost (17) with the nominal prediction (18), written once for both
cvxpy formulations of the tube QP (20) (``tube_mpc`` plain (15), ``tube_vertex``).

Unlike the Drake backend (``amcp_drake.backends.condensed_cost``, which condenses x̂ into a
quadratic in v), the nominal prediction x̂ stays a variable with equality constraints, so that
the two backends cross-check the cost; :func:`nominal_cost` evaluates J_N in plain numpy.
"""

from __future__ import annotations

import cvxpy as cp
import numpy as np

from amcp_drake.backends.base import TubeMPCData

from .offline import sqrtm_psd


def certainty_equivalence_cost(data: TubeMPCData, params: dict[str, cp.Parameter], v: cp.Variable,
                               constraints: list) -> cp.Minimize:
    """Objective J_N of (17) with x̂ of (18) as a variable (n, N+1); appends the equalities
    x̂_0 = x_k, x̂_{l+1} = A_cl(θ̂) x̂_l + B(θ̂) v_l to ``constraints`` and the parameters
    ``A_cl_hat`` = A(θ̂_k) + B(θ̂_k) K (n, n) and ``B_hat`` = B(θ̂_k) (n, m) to ``params``
    (which must hold ``x_k``). ``v`` is (m, N), column l = v_l|k."""
    n, m = np.shape(data.B0)
    N = int(data.N)
    K = np.asarray(data.K, float)
    params["A_cl_hat"] = cp.Parameter((n, n), name="A_cl_hat")
    params["B_hat"] = cp.Parameter((n, m), name="B_hat")
    x_hat = cp.Variable((n, N + 1), name="x_hat")
    constraints += [
        x_hat[:, 0] == params["x_k"],
        x_hat[:, 1:] == params["A_cl_hat"] @ x_hat[:, :N] + params["B_hat"] @ v,
    ]
    Qh, Rh, Ph = (sqrtm_psd(np.asarray(M, float)) for M in (data.Q, data.R, data.P))
    u_hat = K @ x_hat[:, :N] + v  # û_l = K x̂_l + v_l
    return cp.Minimize(cp.sum_squares(Qh @ x_hat[:, :N]) + cp.sum_squares(Rh @ u_hat)
                       + cp.sum_squares(Ph @ x_hat[:, N]))


def nominal_cost(data: TubeMPCData, x: np.ndarray, theta_hat: np.ndarray, v: np.ndarray) -> float:
    """J_N of (17) for inputs v (N, m), rolling out (18) in numpy (constant term included)."""
    A_hat = data.A0 + np.tensordot(theta_hat, data.A, axes=1)
    B_hat = data.B0 + np.tensordot(theta_hat, data.B, axes=1)
    x_hat = np.asarray(x, float)
    cost = 0.0
    for l in range(int(data.N)):
        u_hat = data.K @ x_hat + v[l]
        cost += float(x_hat @ data.Q @ x_hat + u_hat @ data.R @ u_hat)
        x_hat = A_hat @ x_hat + B_hat @ u_hat
    return cost + float(x_hat @ data.P @ x_hat)


__all__ = ["certainty_equivalence_cost", "nominal_cost"]
