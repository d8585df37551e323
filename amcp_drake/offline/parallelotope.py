"""The parallelotope template: X0 = {x | ‖T x‖∞ <= s} with a gain K chosen by a linear program so that
X0 is λ-contractive for every A_cl(θ^k) (``design.x0_template = "parallelotope"``).

Complexity is fixed by n: 2n facets and 2^n vertices, whatever the dynamics (the contractive template
needs hundreds of rows from n = 4 on, the mrpi template's fixed directions rarely fit the closed loop).

Construction (polyhedral Lyapunov functions, Blanchini & Miani, "Set-theoretic methods in control",
Ch. 4-5: the set {‖T x‖∞ <= 1}, T invertible, is λ-contractive for x⁺ = A x iff ‖T A T⁻¹‖∞ <= λ):

1. Starting gains: K₀ of the LMI (16) (:func:`~amcp_drake.offline.design.robust_gain`) and, when the
   nominal pair (A(θ̂0), B(θ̂0)) allows it, a gain placing the nominal closed-loop poles at n distinct
   real values in [:data:`PLACED_POLES`] (scipy's ``place_poles``): a real-eigenvalue closed loop has a
   real eigenbasis in which the ∞-norm is close to the spectral radius, whereas a complex pair r e^{±iφ}
   costs r (|cos φ| + |sin φ|) in any real 2-D block.
2. For a few rounds (:data:`ROUNDS`) from each start: T = V⁻¹ with V the real eigenbasis of the nominal
   closed loop A_cl(θ̂0) (real and imaginary parts of complex eigenvectors, columns normalised); rows of
   T scaled by the Perron vector of max_k |T A_cl(θ^k) T⁻¹| (which brings the ∞-norm down to that
   matrix's spectral radius); then, for each λ of :data:`LAMBDA_GRID`, the linear program (in K, γ and
   slack variables for the absolute values, scipy's HiGHS)

       min γ  s.t.  Σ_l |[T (A(θ^k) + B(θ^k) K) T⁻¹]_il| <= λ   for every row i and vertex θ^k of Θ,
                    Σ_l |[(F + G K) T⁻¹]_jl| <= γ               for every row j of Z,

   and the minimal-λ program of the same constraints without the rows of Z. Each answer is rated by
   r = γ̄ σ̄_W / (1 − λ̄), recomputed from (T, K): λ̄ = max_k ‖T A_cl(θ^k) T⁻¹‖∞, γ̄ = max_j ‖(F+GK)_j T⁻¹‖₁
   (the support of X = {‖T x‖∞ <= 1} in the direction (F+GK)_j) and σ̄_W = max_i σ_W(T_i). The tube scaled
   to robust invariance, s X with s = σ̄_W / (1 − λ̄), has max f̄ = s γ̄ = r, and the scaled terminal set
   of offline/terminal.py exists iff α_∞ max f̄ < 1 with α_∞ = 1 here: r < 1 is the condition for a
   design, and the smaller r, the more room the constraints leave around the tube. The (T, K) of least
   r is kept (λ̄ < 1 required).
3. λ̄ < 1 is required (TemplateError "not contractive" otherwise). X0 = {‖T x‖∞ <= 1} is then scaled
   to robust invariance, h̄^k + w̄ <= 1 (:func:`~amcp_drake.offline.templates.scale_to_robust_invariance`).
4. P for (16) with this K: the LMI (16) of the design backend solved on the closed-loop vertices
   A_cl(θ^k) with the stage cost Q + KᵀRK and no input (B = 0): its P satisfies
   A_cl(θ^k)ᵀ P A_cl(θ^k) − P + Q + KᵀRK ⪯ 0 at every vertex, i.e. (16) for K.

The constraint rows in the linear program follow the literature's implementations of this scheme,
which design K together with the constraints it must respect (the gain of a λ-contractive tube is
chosen with the constraint-satisfaction conditions, not for contraction alone): a gain that only
minimises λ̄ reached ‖K‖ ≈ 100 on a 3-mass chain with |u| <= 3, where no tube fits in Z.

Nothing of this is trusted: the design re-checks (16) by eigenvalues and the automatic mode accepts the
design only when every independent check of offline/checks.py passes (contractivity and invariance of
X0 at its vertices, Assumption 11 for X_f, (11) for μ).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.optimize import linprog

from amcp_drake.model.errors import DesignError
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.budget import DesignBudget, unbounded
from amcp_drake.offline.gain import gain_lmi

#: From this many states on the LPs of step 2 are solved by HiGHS's interior-point method: its dual simplex
#: (the choice of method="highs") took 45 s and ended "numerical difficulties" on one LP of the 5-mass
#: chain (n = 10) that the interior-point method solves in 0.3 s. Below, the choice of scipy stays, so
#: the designs of the shipped examples (n <= 8) are unchanged.
IPM_FROM_N = 9
#: From IPM_FROM_N states on, a round whose least λ̄ is >= 1 but below this still hands its gain to the
#: next round (a new eigenbasis): on the 5-mass chain in the units normalised by W the placed gain's first
#: round reaches λ̄ = 1.007 and the second 0.87 (r = 0.42 in the file's units). Below IPM_FROM_N a round
#: without λ̄ < 1 ends the start, so the shipped designs are unchanged.
CONTINUE_BELOW = 1.1
#: Rounds of (basis, Perron scaling, LPs for K) from each starting gain.
ROUNDS = 4
#: Contraction factors λ of the constraint-aware linear program (step 2); the minimal-λ program is
#: solved as well, so a system that admits only λ̄ close to 1 still gets its best parallelotope.
LAMBDA_GRID = (0.6, 0.75, 0.85, 0.9, 0.94, 0.97)
#: Range of the distinct real nominal poles of the placed starting gain (step 1).
PLACED_POLES = (0.5, 0.9)
#: From IPM_FROM_N states on, further ranges of the placed poles (more starts): scipy's placement of n
#: poles with several inputs is not unique and depends on the state units, and on the 5-mass chain in the
#: units normalised by W the first range leads to no parallelotope that fits Z.
EXTRA_PLACED_POLES = ((0.3, 0.8), (0.6, 0.95))
#: An eigenbasis whose condition number exceeds this is not used (its T would amplify round-off).
MAX_CONDITION = 1e8
#: Added to every entry of max_k |T A_cl T⁻¹| before its Perron vector is taken (irreducibility).
PERRON_EPS = 1e-9


def real_eigenbasis(A: np.ndarray) -> np.ndarray:
    """Columns: real eigenvectors of A, or real and imaginary parts of one of each complex pair, each
    normalised; by decreasing modulus."""
    w, V = np.linalg.eig(A)
    cols: list[np.ndarray] = []
    done: set[int] = set()
    for i in np.argsort(-np.abs(w), kind="stable"):
        if i in done:
            continue
        if abs(w[i].imag) <= 1e-12 * max(1.0, abs(w[i])):
            cols.append(V[:, i].real)
            done.add(int(i))
            continue
        partner = [k for k in range(len(w)) if k not in done and k != i and abs(w[k] - np.conj(w[i])) <= 1e-8 * max(1.0, abs(w[i]))]
        cols += [V[:, i].real, V[:, i].imag]
        done |= {int(i), *(int(k) for k in partner[:1])}
    basis = np.column_stack(cols[:A.shape[0]])
    return basis / np.linalg.norm(basis, axis=0)


def inf_norm(T: np.ndarray, A_cl: np.ndarray) -> float:
    """max_k ‖T A_cl(θ^k) T⁻¹‖∞."""
    T_inv = np.linalg.inv(T)
    return float(max(np.max(np.sum(np.abs(T @ Ak @ T_inv), axis=1)) for Ak in A_cl))


def perron_scaled(T: np.ndarray, A_cl: np.ndarray) -> np.ndarray:
    """T with its rows scaled by 1 / v, v the Perron vector of max_k |T A_cl T⁻¹| (+ PERRON_EPS)."""
    T_inv = np.linalg.inv(T)
    M = np.max([np.abs(T @ Ak @ T_inv) for Ak in A_cl], axis=0) + PERRON_EPS
    w, V = np.linalg.eig(M)
    v = np.abs(V[:, int(np.argmax(w.real))].real)
    if not np.all(v > 0):
        return T
    return T / v[:, None]


def lp_gain(T: np.ndarray, A_v: np.ndarray, B_v: np.ndarray, F: np.ndarray | None = None,
            G: np.ndarray | None = None, lam: float | None = None) -> tuple[np.ndarray, float] | None:
    """The linear programs of step 2 (module docstring) for a fixed T; None when the LP fails.

    Without ``lam``: argmin over K of max_k ‖T (A_k + B_k K) T⁻¹‖∞ and that value. With ``lam`` and the
    rows (F, G) of Z: argmin over K of max_j ‖(F_j + G_j K) T⁻¹‖₁ subject to ‖T (A_k + B_k K) T⁻¹‖∞ <= λ
    for every k, and that minimum γ."""
    n, m = B_v.shape[1], B_v.shape[2]
    T_inv = np.linalg.inv(T)
    v = len(A_v)
    nk, nn = m * n, n * n
    with_z = lam is not None
    nc = len(F) if with_z else 0
    nvar = nk + v * nn + nc * n + 1
    rows, rhs = [], []
    for k in range(v):
        M0 = (T @ A_v[k] @ T_inv).reshape(nn)
        dM = np.einsum("ia,bj->ijab", T @ B_v[k], T_inv).reshape(nn, nk)  # d[T B K T⁻¹]_ij / dK_ab
        base = nk + k * nn
        _abs_rows(rows, rhs, dM, M0, base, nvar)  # ±[T (A_k + B_k K) T⁻¹]_ij <= s_ij
        sums = sp.lil_matrix((n, nvar))
        for i in range(n):
            sums[i, base + i * n: base + (i + 1) * n] = 1.0
        if with_z:
            rows.append(sums)
            rhs.append(np.full(n, float(lam)))  # Σ_j s_ij <= λ
        else:
            sums[:, nvar - 1] = -1.0  # Σ_j s_ij <= t, t minimised
            rows.append(sums)
            rhs.append(np.zeros(n))
    if with_z:
        base = nk + v * nn
        C0 = (np.asarray(F, float) @ T_inv).reshape(nc * n)
        dC = np.einsum("ja,bl->jlab", np.asarray(G, float), T_inv).reshape(nc * n, nk)  # d[G K T⁻¹]_jl / dK_ab
        _abs_rows(rows, rhs, dC, C0, base, nvar)
        sums = sp.lil_matrix((nc, nvar))
        for j in range(nc):
            sums[j, base + j * n: base + (j + 1) * n] = 1.0
        sums[:, nvar - 1] = -1.0  # Σ_l |[(F + GK) T⁻¹]_jl| <= γ
        rows.append(sums)
        rhs.append(np.zeros(nc))
    c = np.zeros(nvar)
    c[-1] = 1.0
    res = linprog(c, A_ub=sp.vstack([sp.csr_matrix(r) for r in rows]).tocsr(), b_ub=np.concatenate(rhs),
                  bounds=[(None, None)] * nk + [(0, None)] * (nvar - nk),
                  method="highs" if n < IPM_FROM_N else "highs-ipm")
    if res.status != 0:
        return None
    return np.asarray(res.x[:nk]).reshape(m, n), float(res.x[-1])


def _abs_rows(rows: list, rhs: list, dM: np.ndarray, M0: np.ndarray, base: int, nvar: int) -> None:
    """Append ±(M0 + dM·vec K) <= s (slacks s at ``base``) to the LP rows (sparse: the rows of every
    vertex are n² × (mn + 1) non-zeros, the dense matrix would be n² × v n² per vertex)."""
    size = len(M0)
    for sign in (1.0, -1.0):
        gain = sp.coo_matrix(sign * dM)
        slack_rows = np.arange(size)
        data = np.concatenate([gain.data, -np.ones(size)])
        r = np.concatenate([gain.row, slack_rows])
        c = np.concatenate([gain.col, base + slack_rows])
        rows.append(sp.csr_matrix((data, (r, c)), shape=(size, nvar)))
    rhs += [-M0, M0]


def rating(T: np.ndarray, K: np.ndarray, A_v: np.ndarray, B_v: np.ndarray, F: np.ndarray, G: np.ndarray,
           W_vertices: np.ndarray) -> tuple[float, float]:
    """(r, λ̄) of step 2, recomputed from T and K: λ̄ = max_k ‖T A_cl(θ^k) T⁻¹‖∞ and
    r = γ̄ σ̄_W / (1 − λ̄) (inf when λ̄ >= 1)."""
    lam = inf_norm(T, A_v + B_v @ K)
    if not lam < 1.0:
        return float("inf"), lam
    gamma = float(np.max(np.sum(np.abs((F + G @ K) @ np.linalg.inv(T)), axis=1)))
    sigma_w = float(np.max(np.abs(W_vertices @ T.T)))
    return gamma * sigma_w / (1.0 - lam), lam


def placed_gain(A0: np.ndarray, B0: np.ndarray, poles_range: tuple[float, float] = PLACED_POLES) -> np.ndarray | None:
    """A gain placing the poles of A0 + B0 K at n distinct real values in :data:`PLACED_POLES`
    (step 1); None when scipy cannot place them (uncontrollable pair, too few inputs).

    scipy's warning that its iteration (for several inputs) stopped above its own tolerance is not
    passed on: the gain is only a starting point, whose closed loop is rated by its own λ̄ (step 2)
    over every vertex of Θ, and a warning per call would fill a campaign's terminal."""
    import warnings

    from scipy.signal import place_poles

    n = A0.shape[0]
    poles = np.linspace(poles_range[0], poles_range[1], n)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Convergence was not reached", category=UserWarning)
            return -np.asarray(place_poles(A0, B0, poles).gain_matrix, float)
    except (ValueError, np.linalg.LinAlgError):
        return None


