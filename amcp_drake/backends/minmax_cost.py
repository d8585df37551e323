"""The min–max cost (19) of a tube MPC plan, evaluated from the plan: what both backends record as
the step's cost when ``TubeMPCData.cost == "minmax"``.

Why not the solver's objective Σ s_l² (the epigraph variables of the QP): the epigraph rows
s_l >= ‖(Q^½ x^j_l, R^½ u^j_l)‖ hold only to the solver's feasibility tolerance, which Clarabel scales
by the largest variable. On a problem in badly scaled state units (generator ``scaled_states``: states
of size 350, Q of size 1e-4) Σ s_l² undershot (19) of the returned plan by 1.3e-6 relative, on both
backends (a case of the property suite). The cost of the plan is the number a user can act
on; that the plan minimises (19) is the optimality claim's job (:mod:`amcp_drake.certificate.optimality`,
KKT residuals of the epigraph problem with t_l = max_j q_lj, recomputed from the plan).

The certificate evaluates (19) with its own code (:func:`amcp_drake.certificate.section4.minmax_cost`):
the two look alike on purpose, since a certificate never reuses the code whose output it checks
(and the layers forbid a backend to import the certificate).
"""

from __future__ import annotations

import numpy as np


def minmax_plan_cost(data, z: np.ndarray, alpha: np.ndarray, v: np.ndarray) -> float:
    """(19) of the plan (z (N+1, n), α (N+1,), v (N, m)) with ``data``'s Q, R, P, K and X0 vertices x^j:
    Σ_{l<N} max_j (‖x^j_l‖²_Q + ‖K x^j_l + v_l‖²_R) + max_j ‖x^j_N‖²_P, x^j_l = z_l + α_l x^j."""
    Xv = np.asarray(data.X0_vertices, float)
    K, P = np.asarray(data.K, float), np.asarray(data.P, float)
    Q, R = np.asarray(data.Q, float), np.asarray(data.R, float)
    z, alpha, v = np.asarray(z, float), np.asarray(alpha, float), np.asarray(v, float)
    total = 0.0
    for l in range(len(v)):
        X = z[l] + alpha[l] * Xv                # (v, n): the vertices of X_{l|k}
        U = X @ K.T + v[l]
        total += float(np.max(np.sum((X @ Q) * X, axis=1) + np.sum((U @ R) * U, axis=1)))
    X = z[len(v)] + alpha[len(v)] * Xv
    return total + float(np.max(np.sum((X @ P) * X, axis=1)))


__all__ = ["minmax_plan_cost"]
