"""The feasible set of the tube MPC QP (20) in vertex form, as one LP (scipy HiGHS).

Neither backend is used: the constraints are written here a third time, in the form the proof
of Proposition 9 has *before* dualisation. For every prediction step l, every vertex x^j of X0
and every vertex θ of Θ_k,

    H_x (A_cl(θ) (z_l + α_l x^j) + B(θ) v_l − z_{l+1}) − α_{l+1} 1 <= −w̄       (5b) at the vertices,

together with (15a), (15b), the terminal set and α >= 0. By Proposition 9 this set of
(z, α, v) is exactly the projection of 𝔻(x_k, Θ_k) (the Λ of (15c)-(15d) are LP duals of the
row maxima over Θ_k). w̄ and f̄ are recomputed from the vertices of W and X0 (not taken from
the design) so that a wrong offline constant is not copied in.

Variables y = [z (N+1)·n | α (N+1) | v N·m | s], with x_k = s·d for a ray direction d.

``row_maxima=True`` writes the rows of (5b) once per (l, θ) instead of once per (l, θ, x^j): for
α_l >= 0 (a bound of the LP) the rows at all vertices x^j hold exactly when

    H_x (A_cl(θ) z_l + B(θ) v_l − z_{l+1}) + α_l c(θ) − α_{l+1} 1 <= −w̄,   c(θ)_i = max_j (H_x A_cl(θ) x^j)_i,

the same set with q times fewer rows (q vertices of X0). The generator uses it from n = 4 on: there
X0 has hundreds to thousands of vertices and the rows at every vertex (N·|vert Θ|·q·u of them, dense)
exhausted 12 GB on a problem of 6 states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog
from scipy.sparse import csr_matrix

from amcp_drake.certificate.feasible_region import TubeLayout
from amcp_drake.model import polytope


@dataclass(frozen=True)
class TubeGeometry:
    """The data of the vertex form: problem matrices with the design's K, X0, X_f.

    ``theta_vertices`` (v_p, p) are the vertices of the parameter set used in the tube;
    ``w_bar`` (u,) and ``f_bar`` (c,) are recomputed from vertices (see module docstring).
    """

    A_cl: np.ndarray       # (v_p, n, n): A(θ) + B(θ) K at each θ vertex
    B_v: np.ndarray        # (v_p, n, m): B(θ) at each θ vertex
    FGK: np.ndarray        # (c, n)
    G: np.ndarray          # (c, m)
    H_x: np.ndarray        # (u, n)
    X0_vertices: np.ndarray  # (v, n)
    w_bar: np.ndarray      # (u,)
    f_bar: np.ndarray      # (c,)
    H_T: np.ndarray        # (r, n)
    h_T: np.ndarray        # (r,)
    N: int

    @classmethod
    def build(cls, problem, design, theta_vertices: np.ndarray) -> TubeGeometry:
        K = np.asarray(design.K, float)
        H_x = np.asarray(design.H_x, float)
        X0_v = polytope.vertices(H_x, np.ones(len(H_x)))
        W_v = problem.w_vertices()
        FGK = problem.F + problem.G @ K
        A_cl = np.array([problem.A_of(t) + problem.B_of(t) @ K for t in theta_vertices])
        B_v = np.array([problem.B_of(t) for t in theta_vertices])
        return cls(A_cl=A_cl, B_v=B_v, FGK=FGK, G=problem.G, H_x=H_x, X0_vertices=X0_v,
                   w_bar=np.max(H_x @ W_v.T, axis=1), f_bar=np.max(FGK @ X0_v.T, axis=1),
                   H_T=np.asarray(design.H_T, float), h_T=np.asarray(design.h_T, float), N=int(problem.N))


def _rows(geo: TubeGeometry, direction: np.ndarray | None, x: np.ndarray | None, row_maxima: bool = False):
    """A_ub, b_ub of the vertex form; the last variable is the ray length s when ``direction``
    is given (x_k = s d), otherwise x_k = ``x`` is data and s is absent. ``row_maxima``: the rows of
    (5b) with the maxima over X0's vertices (module docstring) instead of one block per vertex."""
    N = geo.N
    layout = TubeLayout(geo.H_x.shape[1], geo.G.shape[1], N)
    z, a, v = layout.z, layout.a, layout.v
    size = layout.size + (1 if direction is not None else 0)
    blocks, rhs = [], []
    c = geo.FGK.shape[0]
    u = geo.H_x.shape[0]
    for l in range(N):  # (15a) / (5c) at the tube vertices
        A = np.zeros((c, size))
        A[:, z(l)] = geo.FGK
        A[:, v(l)] = geo.G
        A[:, a(l)] = geo.f_bar
        blocks.append(A)
        rhs.append(np.ones(c))
    A = np.zeros((u, size))  # (15b) x_k ∈ X_{0|k}: H_x (x_k − z_0) <= α_0
    A[:, z(0)] = -geo.H_x
    A[:, a(0)] = -1.0
    if direction is not None:
        A[:, -1] = geo.H_x @ direction
        rhs.append(np.zeros(u))
    else:
        rhs.append(-geo.H_x @ x)
    blocks.append(A)
    for l in range(N):  # (5b) at the vertices of X0 and Θ
        for Acl, Bt in zip(geo.A_cl, geo.B_v):
            HA, HB = geo.H_x @ Acl, geo.H_x @ Bt
            coefficients = [np.max(HA @ geo.X0_vertices.T, axis=1)] if row_maxima else \
                (HA @ xj for xj in geo.X0_vertices)
            for c_alpha in coefficients:
                A = np.zeros((u, size))
                A[:, z(l)] = HA
                A[:, a(l)] = c_alpha
                A[:, v(l)] = HB
                A[:, z(l + 1)] = -geo.H_x
                A[:, a(l + 1)] = -1.0
                blocks.append(A)
                rhs.append(-geo.w_bar)
    A = np.zeros((len(geo.H_T), size))  # terminal set
    A[:, z(N)] = geo.H_T
    A[:, a(N)] = geo.h_T
    blocks.append(A)
    rhs.append(np.ones(len(geo.H_T)))
    bounds = layout.bounds()
    if direction is not None:
        bounds.append((0.0, None))
    return csr_matrix(np.vstack(blocks)), np.concatenate(rhs), bounds, size