def parallelotope_gain(problem, K0: np.ndarray, budget: DesignBudget | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """(K, T, λ̄) of steps 1-2 of the module docstring, starting from ``K0`` (and the placed gain): the
    (T, K) of least rating r over all rounds and λ."""
    budget = budget or unbounded()
    theta_v = problem.theta_vertices()
    A_v = np.array([problem.A_of(t) for t in theta_v])
    B_v = np.array([problem.B_of(t) for t in theta_v])
    A0, B0 = problem.A_of(problem.theta_hat0), problem.B_of(problem.theta_hat0)
    F, G = np.asarray(problem.F, float), np.asarray(problem.G, float)
    W_v = problem.w_vertices()
    starts = [np.asarray(K0, float)]
    for poles_range in (PLACED_POLES, *(EXTRA_PLACED_POLES if problem.n >= IPM_FROM_N else ())):
        placed = placed_gain(A0, B0, poles_range)
        if placed is not None:
            starts.append(placed)
    best: tuple[float, np.ndarray, np.ndarray, float] | None = None
    for number, K in enumerate(starts, start=1):
        for round_ in range(1, ROUNDS + 1):
            budget.tick(f"X0 template parallelotope, start {number}, round {round_}")
            basis = real_eigenbasis(A0 + B0 @ K)
            if not np.isfinite(np.linalg.cond(basis)) or np.linalg.cond(basis) > MAX_CONDITION:
                break
            T = perron_scaled(np.linalg.inv(basis), A_v + B_v @ K)
            round_best: tuple[float, np.ndarray, np.ndarray, float] | None = None
            least: tuple[float, np.ndarray] | None = None  # the least λ̄ of the round, < 1 or not
            for lam in (None, *LAMBDA_GRID):
                budget.tick(f"X0 template parallelotope, start {number}, round {round_}: gain LP")
                found = lp_gain(T, A_v, B_v) if lam is None else lp_gain(T, A_v, B_v, F, G, lam)
                if found is None:
                    continue
                r, lam_bar = rating(T, found[0], A_v, B_v, F, G, W_v)  # recomputed, not the LP's values
                if least is None or lam_bar < least[0]:
                    least = (lam_bar, found[0])
                if lam_bar < 1.0 and (round_best is None or (r, lam_bar) < (round_best[0], round_best[3])):
                    round_best = (r, found[0], T, lam_bar)
            if round_best is None:
                if problem.n >= IPM_FROM_N and least is not None and least[0] < CONTINUE_BELOW:
                    K = least[1]  # not contractive in this basis yet: the next round's basis starts from it
                    continue
                break
            if best is None or (round_best[0], round_best[3]) < (best[0], best[3]):
                best = round_best
            K = round_best[1]
    if best is None:
        raise DesignError("X0 template parallelotope: no eigenbasis or LP solution for the gain with "
                          "lambda_bar < 1 (module offline/parallelotope.py)")
    return best[1], best[2], best[3]


def fixed_gain_terminal_weight(problem, K: np.ndarray, be, margin: float, budget: DesignBudget | None = None) -> np.ndarray:
    """P of (16) for a given K (module docstring, step 4), or DesignError; ``budget`` is checked before
    every solve."""
    theta_v = problem.theta_vertices()
    A_cl = np.array([problem.A_of(t) + problem.B_of(t) @ K for t in theta_v])
    B_none = np.zeros((len(A_cl), problem.n, 1))
    gain = gain_lmi(be, A_cl, B_none, problem.Q + K.T @ problem.R @ K, np.eye(1), margin, budget)
    if gain.status is not SolveStatus.OPTIMAL or gain.P is None:
        raise DesignError(f"parallelotope: the LMI (16) for P with the LP's K: solver status {gain.status.value}")
    return np.asarray(gain.P, float)


__all__ = ["IPM_FROM_N", "LAMBDA_GRID", "PLACED_POLES", "ROUNDS", "fixed_gain_terminal_weight", "inf_norm", "lp_gain",
           "parallelotope_gain", "perron_scaled", "placed_gain", "rating", "real_eigenbasis"]
