"""The parallelotope template: X0 = {x | ‖T x‖∞ <= s} with a gain K chosen by a linear program so that
X0 is λ-contractive for every A_cl(θ^k) (``design.x0_template = "parallelotope"``).

Complexity is fixed by n: 2n facets and 2^n vertices, whatever the dynamics (the contractive template
needs hundreds of rows from n = 4 on, the mrpi template's fixed directions rarely fit the closed loop).

Construction (polyhedral Lyapunov functions, Blanchini & Miani, "Set-theoretic methods in control",
Ch. 4-5: the set {‖T x‖∞ <= 1}, T invertible, is λ-contractive for x⁺ = A x iff ‖T A T⁻¹‖∞ <= λ):

1. K₀: the gain of the LMI (16) (:func:`~amcp_drake.offline.design.robust_gain`).
2. For a few rounds (:data:`ROUNDS`): T = V⁻¹ with V the real eigenbasis of the nominal closed loop
   A_cl(θ̂0) (real and imaginary parts of complex eigenvectors, columns normalised); rows of T scaled by
   the Perron vector of max_k |T A_cl(θ^k) T⁻¹| (which brings the ∞-norm down to that matrix's spectral
   radius); then the linear program

       min λ  s.t.  Σ_l |[T (A(θ^k) + B(θ^k) K) T⁻¹]_il| <= λ  for every row i and vertex θ^k of Θ

   over K and λ (T(A + BK)T⁻¹ is affine in K; the absolute values by slack variables), solved with
   scipy's HiGHS. The best (T, K) of all rounds is kept.
3. λ̄ < 1 is required (TemplateError "not contractive" otherwise). X0 = {‖T x‖∞ <= 1} is then scaled
   to robust invariance, h̄^k + w̄ <= 1 (:func:`~amcp_drake.offline.templates.scale_to_robust_invariance`).
4. P for (16) with this K: the LMI (16) of the design backend solved on the closed-loop vertices
   A_cl(θ^k) with the stage cost Q + KᵀRK and no input (B = 0): its P satisfies
   A_cl(θ^k)ᵀ P A_cl(θ^k) − P + Q + KᵀRK ⪯ 0 at every vertex, i.e. (16) for K.

Nothing of this is trusted: the design re-checks (16) by eigenvalues and the automatic mode accepts the
design only when every independent check of offline/checks.py passes (contractivity and invariance of
X0 at its vertices, Assumption 11 for X_f, (11) for μ).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linprog

from amcp_drake.model.errors import DesignError
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.budget import DesignBudget, unbounded

#: Rounds of (basis, Perron scaling, LP for K); measured on the 3-mass chain: 0.924 after 3 rounds.
ROUNDS = 4
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


def lp_gain(T: np.ndarray, A_v: np.ndarray, B_v: np.ndarray) -> tuple[np.ndarray, float] | None:
    """argmin over K of max_k ‖T (A_k + B_k K) T⁻¹‖∞ (module docstring, step 2) and its value; None
    when the LP fails."""
    n, m = B_v.shape[1], B_v.shape[2]
    T_inv = np.linalg.inv(T)
    v = len(A_v)
    nk, nn = m * n, n * n
    nvar = nk + v * nn + 1
    rows, rhs = [], []
    for k in range(v):
        M0 = (T @ A_v[k] @ T_inv).reshape(nn)
        dM = np.einsum("ia,bj->ijab", T @ B_v[k], T_inv).reshape(nn, nk)  # d[T B K T⁻¹]_ij / dK_ab
        base = nk + k * nn
        slack = np.zeros((nn, nvar))
        slack[:, base:base + nn] = -np.eye(nn)
        upper = slack.copy()
        upper[:, :nk] = dM
        lower = slack.copy()
        lower[:, :nk] = -dM
        rows += [upper, lower]  # ±[T (A_k + B_k K) T⁻¹]_ij <= s_ij
        rhs += [-M0, M0]
        sums = np.zeros((n, nvar))
        for i in range(n):
            sums[i, base + i * n: base + (i + 1) * n] = 1.0
        sums[:, -1] = -1.0  # Σ_j s_ij <= λ
        rows.append(sums)
        rhs.append(np.zeros(n))
    c = np.zeros(nvar)
    c[-1] = 1.0
    res = linprog(c, A_ub=np.vstack(rows), b_ub=np.concatenate(rhs),
                  bounds=[(None, None)] * nk + [(0, None)] * (nvar - nk), method="highs")
    if res.status != 0:
        return None
    return np.asarray(res.x[:nk]).reshape(m, n), float(res.x[-1])


def parallelotope_gain(problem, K0: np.ndarray, budget: DesignBudget | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """(K, T, λ̄) of steps 1-2 of the module docstring, starting from ``K0``; the best round."""
    budget = budget or unbounded()
    theta_v = problem.theta_vertices()
    A_v = np.array([problem.A_of(t) for t in theta_v])
    B_v = np.array([problem.B_of(t) for t in theta_v])
    A0, B0 = problem.A_of(problem.theta_hat0), problem.B_of(problem.theta_hat0)
    K = np.asarray(K0, float)
    best: tuple[np.ndarray, np.ndarray, float] | None = None
    for round_ in range(1, ROUNDS + 1):
        budget.tick(f"X0 template parallelotope, round {round_}")
        basis = real_eigenbasis(A0 + B0 @ K)
        if not np.isfinite(np.linalg.cond(basis)) or np.linalg.cond(basis) > MAX_CONDITION:
            break
        T = np.linalg.inv(basis)
        A_cl = A_v + B_v @ K
        T = perron_scaled(T, A_cl)
        found = lp_gain(T, A_v, B_v)
        if found is None:
            break
        K_new, _ = found
        lam = inf_norm(T, A_v + B_v @ K_new)  # recomputed, not the LP's value
        if best is None or lam < best[2]:
            best = (K_new, T, lam)
        K = K_new
    if best is None:
        raise DesignError("X0 template parallelotope: no eigenbasis or LP solution for the gain (module "
                          "offline/parallelotope.py)")
    return best


def fixed_gain_terminal_weight(problem, K: np.ndarray, be, margin: float) -> np.ndarray:
    """P of (16) for a given K (module docstring, step 4), or DesignError."""
    theta_v = problem.theta_vertices()
    A_cl = np.array([problem.A_of(t) + problem.B_of(t) @ K for t in theta_v])
    B_none = np.zeros((len(A_cl), problem.n, 1))
    gain = be.robust_gain(A_cl, B_none, problem.Q + K.T @ problem.R @ K, np.eye(1), margin)
    if gain.status is not SolveStatus.OPTIMAL or gain.P is None:
        raise DesignError(f"parallelotope: the LMI (16) for P with the LP's K: solver status {gain.status.value}")
    return np.asarray(gain.P, float)


__all__ = ["ROUNDS", "fixed_gain_terminal_weight", "inf_norm", "lp_gain", "parallelotope_gain", "perron_scaled",
           "real_eigenbasis"]
