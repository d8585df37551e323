"""The feasible region of the tube MPC QP (20) at one initial state, by an independent LP.

:class:`TubeLP` writes 𝔻(x0, Θ) in vertex form, before dualisation (proof of Proposition 9): for every
prediction step l, every vertex x^j of X0 and every vertex θ^s of Θ,

    H_x (A_cl(θ^s)(z_l + α_l x^j) + B(θ^s) v_l − z_{l+1}) − α_{l+1} 1 <= −w̄        (5b)

with (15a) (F + GK) z_l + G v_l + f̄ α_l <= 1, (15b) H_x (x0 − z_0) <= α_0 1, the terminal set
H_T z_N + h_T α_N <= 1 and α >= 0; w̄ and f̄ are recomputed from the vertices of W and X0, and the
vertices of Θ are enumerated here, so neither a backend nor an offline constant is trusted. The LP
maximises a common slack t (t <= :data:`SLACK_CAP`) of all rows scaled to unit norm: t >= 0 if and only
if 𝔻(x0, Θ) ≠ ∅, and |t| measures the distance to the boundary.

Used by the certificate for the premise of Theorem 14 (𝔻(x_0, Θ_0) ≠ ∅) and by ``amcp coverage`` for
a whole region of initial states.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import csr_matrix

from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError
from amcp_drake.model.polytope import theta_vertices

#: Upper bound on the LP slack t (keeps the LP bounded; only its sign and small values matter).
SLACK_CAP = 1.0


@dataclass(frozen=True)
class TubeLayout:
    """Where the variables of (20) sit in y = [z_0..z_N (n each) | α_0..α_N | v_0..v_(N−1) (m each)]:
    the layout of :class:`TubeLP` and of the LP of :mod:`amcp_drake.studies.tube_feasibility`."""

    n: int
    m: int
    N: int

    @property
    def nz(self) -> int:
        return (self.N + 1) * self.n

    @property
    def na(self) -> int:
        return self.N + 1

    @property
    def size(self) -> int:
        return self.nz + self.na + self.N * self.m

    def z(self, l: int) -> slice:
        return slice(l * self.n, (l + 1) * self.n)

    def a(self, l: int) -> int:
        return self.nz + l

    def v(self, l: int) -> slice:
        start = self.nz + self.na + l * self.m
        return slice(start, start + self.m)

    def bounds(self) -> list[tuple[float | None, float | None]]:
        """linprog bounds: z and v free, α >= 0."""
        return [(None, None)] * self.nz + [(0.0, None)] * self.na + [(None, None)] * (self.N * self.m)


@dataclass(frozen=True)
class TubeLP:
    """The vertex form of 𝔻(x0, Θ) for one Θ: rows A_ub y <= b_const + B_x x0 (scaled to unit
    norm), with y = [z_0..z_N | α_0..α_N | v_0..v_(N−1)]. Built once per Θ, re-used for every x0."""

    A: csr_matrix
    b: np.ndarray
    Bx: np.ndarray       # (rows, n): the x0-dependent part of the right-hand side
    bounds: list
    size: int
    _A_t: csr_matrix | None = field(default=None, repr=False)

    @classmethod
    def build(cls, problem, design, H_theta: np.ndarray, h_theta: np.ndarray) -> TubeLP:
        verts = theta_vertices(H_theta, h_theta)
        if verts is None or len(verts) == 0:
            raise ProblemError("Theta", "a non-empty bounded parameter set", "an empty or unbounded set")
        n, m, N = problem.n, problem.m, int(problem.N)
        K = np.asarray(design.K, float)
        H_x = np.asarray(design.H_x, float)
        X0v = polytope.vertices(H_x, np.ones(len(H_x)))
        FGK = problem.F + problem.G @ K
        w_bar = np.max(H_x @ problem.w_vertices().T, axis=1)
        f_bar = np.max(FGK @ X0v.T, axis=1)
        u, c = H_x.shape[0], FGK.shape[0]
        layout = TubeLayout(n, m, N)
        z, a, v, size = layout.z, layout.a, layout.v, layout.size
        blocks, rhs, rhs_x = [], [], []
        for l in range(N):  # (15a)
            A = np.zeros((c, size))
            A[:, z(l)], A[:, v(l)], A[:, a(l)] = FGK, problem.G, f_bar
            blocks.append(A), rhs.append(np.ones(c)), rhs_x.append(np.zeros((c, n)))
        A = np.zeros((u, size))  # (15b): −H_x z_0 − α_0 <= −H_x x0
        A[:, z(0)], A[:, a(0)] = -H_x, -1.0
        blocks.append(A), rhs.append(np.zeros(u)), rhs_x.append(-H_x)
        for l in range(N):  # (5b) at the vertices of X0 and Θ
            for theta in verts:
                HA = H_x @ (problem.A_of(theta) + problem.B_of(theta) @ K)
                HB = H_x @ problem.B_of(theta)
                # the rows of the vertices x^j differ only in the coefficient HA x^j of α_l >= 0, so
                # the row with the largest coefficient implies the others (row-wise max over j)
                A = np.zeros((u, size))
                A[:, z(l)], A[:, a(l)], A[:, v(l)] = HA, np.max(HA @ X0v.T, axis=1), HB
                A[:, z(l + 1)], A[:, a(l + 1)] = -H_x, -1.0
                blocks.append(A), rhs.append(-w_bar), rhs_x.append(np.zeros((u, n)))
        H_T, h_T = np.asarray(design.H_T, float), np.asarray(design.h_T, float)
        A = np.zeros((len(H_T), size))  # terminal set X_f (Assumption 11)
        A[:, z(N)], A[:, a(N)] = H_T, h_T
        blocks.append(A), rhs.append(np.ones(len(H_T))), rhs_x.append(np.zeros((len(H_T), n)))
        A, b, Bx = np.vstack(blocks), np.concatenate(rhs), np.vstack(rhs_x)
        norms = np.linalg.norm(A, axis=1)
        keep = norms > 0  # an all-zero row 0 <= b: kept out (it constrains nothing but x0 through b)
        if np.any(~keep & ((b < 0) | np.any(Bx != 0, axis=1))):
            raise ProblemError("Z", "rows that involve the decision variables", "an all-zero row with data")
        A, b, Bx, norms = A[keep], b[keep], Bx[keep], norms[keep]
        return cls(A=csr_matrix(A / norms[:, None]), b=b / norms, Bx=Bx / norms[:, None], bounds=layout.bounds(),
                   size=size)

    def margin(self, x0: np.ndarray, options: dict | None = None) -> float:
        """max t (<= SLACK_CAP) with A y + t <= b(x0), α >= 0: >= 0 iff 𝔻(x0, Θ) ≠ ∅. nan if the LP
        fails (it is always feasible: t may be as negative as needed). ``options``: HiGHS options of
        scipy's ``linprog`` (tolerances; default HiGHS' own, feasibility 1e-7)."""
        from scipy.sparse import hstack

        if self._A_t is None:
            object.__setattr__(self, "_A_t", hstack([self.A, csr_matrix(np.ones((self.A.shape[0], 1)))], format="csr"))
        cost = np.zeros(self.size + 1)
        cost[-1] = -1.0
        res = linprog(cost, A_ub=self._A_t, b_ub=self.b + self.Bx @ np.asarray(x0, float),
                      bounds=self.bounds + [(None, SLACK_CAP)], method="highs", options=options)
        if res.status != 0:
            return float("nan")
        return float(res.x[-1])
