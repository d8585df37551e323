"""Persistent excitation (Section 4.2, spec §8): Assumption 20, Definition 21, the scalar-input PE
constraint and the two-QP procedure, and the set diameter used to show Proposition 23.

* :func:`xi_matrix`, :func:`assumption20` — Ξ = [Ξ_1 … Ξ_n] ∈ ℝ^{p×n(n+m)}, row j =
  [[A_j B_j]_1 … [A_j B_j]_n]; Assumption 20 (Σ_j λ_j [A_j B_j] = 0 ⇒ λ = 0) is rank Ξ = p.
* :func:`pe_measure` — Definition 21 for the realised regressor Φ_k = D_kᵀ: over every window of P
  consecutive steps, λ_min and λ_max of Σ_k D_kᵀ D_k (α and β of the definition are their
  infimum / supremum over windows).
* :func:`pe_quadratic` — the Marafioti-style window constraint Σ_{j=k−P+1}^{k} ū_j ū_jᵀ ⪰ ρ I on the
  stacked input ū_k = [u_k; u_{k−1}; …; u_{k−n}] (m = 1), written by the Schur complement as
  a u_k² + b u_k + c >= 0 (spec §8 step 2) and solved for its roots u₋ <= u₊.
* :func:`pe_bounds` — the first-input bounds of the two QPs (spec §8 step 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .problem import Problem

#: Assumption 20: singular values of Ξ below this (relative to the largest) count as zero.
RANK_TOL = 1e-10
#: When the lower block of the window Gram has λ_min <= ρ(1 + LEVEL_MARGIN), the level is reduced to
#: (1 − LEVEL_MARGIN)·λ_min so that S ≻ 0 with a margin (see :func:`pe_quadratic`).
LEVEL_MARGIN = 0.05
#: Below this fraction of ρ a reduced level is useless; the necessary (1,1) condition is used.
MIN_LEVEL_FRACTION = 1e-3
#: |a| below this is treated as a = 0 (the constraint b u + c >= 0 is then linear in u_k).
A_ZERO_TOL = 1e-12


def xi_matrix(problem: Problem) -> np.ndarray:
    """Ξ ∈ ℝ^{p×n(n+m)} of the Lemma 24 proof: row j is the rows of [A_j B_j] laid end to end."""
    AB = np.concatenate([problem.A, problem.B], axis=2)  # (p, n, n+m)
    return AB.reshape(problem.p, -1)


def assumption20(problem: Problem) -> tuple[bool, np.ndarray]:
    """(holds, singular values of Ξ): Assumption 20 holds iff Ξ has full row rank p."""
    sv = np.linalg.svd(xi_matrix(problem), compute_uv=False)
    holds = len(sv) >= problem.p and sv[-1] > RANK_TOL * max(sv[0], 1e-300)
    return bool(holds), sv


def pe_measure(D: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
    """Definition 21 with Φ_k = D_kᵀ: for each k0 = 0..K−window, λ_min and λ_max of
    Σ_{k=k0}^{k0+window−1} D_kᵀ D_k (D: (K, n, p) regressors D(x_k, u_k))."""
    D = np.asarray(D, float)
    grams = np.einsum("kni,knj->kij", D, D)
    lo, hi = [], []
    for k0 in range(len(D) - window + 1):
        ev = np.linalg.eigvalsh(grams[k0:k0 + window].sum(axis=0))
        lo.append(ev[0])
        hi.append(ev[-1])
    return np.array(lo), np.array(hi)


@dataclass(frozen=True)
class PEQuadratic:
    """a u² + b u + c >= 0 ⇔ Σ_{window} ū ūᵀ ⪰ ρ I (S ≻ 0 assumed); ``roots`` (u₋, u₊) when real."""

    a: float
    b: float
    c: float
    roots: tuple[float, float] | None
    necessary_only: bool = False
    level: float = 0.0


def pe_quadratic(u_past: np.ndarray, n: int, window: int, level: float) -> PEQuadratic | None:
    """The scalar PE constraint at step k (spec §8, steps 1-2).

    ``u_past`` = [u_0, …, u_{k−1}] (m = 1). Needs u_{k−window+1−n} … u_{k−1}, i.e. at least
    window − 1 + n past inputs; returns None otherwise (no constraint yet).

    When S = Ω₂₂ + r_k r_kᵀ is not positive definite, no u_k satisfies the window constraint (S is
    its lower-right block and does not depend on u_k). The level is then lowered to the largest
    attainable one, ρ_k = (1 − LEVEL_MARGIN) λ_min(lower block), and when that is negligible the
    necessary (1,1) condition Σ_{j=k−P+1}^{k} u_j² >= ρ, i.e. u_k² + ω₁₁ >= 0, is returned
    (``necessary_only``): both build up the excitation that makes the full level attainable in
    later windows (a decision of this project, docs/decisions.md "Section 4 extensions"; spec §8
    assumes S ≻ 0). ``level`` on the result is the level enforced.
    """
    u_past = np.asarray(u_past, float).reshape(-1)
    k = len(u_past)
    if k < window - 1 + n:
        return None

    def ubar(j: int) -> np.ndarray:  # [u_j; u_{j-1}; …; u_{j-n}] for j < k
        return u_past[j - n:j + 1][::-1]

    dim = n + 1
    Omega = -level * np.eye(dim)
    for j in range(k - window + 1, k):
        uj = ubar(j)
        Omega += np.outer(uj, uj)
    r = u_past[k - n:k][::-1]  # [u_{k-1}; …; u_{k-n}]
    w11, w21, W22 = Omega[0, 0], Omega[1:, 0], Omega[1:, 1:]
    S = W22 + np.outer(r, r)
    level_used = level
    lam_lower = float(np.linalg.eigvalsh(S + level * np.eye(n))[0])  # λ_min of the lower block of the Gram
    if lam_lower - level <= LEVEL_MARGIN * level:
        # S ⋡ 0: the level ρ is unattainable at k whatever u_k. Enforce the largest attainable level
        # ρ_k = (1 − LEVEL_MARGIN) λ_min(lower block) instead, or, when the lagged inputs carry no
        # excitation at all, the necessary (1,1) condition Σ_window u_j² >= ρ.
        level_used = (1.0 - LEVEL_MARGIN) * lam_lower
        if level_used <= MIN_LEVEL_FRACTION * level:
            c = float(w11)
            roots = (-np.sqrt(-c), np.sqrt(-c)) if c < 0 else None
            return PEQuadratic(1.0, 0.0, c, roots, necessary_only=True, level=level)
        Omega = Omega + (level - level_used) * np.eye(dim)
        w11, w21, W22 = Omega[0, 0], Omega[1:, 0], Omega[1:, 1:]
        S = W22 + np.outer(r, r)
    Si_r = np.linalg.solve(S, r)
    Si_w = np.linalg.solve(S, w21)
    a = float(1.0 - r @ Si_r)
    b = float(-2.0 * r @ Si_w)
    c = float(w11 - w21 @ Si_w)
    disc = b * b - 4 * a * c
    roots = None
    if abs(a) > A_ZERO_TOL and disc >= 0:
        s = np.sqrt(disc)
        r1, r2 = (-b - s) / (2 * a), (-b + s) / (2 * a)
        roots = (min(r1, r2), max(r1, r2))
    return PEQuadratic(a, b, c, roots, level=level_used)


def pe_bounds(quad: PEQuadratic | None) -> list[tuple[float, float]] | None:
    """First-input bounds (lo, hi) of the QPs to solve (spec §8 step 3): None = no constraint
    needed (no data yet, or a u² + b u + c >= 0 for every u); [] = no u_k satisfies it."""
    if quad is None:
        return None
    a, b, c = quad.a, quad.b, quad.c
    inf = float("inf")
    if abs(a) <= A_ZERO_TOL:
        if abs(b) <= A_ZERO_TOL:
            return None if c >= 0 else []
        return [(-c / b, inf)] if b > 0 else [(-inf, -c / b)]
    if quad.roots is None:  # no real root: the sign of a decides
        return None if a > 0 else []
    lo, hi = quad.roots
    if a > 0:
        return [(-inf, lo), (hi, inf)]
    return [(lo, hi)]


def theta_diameter(H: np.ndarray, h: np.ndarray) -> float:
    """sup_{θ1,θ2 ∈ Θ} ‖θ1 − θ2‖ (Proposition 23) from the vertices of {H θ <= h} (largest pairwise
    distance); the bounding-box diagonal (an upper bound) when vertices cannot be enumerated."""
    from . import polytope
    from .certify_checks import theta_vertices

    verts = theta_vertices(H, h)
    if verts is not None and len(verts) > 0:
        diff = verts[:, None, :] - verts[None, :, :]
        return float(np.max(np.linalg.norm(diff, axis=2)))
    p = H.shape[1]
    hi = np.array([polytope.support(H, h, e).value for e in np.eye(p)])
    lo = -np.array([polytope.support(H, h, -e).value for e in np.eye(p)])
    return float(np.linalg.norm(hi - lo))
