"""Persistent excitation (Section 4.2, docs/explanation/paper.md §8): Assumption 20, Definition 21, the scalar-input PE
constraint and the two-QP procedure, and the set diameter used to show Proposition 23.

* :func:`xi_matrix`, :func:`assumption20` — Ξ = [Ξ_1 … Ξ_n] ∈ ℝ^{p×n(n+m)}, row j =
  [[A_j B_j]_1 … [A_j B_j]_n]; Assumption 20 (Σ_j λ_j [A_j B_j] = 0 ⇒ λ = 0) is rank Ξ = p.
* :func:`pe_measure` — Definition 21 for the realised regressor Φ_k = D_kᵀ: over every window of P
  consecutive steps, λ_min and λ_max of Σ_k D_kᵀ D_k (α and β of the definition are their
  infimum / supremum over windows).
* :func:`pe_quadratic` — the Marafioti-style window constraint Σ_{j=k−P+1}^{k} ū_j ū_jᵀ ⪰ ρ I on the
  stacked input ū_k = [u_k; u_{k−1}; …; u_{k−n}] (m = 1), written by the Schur complement as
  a u_k² + b u_k + c >= 0 (docs/explanation/paper.md §8 step 2) and solved for its roots u₋ <= u₊.
* :func:`pe_bounds` — the first-input bounds of the two QPs (docs/explanation/paper.md §8 step 3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amcp_drake.model.problem import Problem

#: Assumption 20: singular values of Ξ below this (relative to the largest) count as zero.
RANK_TOL = 1e-10
#: Ladder of levels (our decision, docs/decisions.md "Section 4 extensions"): the d-dimensional window
#: constraint (stacked input of the last d inputs) targets ρ_d = ρ·LADDER_FACTOR^(n+1−d)/(1 − LEVEL_MARGIN),
#: so that a constraint met at dimension d−1 makes dimension d attainable at the next step, and in
#: steady state the full constraint is met at a level >= ρ.
LADDER_FACTOR = 1.5
#: A dimension counts as attainable when (1 − LEVEL_MARGIN)·λ_min(lower block) reaches its ladder level
#: times ATTAINABLE_FRACTION; it is then enforced at min(ladder level, (1 − LEVEL_MARGIN)·λ_min(lower block)).
LEVEL_MARGIN = 0.05
ATTAINABLE_FRACTION = 0.5
#: When neither QP with the PE bound is feasible, the same rung is retried at these fractions of its
#: level before (20) is solved without PE (a single input may not reach the level, e.g. under |u| <= 1).
RETRY_LEVEL_FACTORS = (0.5, 0.25, 0.125)
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
    """a u_k² + b u_k + c >= 0 ⇔ Σ_{j=k−P+1}^{k} ū⁽ᵈ⁾_j ū⁽ᵈ⁾_jᵀ ⪰ ``level``·I, with ū⁽ᵈ⁾_j =
    [u_j; …; u_{j−d+1}] and d = ``dim`` (d = n + 1 is the constraint of docs/explanation/paper.md §8); ``roots`` (u₋, u₊)
    when real. ``necessary_only``: d = 1, i.e. Σ_window u_j² >= level."""

    a: float
    b: float
    c: float
    roots: tuple[float, float] | None
    necessary_only: bool = False
    level: float = 0.0
    dim: int = 0


def stacked_gram(u: np.ndarray, k: int, dim: int, window: int) -> np.ndarray:
    """Σ_{j=k−window+1}^{k} ū⁽ᵈ⁾_j ū⁽ᵈ⁾_jᵀ, ū⁽ᵈ⁾_j = [u_j; u_{j−1}; …; u_{j−d+1}] (m = 1); needs
    u_{k−window−dim+2} … u_k, i.e. k >= window + dim − 2."""
    u = np.asarray(u, float).reshape(-1)
    G = np.zeros((dim, dim))
    for j in range(k - window + 1, k + 1):
        ub = u[j - dim + 1:j + 1][::-1]
        G += np.outer(ub, ub)
    return G


def _quadratic(u_past: np.ndarray, k: int, dim: int, window: int, level: float) -> tuple[float, float, float]:
    """a, b, c of the dim-dimensional window constraint at level ``level`` (docs/explanation/paper.md §8 step 2), with
    S = Ω₂₂ + r rᵀ ≻ 0 assumed (checked by the caller)."""
    Omega = -level * np.eye(dim)
    for j in range(k - window + 1, k):
        uj = u_past[j - dim + 1:j + 1][::-1]
        Omega += np.outer(uj, uj)
    if dim == 1:
        return 1.0, 0.0, float(Omega[0, 0])
    r = u_past[k - dim + 1:k][::-1]  # [u_{k−1}; …; u_{k−d+1}]
    w11, w21, W22 = Omega[0, 0], Omega[1:, 0], Omega[1:, 1:]
    S = W22 + np.outer(r, r)
    Si_r = np.linalg.solve(S, r)
    Si_w = np.linalg.solve(S, w21)
    return float(1.0 - r @ Si_r), float(-2.0 * r @ Si_w), float(w11 - w21 @ Si_w)


def pe_quadratic(u_past: np.ndarray, n: int, window: int, level: float) -> PEQuadratic | None:
    """The scalar PE constraint at step k (docs/explanation/paper.md §8, steps 1-2), with a ladder for when it is
    unattainable.

    ``u_past`` = [u_0, …, u_{k−1}] (m = 1). The target is Σ_{j=k−P+1}^{k} ū_j ū_jᵀ ⪰ ρ I on the
    stacked input ū_k = [u_k; …; u_{k−n}] (d = n + 1). Its lower-right block (the lagged inputs) does
    not depend on u_k, so when that block's λ_min is below ρ no u_k reaches ρ (docs/explanation/paper.md §8 assumes
    S ≻ 0). That block is the (d−1)-dimensional window Gram of the previous step, so the constraint
    of dimension d−1 met at step k−1 makes dimension d attainable at step k. The rule (a decision of
    this project, docs/decisions.md "Section 4 extensions"): for d = n+1, n, …, 1 take the first
    dimension whose lower block reaches ATTAINABLE_FRACTION of its ladder level
    ρ_d = ρ·LADDER_FACTOR^(n+1−d)/(1 − LEVEL_MARGIN)
    (after the (1 − LEVEL_MARGIN) safety factor) and enforce it at min(ρ_d, (1 − LEVEL_MARGIN)·λ_min);
    d = 1 (Σ_window u_j² >= ρ_1) is always attainable. Starting from no excitation, the full
    dimension is reached after n steps of met constraints.

    Needs window − 1 + n past inputs; returns None before (no constraint yet).
    """
    u_past = np.asarray(u_past, float).reshape(-1)
    k = len(u_past)
    if k < window - 1 + n:
        return None
    for dim in range(n + 1, 0, -1):
        target = level * LADDER_FACTOR ** (n + 1 - dim) / (1.0 - LEVEL_MARGIN)
        if dim > 1:
            # lower block of the dim-dimensional Gram at k = (dim−1)-dimensional Gram at k−1
            lam_lower = float(np.linalg.eigvalsh(stacked_gram(u_past, k - 1, dim - 1, window))[0])
            attainable = (1.0 - LEVEL_MARGIN) * lam_lower
            if attainable < ATTAINABLE_FRACTION * target:
                continue
            used = min(target, attainable)
        else:
            used = target
        return pe_quadratic_at(u_past, dim, window, used)
    raise AssertionError("unreachable: dimension 1 is always attainable")


def pe_quadratic_at(u_past: np.ndarray, dim: int, window: int, level: float) -> PEQuadratic:
    """The dim-dimensional window constraint at step k = len(u_past) and a given level (the caller
    makes sure the level is attainable, i.e. S ≻ 0; lowering the level of an attainable one keeps it so)."""
    u_past = np.asarray(u_past, float).reshape(-1)
    a, b, c = _quadratic(u_past, len(u_past), dim, window, level)
    disc = b * b - 4 * a * c
    roots = None
    if abs(a) > A_ZERO_TOL and disc >= 0:
        s = np.sqrt(disc)
        r1, r2 = (-b - s) / (2 * a), (-b + s) / (2 * a)
        roots = (min(r1, r2), max(r1, r2))
    return PEQuadratic(a, b, c, roots, necessary_only=dim == 1, level=level, dim=dim)


def pe_bounds(quad: PEQuadratic | None) -> list[tuple[float, float]] | None:
    """First-input bounds (lo, hi) of the QPs to solve (docs/explanation/paper.md §8 step 3): None = no constraint
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
    from amcp_drake.model import polytope
    from amcp_drake.model.polytope import theta_vertices

    verts = theta_vertices(H, h)
    if verts is not None and len(verts) > 0:
        diff = verts[:, None, :] - verts[None, :, :]
        return float(np.max(np.linalg.norm(diff, axis=2)))
    p = H.shape[1]
    hi = np.array([polytope.support(H, h, e).value for e in np.eye(p)])
    lo = -np.array([polytope.support(H, h, -e).value for e in np.eye(p)])
    return float(np.linalg.norm(hi - lo))
