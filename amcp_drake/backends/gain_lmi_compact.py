"""The gain LMI (16) in its compact form, for systems where the form as written is too large to solve
in seconds (docs/decisions.md, "The gain LMI (16) at n = 10 to 16").

The form as written (``DrakeBackend._gain_lmi``) has one block of size 3n + m per vertex of Θ:

    [[S, (A_v S + B_v Y)ᵀ, S Q^½, Yᵀ R^½], [A_v S + B_v Y, S, 0, 0], [Q^½ S, 0, I, 0], [R^½ Y, 0, 0, I]] ⪰ 0.

An interior-point solver (Clarabel) works with a dense scaling matrix of size d(d + 1)/2 per PSD block
of size d, so each iteration costs about v·(d(d + 1)/2)³/3 flops: 1.3 GFlop at n = 10 (16 vertices, d = 35;
~3 s of CPU per iteration, ~30 s per solve, measured on the 5-mass chain). The stage-cost part
S Q S + Yᵀ R Y does not depend on θ, so it is bounded once by a new variable Z:

    [[Z, S Q^½, Yᵀ R^½], [Q^½ S, I, 0], [R^½ Y, 0, I]] ⪰ 0                (one block, 2n + m)
    [[S − Z, (A_v S + B_v Y)ᵀ], [A_v S + B_v Y, S]] ⪰ 0   for each vertex v   (blocks of 2n)

By Schur complements this is S − (A_v S + B_v Y)ᵀ S⁻¹ (A_v S + B_v Y) ⪰ Z ⪰ S Q S + Yᵀ R Y, i.e. the
same feasible set of (S, Y) as the form as written, hence the same (16) for P = S⁻¹, K = Y P. The
vertex blocks shrink from 3n + m to 2n: (630/210)³ = 27 times fewer flops per vertex at n = 10.

Every block is handed to the solver as a PSD variable X with X_ij = (M(S, Y, Z) − margin·I)_ij on the
upper triangle (the form Drake itself builds for a PSD constraint on an expression), assembled here
from sparse linear maps (no symbolic expressions: their construction alone took seconds at n = 16).

Vertices (:func:`solve_compact` with ``active``): when Θ has many vertices (2^p for a box), the LMI is
solved on a subset and every vertex is checked by eigenvalues; the vertices whose block is not
positive semidefinite are added and the LMI solved again, until the answer satisfies every vertex's
block. The optimum over the subset that is feasible for every vertex is the optimum over all of them
(the subset's feasible set contains the full one), so the answer is that of the full LMI.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

#: Most vertices of Θ solved at once before the active-vertex loop of :func:`solve_compact` starts
#: with a subset: 16 blocks of 2n take 3 s CPU at n = 10; at n = 12 all 32 at once took 47 s CPU against
#: 56 s for the loop from 8 vertices (8, 16, 24, 32: it needed all of them).
ALL_VERTICES_MAX = 32
#: Vertices added per round of the active-vertex loop (the most violated ones).
ADD_PER_ROUND = 16
#: A vertex block counts as violated when its least eigenvalue is below −this × max(1, ‖S‖₂)
#: (the solver's tolerances are ~1e-8 relative).
VIOLATION_TOL = 1e-7


def _svec_map(n: int, offset: int, ncols: int) -> sp.csr_matrix:
    """Row-major vec of a symmetric n×n matrix from its upper-triangle variables (columns offset + k)."""
    iu = np.triu_indices(n)
    index = np.zeros((n, n), dtype=int)
    index[iu] = np.arange(len(iu[0]))
    index = np.where(np.triu(np.ones((n, n), bool)), index, index.T)
    rows = np.arange(n * n)
    return sp.csr_matrix((np.ones(n * n), (rows, offset + index.ravel())), shape=(n * n, ncols))


def _full_map(r: int, c: int, offset: int, ncols: int) -> sp.csr_matrix:
    """Row-major vec of a general r×c matrix variable (columns offset … offset + r c − 1)."""
    return sp.csr_matrix((np.ones(r * c), (np.arange(r * c), offset + np.arange(r * c))), shape=(r * c, ncols))


def _left(L: np.ndarray, X_map: sp.csr_matrix, cols: int) -> sp.csr_matrix:
    """Map of L X (row-major) from the map of X (X has ``cols`` columns): (L ⊗ I)."""
    return (sp.kron(sp.csr_matrix(L), sp.identity(cols)) @ X_map).tocsr()


def _right(X_map: sp.csr_matrix, R: np.ndarray, rows: int) -> sp.csr_matrix:
    """Map of X R (row-major) from the map of X (X has ``rows`` rows): (I ⊗ Rᵀ)."""
    return (sp.kron(sp.identity(rows), sp.csr_matrix(R.T)) @ X_map).tocsr()


def _transpose(X_map: sp.csr_matrix, r: int, c: int) -> sp.csr_matrix:
    """Map of Xᵀ from the map of the r×c matrix X."""
    perm = (np.arange(r * c).reshape(r, c).T).ravel()
    return X_map[perm]


class BlockLMI:
    """M(x) = M0 + Σ x_k M_k of a symmetric block matrix, kept as the sparse map of its upper triangle:
    ``coef`` (rows: the entries (i, j), i <= j, row-major; columns: x) and ``const``."""

    def __init__(self, sizes: list[int], blocks: dict, ncols: int) -> None:
        """``blocks[(a, b)]`` for a <= b: (map of the block's row-major vec or None, constant block or None)."""
        d = int(sum(sizes))
        starts = np.concatenate([[0], np.cumsum(sizes)])
        I, J = np.triu_indices(d)
        ba = np.searchsorted(starts, I, side="right") - 1
        bb = np.searchsorted(starts, J, side="right") - 1
        pieces, const = [], np.zeros(len(I))
        order = np.zeros(len(I), dtype=int)
        position = 0
        for (a, b), (lin, c0) in blocks.items():
            sel = np.flatnonzero((ba == a) & (bb == b))
            if len(sel) == 0:
                continue
            local = (I[sel] - starts[a]) * sizes[b] + (J[sel] - starts[b])
            if c0 is not None:
                const[sel] = np.asarray(c0, float).ravel()[local]
            if lin is not None:
                pieces.append(lin[local])
                order[position:position + len(sel)] = sel
                position += len(sel)
        full = sp.csr_matrix((len(I), ncols))
        if pieces:
            coef = sp.vstack(pieces).tocsr()
            perm = sp.csr_matrix((np.ones(position), (order[:position], np.arange(position))), shape=(len(I), position))
            full = (perm @ coef).tocsr()
        self.size, self.coef, self.const, self.I, self.J = d, full, const, I, J

    def dense_terms(self, margin: float) -> list[np.ndarray]:
        """[M0 − margin·I, M_1, …, M_k] as dense symmetric matrices (Drake's linear matrix inequality)."""
        d, ncols = self.size, self.coef.shape[1]
        out = np.zeros((ncols + 1, d, d))
        out[0][self.I, self.J] = self.const
        coo = self.coef.tocoo()
        out[1 + coo.col, self.I[coo.row], self.J[coo.row]] = coo.data
        out = out + np.triu(out, 1).transpose(0, 2, 1)
        out[0] -= margin * np.eye(d)
        return list(out)

    def value(self, x: np.ndarray) -> np.ndarray:
        """M(x) as a dense symmetric matrix."""
        upper = self.const + self.coef @ x
        M = np.zeros((self.size, self.size))
        M[self.I, self.J] = upper
        M[self.J, self.I] = upper
        return M


def build_blocks(A_vertices, B_vertices, Q, R):
    """(cost block list, S block, stage-cost block, vertex blocks, layout) of the compact LMI
    (module docstring) in the variables x = [svec S, vec Y, svec Z]."""
    A_vertices = np.asarray(A_vertices, float)
    B_vertices = np.asarray(B_vertices, float)
    n, m = A_vertices.shape[1], B_vertices.shape[2]
    ns = n * (n + 1) // 2
    nx = 2 * ns + m * n
    S_map = _svec_map(n, 0, nx)
    Y_map = _full_map(m, n, ns, nx)
    Z_map = _svec_map(n, ns + m * n, nx)
    Qh, Rh = _sqrtm_psd(Q), _sqrtm_psd(R)
    S_block = BlockLMI([n], {(0, 0): (S_map, None)}, nx)
    stage = BlockLMI([n, n, m], {(0, 0): (Z_map, None), (0, 1): (_right(S_map, Qh, n), None),
                                 (0, 2): (_transpose(_left(Rh, Y_map, n), m, n), None),
                                 (1, 1): (None, np.eye(n)), (2, 2): (None, np.eye(m))}, nx)
    vertices = []
    for A, B in zip(A_vertices, B_vertices):
        AS_BY = (_left(A, S_map, n) + _left(B, Y_map, n)).tocsr()
        vertices.append(BlockLMI([n, n], {(0, 0): ((S_map - Z_map).tocsr(), None),
                                          (0, 1): (_transpose(AS_BY, n, n), None), (1, 1): (S_map, None)}, nx))
    return S_block, stage, vertices, (n, m, ns, nx)


def svec_weight(W: np.ndarray) -> np.ndarray:
    """c with c·svec(S) = ⟨W, S⟩ (off-diagonal entries counted twice)."""
    n = W.shape[0]
    iu = np.triu_indices(n)
    return np.where(iu[0] == iu[1], 1.0, 2.0) * 0.5 * (W + W.T)[iu]


def unpack(x: np.ndarray, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(S, Y) from x = [svec S, vec Y, svec Z]."""
    ns = n * (n + 1) // 2
    S = np.zeros((n, n))
    iu = np.triu_indices(n)
    S[iu] = x[:ns]
    S = S + np.triu(S, 1).T
    return S, x[ns:ns + m * n].reshape(m, n)


def violated_vertices(vertices: list[BlockLMI], x: np.ndarray, scale: float) -> list[tuple[float, int]]:
    """(least eigenvalue, index) of every vertex block that is not positive semidefinite at x."""
    out = []
    for i, block in enumerate(vertices):
        low = float(np.linalg.eigvalsh(block.value(x))[0])
        if low < -VIOLATION_TOL * max(1.0, scale):
            out.append((low, i))
    return sorted(out)


def solve_compact(solve_subset: Callable[[list[int]], tuple], vertices: list[BlockLMI], first: list[int],
                  tick: Callable[[str], None] | None = None):
    """The active-vertex loop of the module docstring: ``solve_subset(indices)`` -> (status, x or None);
    returns (status, x, indices used). ``tick(stage)`` is called before each solve (budget, progress)."""
    active = sorted(set(first))
    while True:
        if tick is not None:
            tick(f"gain LMI (16): {len(active)} of {len(vertices)} vertices")
        status, x = solve_subset(active)
        if x is None or len(active) == len(vertices):
            return status, x, active
        S_norm = float(np.linalg.norm(unpack(x, vertices[0].size // 2, 0)[0], 2))
        bad = [i for _, i in violated_vertices(vertices, x, S_norm) if i not in active]
        if not bad:
            return status, x, active
        active = sorted(set(active) | set(bad[:ADD_PER_ROUND]))


def initial_vertices(A_vertices, B_vertices, Q, R, count: int = ADD_PER_ROUND) -> list[int]:
    """The ``count`` vertices where the Riccati gain and cost of the mean vertex (A̅, B̅) violate (16)
    most: a cheap guess of the vertices active at the optimum (the loop adds any that are missing)."""
    import scipy.linalg as sla

    A_vertices = np.asarray(A_vertices, float)
    B_vertices = np.asarray(B_vertices, float)
    A_bar, B_bar = A_vertices.mean(axis=0), B_vertices.mean(axis=0)
    try:
        with np.errstate(all="ignore"):
            P = sla.solve_discrete_are(A_bar, B_bar, Q, R)
        K = -np.linalg.solve(R + B_bar.T @ P @ B_bar, B_bar.T @ P @ A_bar)
    except (ValueError, np.linalg.LinAlgError):
        return list(range(min(count, len(A_vertices))))
    if not np.all(np.isfinite(P)) or not np.all(np.isfinite(K)):
        return list(range(min(count, len(A_vertices))))
    worst = []
    for A, B in zip(A_vertices, B_vertices):
        Acl = A + B @ K
        M = Acl.T @ P @ Acl - P + Q + K.T @ R @ K
        worst.append(float(np.linalg.eigvalsh(0.5 * (M + M.T))[-1]))
    return [int(i) for i in np.argsort(worst)[::-1][:count]]


def _sqrtm_psd(M: np.ndarray) -> np.ndarray:
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


__all__ = ["ADD_PER_ROUND", "ALL_VERTICES_MAX", "BlockLMI", "VIOLATION_TOL", "build_blocks", "initial_vertices", "solve_compact",
           "svec_weight", "unpack", "violated_vertices"]
