"""Solver answers verified before the online loop uses them.

A backend's "optimal" is a claim, not a fact (campaign problem 0-19: a projection 0.55 outside
Θ_1 was recorded as optimal). Every answer of the three online problems is checked here, with
numpy only, against the original rows of the problem it claims to solve:

* :func:`check_projection` — (12): the point lies in the target set S (Θ, or Θ_k under
  Remark 7), is no farther from θ̃ than a known point of S, and satisfies the KKT conditions of
  the projection (θ̃ − θ̂ is a non-negative combination of the normals of the rows active at θ̂).
* :func:`check_set_update` — (9), its moving window (Remark 4) and (25) before the dilation: the
  returned offsets are nested, h <= h_{k−1} (Lemma 3, (10)); the multipliers Λ certify the outer bound Θ_{k−1} ∩ Δ_k ⊆ Θ_k row by row by LP duality
  ([H_θ]_i θ = λ_iᵀ H̃ θ <= λ_iᵀ h̃ <= h_i, with the residual of Λ H̃ = H_θ bounded on Θ0's box);
  and, when the backend returns the maximisers, each is feasible for the original rows and
  achieves its offset (so h is the support, not a loose bound). None of these uses θ*.
* :func:`check_tube` — (20): the returned (v, z, α, Λ) satisfy (15a)-(15d), α >= 0 and the
  terminal set; for the vertex form (no Λ), (5b) at the vertices of Θ_k.

Each check returns :class:`AnswerCheck` rows; :func:`describe_failures` turns the failed ones into
the text recorded in ``StepRecord.detail``. The controller (:mod:`amcp_drake.online.controller`) decides the
fallbacks (docs/decisions.md, "Verified solver answers"). The certificate re-checks the recorded
run independently (certificate.claims, certificate.tube); these checks run *before* an answer is used.
"""

from __future__ import annotations

import functools
from math import isfinite as _isfinite
from typing import NamedTuple

import numpy as np
from scipy.optimize import nnls

from amcp_drake.model.arrays import all_finite, same_bits
from amcp_drake.model.tolerances import (
    PROJECTION_ACTIVE_TOL,
    PROJECTION_CANDIDATE_RTOL,
    PROJECTION_KKT_RTOL,
    PROJECTION_MEMBERSHIP_TOL,
    SET_NESTED_TOL,
    SET_POINT_TOL,
    SET_TOL,
    TUBE_TOL,
)

# The gates' tolerances (model.tolerances, section "gates"): each is equal to, or an order below, the tolerance
# of the claim its answer feeds (model.claim_table.GATES), so an answer that passes is one the certificate
# accepts, and loosening a gate never loosens a claim. The tube's rows are gated at the claims' TUBE_TOL and the
# set update's dual outer bound at the Lemma 3 claims' SET_TOL.

# ufunc reductions called directly (``ndarray.max`` reaches the same reduction through a Python wrapper)
_max = np.maximum.reduce
_add_reduce = np.add.reduce
_and_reduce = np.logical_and.reduce
# Products of 1-D/2-D operands as ``a.dot(b)``: the BLAS call of ``@`` (the same bits) without the matmul
# ufunc's dispatch, and np.dot's routine without NumPy 2's Python-level dispatcher


class AnswerCheck(NamedTuple):
    """One check of one answer: ``value`` is the measured violation (<= ``tolerance`` passes);
    ``ran`` is False when the answer lacks what the check needs (recorded, never a pass).

    Immutable; a NamedTuple rather than a frozen dataclass because a dozen are made per step of the
    online loop (0.2 µs each instead of 0.55)."""

    name: str
    value: float
    tolerance: float
    ran: bool = True

    @property
    def passed(self) -> bool:
        return self.ran and _within(self.value, self.tolerance)

    def describe(self) -> str:
        if not self.ran:
            return f"{self.name}: not run"
        return f"{self.name} {self.value:.3g} > {self.tolerance:.0e}"


def _within(value: float, tolerance: float) -> bool:
    """The pass criterion of every check: a finite value no larger than the tolerance."""
    return _isfinite(value) and value <= tolerance


