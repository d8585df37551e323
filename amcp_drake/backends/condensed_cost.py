"""The certainty-equivalence cost (17)-(18) condensed into a quadratic in v, written once for every
Drake formulation of the tube QP (20) (``drake_tube`` plain (15), ``drake_vertex``) and the fast
path (``daqp_fast``). The cvxpy backend keeps the nominal prediction x̂ as variables instead
(``amcp_reference.nominal_cost``), so that the two backends cross-check the cost.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.backends.base import TubeMPCData
from amcp_drake.model.arrays import same_bits, scalar_operand

_HALF = scalar_operand(0.5)  # ½ of the symmetric part, a 0-d array (model.arrays.scalar_operand)


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
        self._allocate()

    def _allocate(self) -> None:
        """Buffers written in place by :meth:`_blocks` (~20 fewer numpy calls and temporaries
        per step; the same products on the same operands, so the same bits as building them anew).

        ``_source`` holds the powers A_cl^l (N+1, n, n) and the products A_cl^l B(θ̂) (N+1, n, m) (the
        last block zero); W = [A_cl^l | Γ_l] is gathered from it by one ``np.take`` with a fixed index
        (Γ_l's block i is A_cl^(l−1−i) B(θ̂), or zero for i >= l). G's three row blocks are views."""
        n, m, N = self.n, self.m, self.N
        powers_size = (N + 1) * n * n
        self._source = np.zeros(powers_size + (N + 1) * n * m)
        powers = self._source[:powers_size].reshape(N + 1, n, n)
        powers[0] = np.eye(n)
        self._power_steps = [(powers[l - 1], powers[l]) for l in range(1, N + 1)]  # A_cl^l = A_cl A_cl^(l−1)
        self._powers_head = powers[:N]
        self._PB_head = self._source[powers_size:].reshape(N + 1, n, m)[:N]
        cols = n + N * m
        index = np.empty((N + 1, n, cols), dtype=np.intp)
        l, a, c = np.meshgrid(np.arange(N + 1), np.arange(n), np.arange(n), indexing="ij")
        index[:, :, :n] = (l * n + a) * n + c
        block, j = np.divmod(np.arange(N * m), m)                    # column n + i·m + j of W: block i
        lag = self._lag[:, block]                                     # (N+1, N·m): l − 1 − i, or N
        index[:, :, n:] = powers_size + (lag[:, None, :] * n + np.arange(n)[None, :, None]) * m + j[None, None, :]
        self._W_index = index
        self._W = np.empty((N + 1, n, cols))
        self._W_head, self._W_last = self._W[:N], self._W[N]
        self._G = np.empty((N * n + n + N * m, cols))
        self._G_T = self._G.T
        self._G_Q = self._G[:N * n].reshape(N, n, cols)               # Q^½ x̂_l, l < N
        self._G_P = self._G[N * n:N * n + n]                          # P^½ x̂_N
        self._G_R = self._G[N * n + n:].reshape(N, m, cols)           # R^½ û_l
        self._KW = np.empty((N, m, cols))

    def matrices(self, x: np.ndarray, theta_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(H, g, c) with J_N(x_k, v) of (17) = vᵀ H v + 2 gᵀ v + c for the stacked v (N·m,), x̂_0 = x_k
        and x̂ rolled out by (18) with θ̂_k: x̂ = Φ x_k + Γ v, û = K̄ x̂ + v. H (N·m, N·m) is symmetric;
        it depends on θ̂_k only and is reused while θ̂_k does not change."""
        theta_hat = np.asarray(theta_hat, float)
        if self._last is None or not same_bits(self._last[0], theta_hat):
            self._last = (theta_hat.copy(), *self._blocks(theta_hat))
        _, H, S, T = self._last
        return H, S.T @ x, float(x.dot(T).dot(x))  # S.T: a strided view, matmul kept (np.dot would copy: other bits)

    def _blocks(self, theta_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d, n, m = self.data, self.n, self.m
        B_hat = d.B0 + theta_hat.dot(self._B_flat).reshape(n, m)
        A_cl = d.A0 + theta_hat.dot(self._A_flat).reshape(n, n) + B_hat.dot(self.K)
        for previous, power in self._power_steps:
            A_cl.dot(previous, out=power)                   # written in place (same products, bit for bit)
        np.matmul(self._powers_head, B_hat, out=self._PB_head)
        self._source.take(self._W_index, out=self._W, mode="clip")   # W (indices valid: "clip" skips a buffer)
        np.matmul(self.Qh, self._W_head, out=self._G_Q)
        self.Ph.dot(self._W_last, out=self._G_P)
        KW = np.matmul(self.K, self._W_head, out=self._KW)
        KW += self._v_identity
        np.matmul(self.Rh, KW, out=self._G_R)
        M = self._G_T.dot(self._G)
        H = M[n:, n:]
        return _HALF * (H + H.T), M[:n, n:], M[:n, :n]


__all__ = ["CondensedCost"]
