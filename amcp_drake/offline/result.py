"""The result of the offline design (:class:`OfflineDesign`) and the two helpers the design and
its independent checks share: the closed-loop matrices at the vertices of Θ and sup ‖D(x,u)‖² of (11).

Kept apart from design.py so that the checks (offline/checks.py) and the automatic mode
(offline/auto.py) do not import the design code they judge or drive (no import cycle).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.model.problem import Problem
from amcp_drake.offline.budget import BYTES_PER_QHULL_VERTEX, DesignBudget, unbounded


@dataclass(frozen=True, eq=False)
class OfflineDesign:
    """Result of :func:`design`. Shapes: n states, m inputs, p parameters, u facets of X0,
    v vertices of X0, v_p vertices of Θ, c rows of Z, r rows of X_f, q rows of H_θ.

    * ``K`` (m, n), ``P`` (n, n): Assumption 8 and (16).
    * ``H_x`` (u, n): X0 = {x | H_x x <= 1} (14); ``X0_vertices`` (v, n).
    * ``w_bar`` (u,): [w̄]_i = max_{w∈W} [H_x]_i w; ``f_bar`` (c,): [f̄]_i = max_{x∈X0} [F+GK]_i x.
    * ``h_bar`` (v_p, u): [h̄^k]_i = max_{x∈X0} [H_x]_i A_cl(θ^k) x (App. A.1); ``lambda_bar`` = max h̄.
    * ``A_z`` (n, n): centre dynamics z⁺ = A_z z of the terminal recursion (Appendix A.1).
    * ``H_T`` (r, n), ``h_T`` (r,): X_f = {(z, α) | H_T z + h_T α <= 1, α >= 0} (Assumption 11).
    * ``mu``: gain of (12); ``mu_sup`` = sup ‖D(x,u)‖₂² over ``mu_region`` (the (x,u) set used), or an
      upper bound of it (``mu_method``).
    * ``H_theta`` (q, p), ``h_theta0`` (q,): the fixed shape and initial offsets of (9), Θ ⊆ Θ0.
    * ``theta_vertices`` (v_p, p).
    """

    K: np.ndarray
    P: np.ndarray
    H_x: np.ndarray
    X0_vertices: np.ndarray
    w_bar: np.ndarray
    f_bar: np.ndarray
    h_bar: np.ndarray
    lambda_bar: float
    A_z: np.ndarray
    H_T: np.ndarray
    h_T: np.ndarray
    mu: float
    mu_sup: float
    mu_region: str
    H_theta: np.ndarray
    h_theta0: np.ndarray
    theta_vertices: np.ndarray
    terminal_iterations: int
    backend: str
    gain_source: str = "lmi"
    info: dict = field(default_factory=dict)
    #: the box |x_i| <= bound over which μ of (11) was computed when Z is unbounded in x (None: over Z);
    #: recorded with the design so that a trajectory carries what the certificate's (11) check needs
    mu_state_bound: float | None = None
    #: how ``mu_sup`` was obtained (:class:`RegressorSup`): "exact: ..." (the supremum, from the region's
    #: vertices) or "bound: ..." (an upper bound of it from support LPs; μ is then smaller, still valid)
    mu_method: str = "exact"

    def to_dict(self) -> dict:
        """JSON-ready dict of every field."""
        out = {}
        for key in self.__dataclass_fields__:
            value = getattr(self, key)
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        return out

    @classmethod
    def from_dict(cls, data: dict) -> OfflineDesign:
        """Inverse of :meth:`to_dict`."""
        kwargs = {}
        for key, f in cls.__dataclass_fields__.items():
            if key not in data:
                if key in ("gain_source", "info", "mu_state_bound", "mu_method"):
                    continue
                raise ProblemError(f"design.{key}", "a value", "nothing (missing)")
            value = data[key]
            kwargs[key] = np.asarray(value, float) if isinstance(value, list) else value
        return cls(**kwargs)


def closed_loop_vertices(problem: Problem, K: np.ndarray, theta_vertices: np.ndarray) -> np.ndarray:
    """A_cl(θ^k) = A(θ^k) + B(θ^k) K for every vertex θ^k of Θ, shape (v_p, n, n)."""
    return np.array([problem.A_of(t) + problem.B_of(t) @ K for t in theta_vertices])


#: The exact supremum of (11) enumerates the vertices of the (x, u) region only when their estimated
#: count is at most this (2^14: a box in 14 dimensions, about 2 s of CPU with Qhull); above it, or when
#: the enumeration's memory estimate exceeds the design's limit, the upper bound of
#: :func:`regressor_upper_bound` is used (a larger sup, hence a smaller μ, still valid for (11)).
MU_EXACT_MAX_VERTICES = 2**14
#: Relative and absolute margins added to every support-LP value of :func:`regressor_upper_bound`
#: (HiGHS at :data:`~amcp_drake.model.polytope.HIGHS_CERTIFIED_OPTIONS` is exact to about 1e-10), so
#: that the bound stays above the supremum whatever the LP's round-off.
MU_BOUND_LP_RTOL = 1e-7
MU_BOUND_LP_ATOL = 1e-12
#: Vertices evaluated at once by the exact supremum (bounds its memory; the budget is ticked per chunk).
MU_VERTEX_CHUNK = 4096
#: The ways sup ‖D‖₂² of (11) is obtained (``method`` of :func:`regressor_sup`).
MU_METHODS = ("auto", "exact", "bound")


@dataclass(frozen=True)
class RegressorSup:
    """sup ‖D(x,u)‖₂² of (11) (``value``) over ``region``, and how it was obtained: ``method`` "exact"
    (the maximum over the enumerated vertices of the region: the supremum itself) or "bound" (the upper
    bound of :func:`regressor_upper_bound`, >= the supremum); ``detail`` says which and why."""

    value: float
    region: str
    method: str
    detail: str


def regressor_bound(problem: Problem, state_bound: float | None, budget: DesignBudget | None = None, method: str = "auto") -> tuple[float, str]:
    """(value, region) of :func:`regressor_sup`."""
    found = regressor_sup(problem, state_bound, budget, method)
    return found.value, found.region


def regressor_sup(problem: Problem, state_bound: float | None, budget: DesignBudget | None = None, method: str = "auto") -> RegressorSup:
    """sup ‖D(x,u)‖₂² over Z (or Z ∩ {|x_i| <= state_bound} when Z is unbounded in x), or an upper
    bound of it; either gives a valid μ in (11) (1/μ > sup ‖D‖₂² holds for μ = fraction / value).

    ``method`` "exact": ‖D(x,u)‖₂ is convex in z = (x,u), so the supremum is attained at a vertex of that
    polytope in R^(n+m); the vertices are enumerated (Qhull, no optimisation solver) and D evaluated at
    each. "bound": :func:`regressor_upper_bound` (support LPs only, no enumeration). "auto": exact when
    the region's vertex count, estimated before anything is enumerated (2^d for a box in d dimensions,
    otherwise ``budget``'s estimate), is at most :data:`MU_EXACT_MAX_VERTICES` and its memory estimate
    within ``budget``'s limit; the bound otherwise. ``budget``
    (:class:`~amcp_drake.offline.budget.DesignBudget`, None: the default limit) is ticked while the
    vertices are evaluated.
    """
    if method not in MU_METHODS:
        raise ValueError(f"method: expected one of {', '.join(MU_METHODS)}; received {method!r}")
    budget = budget or unbounded()
    n, m = problem.n, problem.m
    H = np.hstack([problem.F, problem.G])
    h = np.ones(len(H))
    region = "Z"
    mats = np.concatenate([problem.A, problem.B], axis=2)  # D(z) = [M_1 z, ..., M_p z], M_i = [A_i B_i]
    if not polytope.is_bounded(H, h):
        if state_bound is None:
            raise ProblemError("design.mu_state_bound", "a bound on |x_i| because Z is unbounded in x (needed for "
                               "sup ‖D(x,u)‖² in (11))", "nothing",
                               "Set design.mu_state_bound; the closed loop is then checked to stay inside that box.")
        Hb, hb = polytope.box(-state_bound * np.ones(n), state_bound * np.ones(n))
        H = np.vstack([H, np.hstack([Hb, np.zeros((2 * n, m))])])
        h = np.concatenate([h, hb])
        region = f"Z ∩ {{|x_i| <= {state_bound:g}}}"
        if not polytope.is_bounded(H, h):
            if np.any(problem.B != 0):
                raise ProblemError("Z.G", "Z bounded in the input u (needed for (11): D(x, u) depends on u through "
                                   "the B_i)", "an input direction without bound")
            # every B_i = 0: D(x, u) = [A_1 x, ..., A_p x] does not depend on u, and Z need not bound u.
            # The supremum is taken over X_s = {x | the rows of Z without u} ∩ {|x_i| <= state_bound},
            # which contains the projection of Z ∩ {|x_i| <= state_bound} onto x: an upper bound of the
            # supremum over Z (so μ of (11) is valid), equal to it when the rows of Z with u hold no x
            # (input bounds) and admit some u.
            state_rows = np.all(problem.G == 0, axis=1)
            H = np.vstack([problem.F[state_rows], Hb])
            h = np.concatenate([np.ones(int(state_rows.sum())), hb])
            mats = np.asarray(problem.A, float)
            region = f"{{x | the rows of Z without u, |x_i| <= {state_bound:g}}} (B known: D does not depend on u)"
    dim = H.shape[1]
    count, how = _vertex_estimate(H, h, budget)
    if method == "auto":
        too_many = count > MU_EXACT_MAX_VERTICES
        too_large = count * dim * BYTES_PER_QHULL_VERTEX > budget.limit_bytes
        method = "bound" if (too_many or too_large) else "exact"
        why = (f"exact enumeration refused: {how}, above {MU_EXACT_MAX_VERTICES:,}" if too_many else
               f"exact enumeration refused: {how} need more than the memory limit" if too_large else "")
    else:
        why = f"{method} asked for"
    if method == "exact":
        budget.require("mu (11): the vertices of the (x, u) region", count * dim * BYTES_PER_QHULL_VERTEX,
                       f"vertex enumeration of {len(H)} rows in {dim} dimensions: {how}")
        budget.tick("mu (11): vertex enumeration")
        verts = polytope.vertices(H, h)
        sup = 0.0
        for start in range(0, len(verts), MU_VERTEX_CHUNK):
            budget.tick("mu (11): sup ‖D‖² at the vertices")
            D = np.einsum("pij,vj->vip", mats, verts[start:start + MU_VERTEX_CHUNK])  # (v, n, p)
            sup = max(sup, float(np.max(np.linalg.norm(D, ord=2, axis=(1, 2)) ** 2)))
        found = RegressorSup(sup, region, "exact", f"exact: maximum over the {len(verts):,} vertices of the region "
                                                   f"in {dim} dimensions")
    else:
        budget.tick("mu (11): upper bound by support LPs")
        sup, parts = regressor_upper_bound(mats, H, h)
        found = RegressorSup(sup, region, "bound", f"bound: {parts} (>= the supremum; {why})")
    if found.value <= 0.0:
        raise ProblemError("system.A, system.B", "a regressor D(x,u) that is not identically zero on Z", "sup ‖D‖ = 0")
    return found


def _vertex_estimate(H: np.ndarray, h: np.ndarray, budget: DesignBudget) -> tuple[float, str]:
    """(estimated vertex count, how) of the bounded polytope {H z <= h}: 2^d when it is a box (every
    row has one nonzero entry and each coordinate is bounded on both sides: then exact), else the
    budget's estimate (the upper bound theorem, or a count measured in the same dimension)."""
    dim = H.shape[1]
    nonzero = H != 0
    if np.all(nonzero.sum(axis=1) <= 1) and np.all(np.any(H > 0, axis=0)) and np.all(np.any(H < 0, axis=0)):
        return 2.0 ** dim, f"2^{dim} vertices of a box in {dim} dimensions"
    return budget.estimate_vertices(len(H), dim)