def failures(checks: list[AnswerCheck]) -> list[AnswerCheck]:
    """The checks that ran and failed (a check that did not run is not a failure: see ``ran``).

    Reads the fields (name, value, tolerance, ran) by index rather than through the ``passed``
    property (a dozen checks per step of the online loop); the criterion is :func:`_within`."""
    return [c for c in checks if c[3] and not _within(c[1], c[2])]


def describe_failures(problem: str, checks: list[AnswerCheck]) -> str:
    """Text for ``StepRecord.detail``: ``"<problem>: <check> <value> > <tol>; ..."``."""
    return f"{problem}: " + "; ".join(c.describe() for c in failures(checks))


def _finite_shape(name: str, array, shape: tuple[int, ...]) -> AnswerCheck:
    ok = _has_shape(array, shape) and all_finite(array)
    return AnswerCheck(_finite_name(name, shape), 0.0 if ok else float("inf"), 0.0)


@functools.lru_cache(maxsize=64)
def _finite_name(name: str, shape: tuple[int, ...]) -> str:
    """The name of a "finite, shape" check (formatted once per (name, shape))."""
    return f"{name} finite, shape {shape}"


def _has_shape(array, shape: tuple[int, ...]) -> bool:
    """``array is not None and np.shape(array) == shape``, without np.shape's dispatch for an ndarray."""
    if isinstance(array, np.ndarray):
        return array.shape == shape
    return array is not None and np.shape(array) == shape