def max_ray_length(geo: TubeGeometry, direction: np.ndarray, row_maxima: bool = False) -> float:
    """max{s >= 0 | 𝔻(s·d, Θ) ≠ ∅}: the distance from 0 to the boundary of the feasible set of
    (20) along d (in units of ‖d‖). Returns nan when the LP fails and inf when unbounded.
    ``row_maxima``: the rows of (5b) with the maxima over X0's vertices (module docstring)."""
    A, b, bounds, size = _rows(geo, np.asarray(direction, float), None, row_maxima)
    cost = np.zeros(size)
    cost[-1] = -1.0
    res = linprog(cost, A_ub=A, b_ub=b, bounds=bounds, method="highs")
    if res.status == 3:
        return float("inf")
    if res.status != 0:
        return float("nan")
    return float(res.x[-1])


def feasibility_margin(geo: TubeGeometry, x: np.ndarray) -> float:
    """Largest t such that the vertex form with every right-hand side reduced by t is feasible
    at x_k = x: t >= 0 means 𝔻(x, Θ) ≠ ∅ (computed with the rows' right-hand sides as they are,
    α >= 0 kept). Returns -inf when even a large t cannot make it feasible (LP infeasible)."""
    A, b, bounds, size = _rows(geo, None, np.asarray(x, float))
    # variables [y, t]: A y + t <= b, maximise t (t bounded above by 1 to keep the LP bounded)
    A_t = csr_matrix(np.hstack([A.toarray(), np.ones((A.shape[0], 1))]))
    cost = np.zeros(size + 1)
    cost[-1] = -1.0
    res = linprog(cost, A_ub=A_t, b_ub=b, bounds=bounds + [(None, 1.0)], method="highs")
    if res.status != 0:
        return float("-inf")
    return float(res.x[-1])