def _lp_max(H: np.ndarray, h: np.ndarray, direction: np.ndarray) -> float:
    """max direction·z over {H z <= h}, made safe against the LP's round-off (MU_BOUND_LP_RTOL/ATOL)."""
    res = polytope.support(H, h, direction, certified=True)
    if res.status != "optimal" or not np.isfinite(res.value):
        raise DesignError(f"mu (11): a support LP of the upper bound of sup ‖D‖² ended {res.status}")
    return res.value + MU_BOUND_LP_RTOL * abs(res.value) + MU_BOUND_LP_ATOL


def regressor_upper_bound(mats: np.ndarray, H: np.ndarray, h: np.ndarray) -> tuple[float, str]:
    """An upper bound of sup ‖D(z)‖₂² over the bounded polytope {H z <= h}, D(z) = [M_1 z, ..., M_p z]
    (``mats`` (p, n, d)), from support LPs only (no vertex enumeration), and which of its terms gave it.

    With G(z) = D(z)ᵀD(z) (p × p), G_ij = (M_i z)ᵀ(M_j z) and ‖D‖₂² = λ_max(G):

    * s_i² >= sup ‖M_i z‖² by two bounds, the smaller kept: Σ_r (max |m_ir · z|)² over the rows m_ir of
      M_i (2 LPs per nonzero row), and |z|ᵀ|M_iᵀM_i||z| <= bᵀ|M_iᵀM_i|b with b_j = max |z_j| (2 LPs per
      coordinate);
    * c_ij >= sup |G_ij| (i ≠ j): min(s_i s_j (Cauchy–Schwarz), bᵀ|M_iᵀM_j|b); 0 when M_iᵀM_j = 0;
    * ‖D‖₂² = λ_max(G) <= max_i Σ_j |G_ij| (Gershgorin) <= max_i (s_i² + Σ_{j≠i} c_ij), and
      ‖D‖₂² <= ‖D‖_F² = Σ_i ‖M_i z‖² <= Σ_i s_i²; the smaller of the two is returned.

    Every LP value is raised by MU_BOUND_LP_RTOL/ATOL. Equal to the supremum when p = 1 and M_1 has one
    nonzero row, or when the columns of D have disjoint rows and each M_i one nonzero row.
    """
    mats = np.asarray(mats, float)
    p, dim = mats.shape[0], H.shape[1]
    eye = np.eye(dim)
    b = np.array([max(_lp_max(H, h, eye[j]), _lp_max(H, h, -eye[j]), 0.0) for j in range(dim)])
    s2 = np.zeros(p)
    for i in range(p):
        rows = mats[i][np.any(mats[i] != 0, axis=1)]
        by_rows = sum(max(_lp_max(H, h, r), _lp_max(H, h, -r), 0.0) ** 2 for r in rows)
        by_box = float(b @ np.abs(mats[i].T @ mats[i]) @ b)
        s2[i] = min(by_rows, by_box)
    s = np.sqrt(s2)
    cross = np.zeros((p, p))
    for i in range(p):
        for j in range(p):
            if i != j:
                cross[i, j] = min(s[i] * s[j], float(b @ np.abs(mats[i].T @ mats[j]) @ b))
    gershgorin = float(np.max(s2 + cross.sum(axis=1))) if p else 0.0
    frobenius = float(np.sum(s2))
    if gershgorin <= frobenius:
        return gershgorin, f"max_i (s_i² + Σ_j c_ij) = {gershgorin:.6g} (Gershgorin on DᵀD; ‖D‖_F² bound {frobenius:.6g})"
    return frobenius, f"Σ_i s_i² = {frobenius:.6g} (‖D‖₂² <= ‖D‖_F²; Gershgorin bound {gershgorin:.6g})"