def _unit(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norms = np.sqrt(_add_reduce(H * H, axis=1))
    if not _and_reduce(norms, axis=None):  # a zero row (rare): divided by 1 instead
        norms[norms == 0.0] = 1.0
    return H / norms[:, None], h / norms


# -- (12) ------------------------------------------------------------------------------------------
def check_projection(theta, point: np.ndarray, H: np.ndarray, h: np.ndarray,
                     candidates: tuple[np.ndarray, ...] = ()) -> list[AnswerCheck]:
    """Is ``theta`` = Π_S(point), S = {H θ <= h}? Membership, no worse than any candidate that is
    itself in S, and KKT (see the module docstring). Tolerances: PROJECTION_*."""
    point = np.asarray(point, float)
    shape = _finite_shape("projection", theta, point.shape)
    if not shape.passed:
        return [shape]
    theta = np.asarray(theta, float)
    Hn, hn = _unit(np.asarray(H, float), np.asarray(h, float))
    slack = hn - Hn @ theta
    checks = [shape, AnswerCheck("projection in set", float(max(0.0, -np.min(slack))), PROJECTION_MEMBERSHIP_TOL)]
    dist = float(np.linalg.norm(theta - point))
    best = [float(np.linalg.norm(c - point)) for c in candidates
            if c is not None and float(np.max(Hn @ c - hn)) <= 0.0]
    if best:
        ref = min(best)
        checks.append(AnswerCheck("projection no farther than a known point of the set",
                                  (dist - ref) / max(ref, 1.0), PROJECTION_CANDIDATE_RTOL))
    active = slack <= PROJECTION_ACTIVE_TOL
    gap = point - theta
    if np.any(active):
        _, residual = nnls(Hn[active].T, gap)
    else:
        residual = float(np.linalg.norm(gap))
    checks.append(AnswerCheck("projection KKT residual", float(residual) / max(dist, 1.0), PROJECTION_KKT_RTOL))
    return checks


# -- (9) / (7) / (25) ----------------------------------------------------------------------------
def check_set_update(h, Lambda, points, H_theta: np.ndarray, h_prev: np.ndarray, H_data: np.ndarray,
                     h_data: np.ndarray, theta_box: np.ndarray) -> list[AnswerCheck]:
    """Are the offsets ``h`` of LP (9) a valid, nested and tight outer bound of Θ_{k−1} ∩ Δ_k?

    ``Lambda`` (q, q + r): multipliers of (9); ``points`` (q, p) or None: maximisers per row;
    ``theta_box`` (p,): max |θ_j| over Θ0 ⊇ Θ_{k−1} (bounds the residual of Λ H̃ = H_θ).
    Rows of H_θ and H_data are unit rows (design.H_theta, controller._delta)."""
    return _set_update_rows(h, Lambda, points, H_theta, h_prev, H_data, h_data, theta_box, None)[0]


class SetUpdateCheck:
    """:func:`check_set_update` for the online loop: the same rows, names and values, with the
    parts that depend only on the answer (h, Λ, maximisers) and on Θ_{k−1} (H_θ, h_{k−1}) — the rows of h
    ("finite, shape" and the nesting (10)), the finiteness of Λ and max(Λ, 0), the finiteness of the
    maximisers and their miss of the offsets h — taken from the last call when those five arrays are
    unchanged to the bit (the same operations on the same operands give the same values). Once Θ_k has
    settled, the vertex update returns the same answer at most steps; the rows with Δ_k (the dual bound
    and the maximisers' feasibility) are computed at every call."""

    def __init__(self) -> None:
        #: ((h, h_prev, Λ, maximisers, H_θ) copies, their known parts) of the last call, or None
        self._last: tuple | None = None

    def check(self, h, Lambda, points, H_theta, h_prev, H_data, h_data, theta_box) -> list[AnswerCheck]:
        """As :func:`check_set_update`."""
        key = (h, h_prev, Lambda, points, H_theta)
        arrays = (type(h) is np.ndarray and type(h_prev) is np.ndarray and type(Lambda) is np.ndarray
                  and type(points) is np.ndarray and type(H_theta) is np.ndarray)
        last = self._last
        known = None
        if (arrays and last is not None and same_bits(last[0][0], h) and same_bits(last[0][1], h_prev)
                and same_bits(last[0][2], Lambda) and same_bits(last[0][3], points)
                and same_bits(last[0][4], H_theta)):
            known = last[1]
        checks, parts = _set_update_rows(h, Lambda, points, H_theta, h_prev, H_data, h_data, theta_box, known)
        if known is None:
            self._last = (tuple(a.copy() for a in key), parts) if arrays and parts is not None else None
        return checks


def _set_update_rows(h, Lambda, points, H_theta, h_prev, H_data, h_data, theta_box,
                     known: tuple | None) -> tuple[list[AnswerCheck], tuple | None]:
    """The rows of :func:`check_set_update`, and its parts that depend only on (h, h_prev, Λ, maximisers,
    H_θ): (the two rows of h, max(Λ, 0) or None, the maximisers' miss or None). ``known``: those parts
    from an earlier call with the same five arrays to the bit (:class:`SetUpdateCheck`), or None to
    compute them. Returns (rows, parts; None when h failed its "finite, shape" row)."""
    H_theta = np.asarray(H_theta, float)
    h_prev = np.asarray(h_prev, float)
    q, p = H_theta.shape
    H_tilde = np.concatenate([H_theta, np.asarray(H_data, float).reshape(-1, p)])
    h_tilde = np.concatenate([h_prev, np.asarray(h_data, float).reshape(-1)])
    if known is None:
        shape = _finite_shape("set update h", h, (q,))
        if not shape.passed:
            return [shape], None
        h = np.asarray(h, float)
        head = (shape, AnswerCheck("set update nested h <= h_prev (10)", float(_max(h - h_prev, axis=None)),
                                   SET_NESTED_TOL))
        lam = miss = None
    else:
        head, lam, miss = known  # lam: Λ was finite; miss: the maximisers were finite, of shape (q, p)
    checks = list(head)
    if not _has_shape(Lambda, (q, len(h_tilde))) or (lam is None and not all_finite(Lambda)):
        checks.append(AnswerCheck("set update outer bound (dual certificate)", float("nan"), SET_TOL, ran=False))
    else:
        if lam is None:
            lam = np.maximum(np.asarray(Lambda, float), 0.0)
        residual = H_theta - lam.dot(H_tilde)
        bound = lam.dot(h_tilde) + np.abs(residual).dot(np.asarray(theta_box, float))
        checks.append(AnswerCheck("set update outer bound (dual certificate)", float(_max(bound - h, axis=None)),
                                  SET_TOL))
    if points is None:
        checks.append(AnswerCheck("set update maximisers feasible and tight", float("nan"), SET_POINT_TOL, ran=False))
    elif miss is None and (not _has_shape(points, (q, p)) or not all_finite(points)):
        checks.append(AnswerCheck("set update maximisers feasible and tight", float("inf"), SET_POINT_TOL))
    else:
        pts = np.asarray(points, float)
        Ht_n, ht_n = _unit(H_tilde, h_tilde)
        infeasible = float(_max(pts.dot(Ht_n.T) - ht_n, axis=None))
        if miss is None:
            miss = float(_max(np.abs(_add_reduce(H_theta * pts, axis=1) - h), axis=None))
        checks.append(AnswerCheck("set update maximisers feasible and tight", max(infeasible, miss), SET_POINT_TOL))
    return checks, (head, lam, miss)


# -- (20) ------------------------------------------------------------------------------------------
def check_tube(sol, data, x: np.ndarray, h_theta: np.ndarray, H_theta: np.ndarray | None = None,
               theta_vertices: np.ndarray | None = None) -> list[AnswerCheck]:
    """Does the answer ``sol`` (MPCSolution) of the QP (20) satisfy its constraints?

    ``data``: the controller's TubeMPCData; ``h_theta``: (q,) or per-stage (N, q) offsets (26);
    ``H_theta``: Θ_k's rows when they differ from ``data.H_theta`` (exact update (7));
    ``theta_vertices``: vertices of Θ_k for (5b) at the vertices: the vertex form's check of (5b),
    and in the plain form a check beside (15c)-(15d) (which, each met to TUBE_TOL, bound (5b)
    only to about TUBE_TOL·(1 + ‖θ‖)).
    Rows (vertex form of (15a)/(15b)): x^j_l = z_l + α_l x^j, u^j_l = K x^j_l + v_l,
    (15a) F x^j_l + G u^j_l <= 1; (15b) H_x (x_k − z_0) <= α_0; (15c) Λ^j_l h_θ(l) + H_x d^j_l
    − α_{l+1} <= −w̄; (15d) H_x D^j_l = Λ^j_l H_θ, Λ >= 0; terminal H_T z_N + h_T α_N <= 1; α >= 0.
    """
    d = data
    N, n, m = int(d.N), d.A0.shape[0], d.B0.shape[1]
    checks = [_finite_shape("tube v", sol.v, (N, m)), _finite_shape("tube z", sol.z, (N + 1, n)),
              _finite_shape("tube alpha", sol.alpha, (N + 1,))]
    if not all(c.passed for c in checks):
        return checks
    v, z, alpha = (np.asarray(a, float) for a in (sol.v, sol.z, sol.alpha))
    H_x, Xv, K = np.asarray(d.H_x, float), np.asarray(d.X0_vertices, float), np.asarray(d.K, float)
    H_th = np.asarray(d.H_theta if H_theta is None else H_theta, float)
    h_st = np.asarray(h_theta, float)
    h_st = np.broadcast_to(h_st, (N, h_st.shape[-1]))
    X = z[:, None, :] + alpha[:, None, None] * Xv[None, :, :]           # (N+1, v, n) tube vertices
    U = X[:N] @ K.T + v[:, None, :]                                       # (N, v, m)
    checks.append(AnswerCheck("tube alpha >= 0", float(max(0.0, -np.min(alpha))), TUBE_TOL))
    checks.append(AnswerCheck("tube x_k in X_0|k (15b)", float(np.max(H_x @ (x - z[0]) - alpha[0])), TUBE_TOL))
    checks.append(AnswerCheck("tube constraints (15a)",
                              float(np.max(X[:N] @ np.asarray(d.F).T + U @ np.asarray(d.G).T - 1.0)), TUBE_TOL))
    checks.append(AnswerCheck("tube terminal set", float(np.max(np.asarray(d.H_T) @ z[N] + np.asarray(d.h_T) * alpha[N]
                                                                - 1.0)), TUBE_TOL))
    A, B = np.asarray(d.A, float), np.asarray(d.B, float)
    base = X[:N] @ np.asarray(d.A0).T + U @ np.asarray(d.B0).T           # (N, v, n): A0 x + B0 u
    D = np.einsum("pab,lvb->lvap", A, X[:N]) + np.einsum("pab,lvb->lvap", B, U)  # (N, v, n, p) regressors
    HD = np.einsum("ua,lvap->lvup", H_x, D)                                # (N, v, u, p)
    rhs = alpha[1:, None, None] - np.asarray(d.w_bar)[None, None, :]        # α_{l+1} − w̄
    lhs_fixed = np.einsum("ua,lva->lvu", H_x, base - z[1:, None, :])       # H_x d^j_l
    if sol.Lambda is not None:
        Lam = np.asarray(sol.Lambda, float)
        if Lam.shape != HD.shape[:3] + (H_th.shape[0],) or not np.all(np.isfinite(Lam)):
            checks.append(AnswerCheck(f"tube Lambda finite, shape {HD.shape[:3] + (H_th.shape[0],)}", float("inf"), 0.0))
            return checks
        checks.append(AnswerCheck("tube Lambda >= 0", float(max(0.0, -np.min(Lam))), TUBE_TOL))
        lam_h = np.einsum("lvuq,lq->lvu", Lam, h_st)
        checks.append(AnswerCheck("tube (15c)", float(np.max(lam_h + lhs_fixed - rhs)), TUBE_TOL))
        checks.append(AnswerCheck("tube (15d)", float(np.max(np.abs(HD - Lam @ H_th))), TUBE_TOL))
        if theta_vertices is None:  # per-stage sets (26) or no vertices: (15c)-(15d) are the checks
            return checks
    if theta_vertices is not None:
        worst = np.einsum("lvup,tp->lvut", HD, np.asarray(theta_vertices, float)).max(axis=3)
        checks.append(AnswerCheck("tube (5b) at the vertices of Θ_k", float(np.max(worst + lhs_fixed - rhs)),
                                  TUBE_TOL))
    else:
        checks.append(AnswerCheck("tube (5b) at the vertices of Θ_k", float("nan"), TUBE_TOL, ran=False))
    return checks


#: Most bytes of one block of the coefficients [H_x A_cl(θ^s) x^j]_i that :class:`TubeCheck` reduces over
#: the vertices x^j of X0: 16 MiB.
TUBE_CHUNK_BYTES = 16 * 2**20


class TubeCheck:
    """:func:`check_tube` with its rows preassembled: the same rows, check names and values
    (up to round-off), written once as matrices on y = [z (N+1)·n | α (N+1) | v N·m] and on
    w_l = [z_l | z_{l+1} | α_l | α_{l+1} | v_l | 1] from the controller's data (never from a backend's
    matrices, so the check stays independent of the solver's problem):

    * ``fixed`` (dense): −α <= 0; (15b) −H_x z_0 − α_0 <= −H_x x_k (its right side written per
      step); (15a) (F + G K)(z_l + α_l x^j) + G v_l <= 1, the largest over j taken exactly through the
      α_l term (α_l times the maximum of (F + GK) x^j over j for α_l >= 0, the minimum for α_l < 0), so
      that its rows number N·(rows of F), not N·v·(rows of F); terminal H_T z_N + h_T α_N <= 1. One
      matrix-vector product, one maximum per block (``reduceat``).
    * vertex form (no Λ), (5b) at (l, j, s): H_x(A_cl(θ^s)(z_l + α_l x^j) + B(θ^s) v_l − z_{l+1})
      − α_{l+1} <= −w̄ for every vertex x^j of X0 and θ^s of Θ_k, the largest over j taken exactly
      through the α_l term alone (its coefficient's maximum over j for α_l >= 0, minimum for α_l < 0).
      The coefficients on w_l do not depend on l: one (S·u, 2n + 3 + m) matrix and the two extremes,
      rebuilt only when the vertices of Θ_k change (compared to the bit); all N·S·u rows are one
      product W Cᵀ.
    * plain form (Λ): Λ >= 0; (15c) Λ^j_l h_θ(l) + H_x(A0 x^j_l + B0 u^j_l − z_{l+1}) − α_{l+1} <= −w̄
      and (15d) H_x D^j_l = Λ^j_l H_θ, their parts in (z, α, v) again one product with W each.
    """

    def __init__(self, data) -> None:
        self.data = d = data
        N, n, m = int(d.N), np.shape(d.A0)[0], np.shape(d.B0)[1]
        self.N, self.n, self.m = N, n, m
        self.H_x = np.asarray(d.H_x, float)
        self.Xv = np.asarray(d.X0_vertices, float)
        K, F, G = np.asarray(d.K, float), np.asarray(d.F, float), np.asarray(d.G, float)
        H_T, h_T = np.asarray(d.H_T, float), np.asarray(d.h_T, float).reshape(-1)
        self.K = K
        self.a0, self.v0 = (N + 1) * n, (N + 1) * n + N + 1
        size = self.v0 + N * m
        u, nv, c, r = self.H_x.shape[0], len(self.Xv), F.shape[0], H_T.shape[0]
        a0, v0 = self.a0, self.v0
        alpha_rows = np.zeros((N + 1, size))
        alpha_rows[:, a0:v0] = -np.eye(N + 1)
        rows15b = np.zeros((u, size))
        rows15b[:, :n] = -self.H_x
        rows15b[:, a0] = -1.0
        FK = F + G @ K
        # (15a) at (l, j): the rows without their α_l term, one per (l, constraint row); the largest over
        # the vertices x^j adds α_l times the extreme of (F + GK) x^j over j (max for α_l >= 0, min below)
        rows15a = np.zeros((N, c, size))
        for l in range(N):
            rows15a[l, :, l * n:(l + 1) * n] = FK
            rows15a[l, :, v0 + l * m:v0 + (l + 1) * m] = G
        FX = self.Xv @ FK.T if nv else np.zeros((1, c))
        self._f_hi, self._f_lo = np.max(FX, axis=0), np.min(FX, axis=0)  # (c,)
        rowsT = np.zeros((r, size))
        rowsT[:, N * n:(N + 1) * n] = H_T
        rowsT[:, a0 + N] = h_T
        self.fixed = np.vstack([alpha_rows, rows15b, rows15a.reshape(N * c, size), rowsT])
        self.b = np.concatenate([np.zeros(N + 1), np.zeros(u), np.ones(N * c), np.ones(r)])
        self._b15b = self.b[N + 1:N + 1 + u]                          # a view: −H_x x_k, written per step
        self.starts = np.array([0, N + 1, N + 1 + u, N + 1 + u + N * c])
        self.Acl0 = np.asarray(d.A0, float) + np.asarray(d.B0, float) @ K
        self.Acl = np.asarray(d.A, float) + np.asarray(d.B, float) @ K  # (p, n, n)
        self.B0, self.B = np.asarray(d.B0, float), np.asarray(d.B, float)
        self.w_bar = np.asarray(d.w_bar, float)
        self._vertices = None
        self._Ct = np.zeros((2 * n + 3 + m, 0))
        self._tube_values = np.zeros((N, 0))  # W C written per check (its width follows Θ_k's vertex count)
        self._w = np.ones((N, 2 * n + 3 + m))  # w_l = [z_l | z_{l+1} | α_l | α_{l+1} | v_l | 1]
        # w gathered from [y | 1] by one np.take (the same copies as writing its five column blocks)
        one = size
        self._w_index = np.array([np.concatenate([np.arange(l * n, (l + 2) * n), [a0 + l, a0 + l + 1],
                                                  np.arange(v0 + l * m, v0 + (l + 1) * m), [one]])
                                  for l in range(N)], dtype=np.intp)
        self._y1 = np.ones(size + 1)     # [y | 1], written per check
        self._one = np.ones(1)
        self._rows = np.empty(len(self.b))  # fixed @ y − b, written per check
        self._minus_H_x = -self.H_x      # −H_x x_k = H_x (−x_k) bit for bit (negation is exact)
        self._shapes = ((N, m), (N + 1, n), (N + 1,))
        # the three "finite, shape" rows of an answer that has them (immutable: the same objects every step)
        self._finite_rows = tuple(AnswerCheck(_finite_name(name, shape), 0.0, 0.0)
                                  for name, shape in zip(("tube v", "tube z", "tube alpha"), self._shapes))
        self._plain_rows: tuple[np.ndarray, np.ndarray] | None = None  # (15c), (15d) on w_l, on first need

    def _lambda_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """The parts of (15c) (v·u rows, with +w̄ on the constant column) and of (15d) (v·u·p rows:
        H_x D^j_l, column p of D = (A_p + B_p K) x^j_l + B_p v_l) in w_l, transposed for W @ ·."""
        n, m, u, nv = self.n, self.m, self.H_x.shape[0], len(self.Xv)
        p, width = self.Acl.shape[0], 2 * n + 3 + m
        HA0, HB0 = self.H_x @ self.Acl0, self.H_x @ self.B0
        C = np.zeros((nv, u, width))
        C[..., :n] = HA0
        C[..., n:2 * n] = -self.H_x
        C[..., 2 * n] = self.Xv @ HA0.T                                      # H_x A_cl0 x^j
        C[..., 2 * n + 1] = -1.0
        C[..., 2 * n + 2:2 * n + 2 + m] = HB0
        C[..., -1] = self.w_bar
        HA = np.einsum("ua,pab->upb", self.H_x, self.Acl)                    # (u, p, n): H_x A_cl,p
        D = np.zeros((nv, u, p, width))
        D[..., :n] = HA
        D[..., 2 * n] = np.einsum("upb,jb->jup", HA, self.Xv)
        D[..., 2 * n + 2:2 * n + 2 + m] = np.einsum("ua,pab->upb", self.H_x, self.B)
        return C.reshape(nv * u, width).T.copy(), D.reshape(nv * u * p, width).T.copy()

    def _tube_rows(self, theta_vertices: np.ndarray) -> None:
        """Cᵀ (2n + 3 + m, S·u) for the rows (5b) at Θ_k's vertices θ^s without their α_l term, the
        right side −w̄ moved to the last row, and the extremes over the vertices x^j of X0 of the α_l
        coefficient [H_x A_cl(θ^s) x^j]_i: the largest over j of row (j, s, i) is the row without that
        term plus α_l times the maximum (α_l >= 0) or the minimum (α_l < 0), so the rows are never formed
        for every j (v·S·u rows: 5.7 million at 3,975 vertices of X0, 8 of Θ and 178 facets)."""
        T = np.asarray(theta_vertices, float)
        n, m, u, S = self.n, self.m, self.H_x.shape[0], len(T)
        HA = self.H_x @ (self.Acl0 + np.tensordot(T, self.Acl, axes=1))   # (S, u, n)
        HB = self.H_x @ (self.B0 + np.tensordot(T, self.B, axes=1))        # (S, u, m)
        C = np.zeros((S, u, 2 * n + 2 + m))
        C[..., :n] = HA
        C[..., n:2 * n] = -self.H_x
        C[..., 2 * n + 1] = -1.0
        C[..., 2 * n + 2:] = HB
        # the last row (on w's constant column 1) moves the right side −w̄ to the left: rows <= 0
        self._Ct = np.vstack([C.reshape(-1, 2 * n + 2 + m).T, np.tile(self.w_bar, S)[None, :]])
        hi, lo = np.full(S * u, -np.inf), np.full(S * u, np.inf)
        flat = HA.reshape(S * u, n)
        step = max(1, TUBE_CHUNK_BYTES // (8 * S * u))
        for start in range(0, len(self.Xv), step):                         # H_x A_cl(θ^s) x^j, in chunks of j
            coef = self.Xv[start:start + step] @ flat.T                      # (chunk, S·u)
            np.maximum(hi, np.max(coef, axis=0), out=hi)
            np.minimum(lo, np.min(coef, axis=0), out=lo)
        self._alpha_hi, self._alpha_lo = hi, lo

    def check(self, sol, x: np.ndarray, theta_vertices: np.ndarray | None = None, h_theta=None,
              H_theta: np.ndarray | None = None) -> list[AnswerCheck]:
        """The checks of :func:`check_tube` for ``sol`` at x_k. With Λ (plain form): ``h_theta`` (q,)
        or per stage (N, q) and ``H_theta`` (None: the data's), and (5b) at ``theta_vertices`` when
        they are given; without Λ (vertex form): (5b) at the vertices of Θ_k (None: "not run")."""
        v, z, alpha = sol.v, sol.z, sol.alpha
        shapes = self._shapes
        y = None
        if _has_shape(v, shapes[0]) and _has_shape(z, shapes[1]) and _has_shape(alpha, shapes[2]):
            z, alpha, v = np.asarray(z, float), np.asarray(alpha, float), np.asarray(v, float)
            y1 = np.concatenate([z.reshape(-1), alpha, v.reshape(-1), self._one], out=self._y1)  # [y | 1]
            y = y1[:-1]
        if y is None or not all_finite(y):
            return [_finite_shape("tube v", sol.v, shapes[0]), _finite_shape("tube z", sol.z, shapes[1]),
                    _finite_shape("tube alpha", sol.alpha, shapes[2])]
        checks = list(self._finite_rows)
        self._minus_H_x.dot(np.asarray(x, float), out=self._b15b)
        rows = np.subtract(self.fixed.dot(y, out=self._rows), self.b, out=self._rows)
        a_N = alpha[:self.N, None]                                           # α_l of (15a), l < N
        rows[self.starts[2]:self.starts[3]] += np.where(a_N >= 0, a_N * self._f_hi, a_N * self._f_lo).reshape(-1)
        worst = np.maximum.reduceat(rows, self.starts).tolist()
        checks += [AnswerCheck("tube alpha >= 0", max(0.0, worst[0]), TUBE_TOL),
                   AnswerCheck("tube x_k in X_0|k (15b)", worst[1], TUBE_TOL),
                   AnswerCheck("tube constraints (15a)", worst[2], TUBE_TOL),
                   AnswerCheck("tube terminal set", worst[3], TUBE_TOL)]
        # w_l = [z_l | z_{l+1} | α_l | α_{l+1} | v_l | 1] (the indices are valid: "clip" only skips a buffer)
        w = y1.take(self._w_index, out=self._w, mode="clip")
        if sol.Lambda is not None:
            Lam = np.asarray(sol.Lambda, float)
            malformed = self._malformed_lambda(Lam, H_theta)
            if malformed is not None:  # as check_tube: nothing else is checked on such an answer
                return checks + [malformed]
            checks += self._lambda_checks(Lam, h_theta, H_theta)
            if theta_vertices is None or len(theta_vertices) == 0:  # per-stage sets (26): (15c)-(15d) only
                return checks
        elif theta_vertices is None or len(theta_vertices) == 0:
            checks.append(AnswerCheck("tube (5b) at the vertices of Θ_k", float("nan"), TUBE_TOL, ran=False))
            return checks
        if self._vertices is None or not same_bits(self._vertices, np.asarray(theta_vertices, float)):
            self._tube_rows(theta_vertices)
            self._vertices = np.array(theta_vertices, float)
            self._tube_values = np.empty((self.N, self._Ct.shape[1]))
        tube = w.dot(self._Ct, out=self._tube_values)
        a_l = w[:, 2 * self.n:2 * self.n + 1]                                # α_l, (N, 1)
        tube += np.where(a_l >= 0, a_l * self._alpha_hi, a_l * self._alpha_lo)
        checks.append(AnswerCheck("tube (5b) at the vertices of Θ_k", float(_max(tube, axis=None)), TUBE_TOL))
        return checks

    def _malformed_lambda(self, Lam: np.ndarray, H_theta) -> AnswerCheck | None:
        """The failed check of a Λ that is not finite or not of shape (N, v, u, q), else None."""
        q = np.shape(self.data.H_theta if H_theta is None else H_theta)[0]
        shape = (self.N, len(self.Xv), self.H_x.shape[0], q)
        if Lam.shape != shape or not np.isfinite(Lam).all():
            return AnswerCheck(f"tube Lambda finite, shape {shape}", float("inf"), 0.0)
        return None

    def _lambda_checks(self, Lam: np.ndarray, h_theta, H_theta) -> list[AnswerCheck]:
        """Λ >= 0, (15c) and (15d) of the plain form, as in :func:`check_tube` (Λ well formed)."""
        N, u, nv = self.N, self.H_x.shape[0], len(self.Xv)
        H_th = np.asarray(self.data.H_theta if H_theta is None else H_theta, float)
        q = H_th.shape[0]
        if self._plain_rows is None:
            self._plain_rows = self._lambda_rows()
        C15c, C15d = self._plain_rows
        h_st = np.broadcast_to(np.asarray(h_theta, float), (N, q))
        lam_h = (Lam.reshape(N, nv * u, q) @ h_st[:, :, None])[..., 0]      # (N, v·u): Λ^j_l h_θ(l)
        w = self._w
        hd = (w @ C15d).reshape(N, nv, u, -1)                                # H_x D^j_l
        return [AnswerCheck("tube Lambda >= 0", max(0.0, -float(Lam.min())), TUBE_TOL),
                AnswerCheck("tube (15c)", float((w @ C15c + lam_h).max()), TUBE_TOL),
                AnswerCheck("tube (15d)", float(np.abs(hd - Lam @ H_th).max()), TUBE_TOL)]
