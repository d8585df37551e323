"""The certainty-equivalence cost (17)-(18) condensed into a quadratic in v, written once for every
Drake formulation of the tube QP (20) (``drake_tube`` plain (15), ``drake_vertex``) and the fast
path (``daqp_fast``). The cvxpy backend keeps the nominal prediction x̂ as variables instead
(``amcp_reference.nominal_cost``), so that the two backends cross-check the cost.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.backends.base import TubeMPCData
from amcp_drake.model.arrays import same_bits


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    """Symmetric square root of a positive semidefinite matrix (Q, R, P of (17))."""
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


class CondensedCost:
    """Cost (17)-(18) as a quadratic in v: J = vᵀ H v + 2 gᵀ v + c, with x̂_{l+1} = A_cl(θ̂) x̂_l + B(θ̂) v_l.

    With W = [Φ | Γ] (x̂ = Φ x_k + Γ v) and the stacked weighted residuals
    E = [Q^½ x̂_l (l < N); P^½ x̂_N; R^½ û_l (l < N)] = G [x_k; v], J = ‖E‖² and
    GᵀG = [[T, S], [Sᵀ, H]]: one product gives H, S and T. Only the powers of A_cl(θ̂_k) change
    per step; everything is recomputed only when θ̂_k changes.
    """

    def __init__(self, data: TubeMPCData) -> None:
        self.data = data
        n, m = np.shape(data.B0)
        N = int(data.N)
        self.n, self.m, self.N = n, m, N
        self.K = np.asarray(data.K, float)
        self.Qh, self.Rh, self.Ph = (_sqrt_psd(np.asarray(M, float)) for M in (data.Q, data.R, data.P))
        lag = np.arange(N + 1)[:, None] - 1 - np.arange(N)[None, :]   # l − 1 − i
        self._lag = np.where(lag >= 0, lag, N)                         # index N: zero block
        self._last: tuple | None = None                                # (θ̂, H, S, T) of the last call
        p = np.shape(data.A)[0]
        self._A_flat = np.asarray(data.A, float).reshape(p, n * n)     # A(θ) − A0 = θ @ A_flat (row-major)
        self._B_flat = np.asarray(data.B, float).reshape(p, n * m)
        # û_l = K x̂_l + v_l: the identity on v_l, in W's columns [x_k (n) | v (N·m)]
        self._v_identity = np.zeros((N, m, n + N * m))
        self._v_identity[np.arange(N)[:, None], np.arange(m)[None, :], n + np.arange(N * m).reshape(N, m)] = 1.0

    def matrices(self, x: np.ndarray, theta_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(H, g, c) with J_N(x_k, v) of (17) = vᵀ H v + 2 gᵀ v + c for the stacked v (N·m,), x̂_0 = x_k
        and x̂ rolled out by (18) with θ̂_k: x̂ = Φ x_k + Γ v, û = K̄ x̂ + v. H (N·m, N·m) is symmetric;
        it depends on θ̂_k only and is reused while θ̂_k does not change."""
        theta_hat = np.asarray(theta_hat, float)
        if self._last is None or not same_bits(self._last[0], theta_hat):
            self._last = (theta_hat.copy(), *self._blocks(theta_hat))
        _, H, S, T = self._last
        return H, S.T @ x, float(np.dot(np.dot(x, T), x))  # S.T: a strided view, matmul kept (np.dot would copy: other bits)

    def _blocks(self, theta_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d, n, m, N = self.data, self.n, self.m, self.N
        B_hat = d.B0 + np.dot(theta_hat, self._B_flat).reshape(n, m)
        A_cl = d.A0 + np.dot(theta_hat, self._A_flat).reshape(n, n) + np.dot(B_hat, self.K)
        powers = np.empty((N + 1, n, n))
        powers[0] = np.eye(n)
        for l in range(1, N + 1):
            np.dot(A_cl, powers[l - 1], out=powers[l])   # written in place (same products, bit for bit)
        PB = np.zeros((N + 1, n, m))
        np.matmul(powers[:N], B_hat, out=PB[:N])
        W = np.empty((N + 1, n, n + N * m))                     # block l: [A_cl^l | Γ_l]
        W[:, :, :n] = powers
        W[:, :, n:] = PB[self._lag].transpose(0, 2, 1, 3).reshape(N + 1, n, N * m)
        G = np.concatenate([(self.Qh @ W[:N]).reshape(N * n, -1), np.dot(self.Ph, W[N]),
                            (self.Rh @ (self.K @ W[:N] + self._v_identity)).reshape(N * m, -1)])
        M = np.dot(G.T, G)
        H = M[n:, n:]
        return 0.5 * (H + H.T), M[:n, n:], M[:n, :n]


__all__ = ["CondensedCost"]
