"""The tube MPC QP (20) in cvxpy: constraints (15a)-(15d), terminal set, cost (17)-(18).

One DPP problem is built per controller (and rebuilt only when the number of rows of H_θk
changes). Parameters, set at every step:

* ``x_k`` (n,): the measured state, in (15b) and x̂_0 = x_k of (18);
* ``h_theta`` (N, q), ``H_theta`` (q, p): Θ_k of (15c)-(15d); row l of ``h_theta`` is the offset
  used at stage l (all rows equal to h_θk, or the predicted sets (26) of Section 4.1);
* ``u0_lo``, ``u0_hi`` (m,): only in the variant built with ``u0_bounds=True`` (PE, docs/explanation/paper.md §8);
* ``A_cl_hat`` = A(θ̂_k) + B(θ̂_k) K (n, n), ``B_hat`` = B(θ̂_k) (n, m): the dynamics (18).

The nominal trajectory x̂ of (18) is kept as a variable with equality constraints (the Drake
backend condenses it into a quadratic in v instead), so the two backends cross-check the cost.
The tube constraints are written per prediction step l, vectorised over the vertices x^j of X0
by the vertex matrix X_l = [x^1_l, ..., x^v_l] = z_l 1ᵀ + α_l [x^1, ..., x^v] (n, v).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import cvxpy as cp
import numpy as np

from amcp_drake.backends.base import Attempt, MPCSolution, TubeMPCData, backend_attempts
from amcp_drake.backends.clarabel_retry import RETRIED, first_try, solve_with_retries
from amcp_drake.backends.minmax_cost import minmax_plan_cost
from amcp_drake.model.status import SolveStatus

from .nominal_cost import certainty_equivalence_cost, nominal_cost
from .offline import sqrtm_psd
from .solver_call import SolverCall, clarabel_defaults

#: Constraint groups, named as in the Drake backend so that reports read the same.
GROUP_15A = "(15a) state and input constraints"
GROUP_15B = "(15b) x_k in X_0|k"
GROUP_15C = "(15c) tube propagation with multipliers"
GROUP_15D = "(15d) H_x D = Lambda H_theta"
GROUP_TERMINAL = "terminal set (z_N, alpha_N) in Xf"
GROUPS = (GROUP_15A, GROUP_15B, GROUP_15C, GROUP_15D, GROUP_TERMINAL)

#: A group of the elastic (diagnostic) problem is reported as violated when its slack exceeds
#: this; Clarabel's default feasibility tolerance is 1e-8, so 1e-6 is well above round-off.
ELASTIC_SLACK_TOL = 1e-6
#: Stand-in for an infinite side of ``u0_bounds`` (cvxpy parameters must be finite).
U0_INF = 1e6
#: A new number of rows of H_θk (the exact update (7) changes it at most steps) needs a new problem
#: (formulate + canonicalisation: 0.35-0.57 s on campaign seed 13 #6 against ~25 ms per solve). The
#: problem built for a new number q holds the next multiple of this many rows; fewer rows are padded
#: (CvxpyTubeMPC._padded), and it is built again only for more rows than it holds or at least twice
#: this many fewer. The first problem holds exactly the design's rows (the updates (9) and the window
#: never change H_θ, so they are not affected).
ROW_CAPACITY_STEP = 8
#: Clarabel settings of the plain form (the user's options override them): its KKT systems factorised
#: by faer's supernodal LDLᵀ instead of QDLDL, on one thread (faer's default takes every core; the
#: machine is shared and CPU time is measured per thread). The program and the tolerances are the same.
#: Why: on a thin Θ_k the rows (15c) and (15d) of one multiplier row are nearly dependent (for a slab of
#: width w they share the two multipliers through [[1, −1], [w/2, w/2]], smaller singular value w/√2),
#: and this form keeps all 3 360 of them on massera2017 (every row of (15c), every multiplier, (15d) as
#: equalities); late in the iterations (μ ~ 1e-10) QDLDL's solves were too inaccurate for iterative
#: refinement, the step length fell to 0 and Clarabel ended "AlmostSolved" (gap 4.1e-8) under the whole
#: retry ladder. massera2017, θ* = −1, 984 QPs (benchmarks/massera_plain_qps.py): unanswered 1 -> 0,
#: first tries needing a retry 50 -> 6; CPU per closed-loop step +3-5 % (Example 1) to +6-15 %
#: (massera2017). docs/decisions.md, "The cvxpy plain form's unanswered QPs on massera2017".
PLAIN_FORM_CLARABEL_OPTIONS = {"direct_solve_method": "faer", "max_threads": 1}
#: The optimality check of the plain form's answer (:meth:`CvxpyTubeMPC._checked_optimal`):
#: its cost may exceed the vertex form's optimum of the same step by at most this many times the gap
#: tolerance in effect (tol_gap_abs + tol_gap_rel·|cost|, for the errors of both solves). Why: on a
#: generated problem (thorough profile; n = 1, p = 2, exact update (7), a Θ_k slab 1.3e-6 wide,
#: x_k = −0.023) Clarabel ended "Solved" at 1e-10 with a cost 8.2e-9 above the optimum (v 1.3e-4
#: off): the feasibility tolerance is relative to the largest variables, and in this form α_N (23.7)
#: and Λ (up to 129) are large and not unique (the cost depends on v only).
OPTIMALITY_SLACK = 10.0
#: The re-solve of an answer that fails that check: Clarabel's feasibility tolerance this many times
#: the one in effect (tighter), the gap tolerances unchanged. On the case above 1e-12 gave v to 8e-10.
TIGHTER_FEASIBILITY = 1e-2
#: Weight ε of the tie-break term ε·Σ_l α_l added to the certainty-equivalence cost (17) for one more
#: solve when the plain form ends without an answer under the whole retry ladder
#: (:meth:`CvxpyTubeMPC._tie_broken`). Why: (17) depends on v only, so the optimal (z, α, Λ) of a step is
#: a whole face, and Λ on it is unbounded in the directions that (15d) leaves free (for a box Θ_k of width w,
#: Λ_i and Λ_{i+p} grow together until Λ s reaches the row's slack, s ~ w/2); Clarabel's iterates head for
#: the middle of that face, and on mass_chain3 (n = 6, 64-vertex X0, 30 989 variables, Θ_k 0.02 x 0.009)
#: the step length collapsed at a gap of 1.2e-6 under every rung of the ladder and with every other
#: setting tried (QDLDL, equilibration to 1e-8/1e8, 50 equilibration passes, smaller dynamic
#: regularisation, shorter steps). With ε·Σα the smallest tube is preferred and the step is "Solved":
#: ε = 1e-9, 1e-8, 1e-7 all solved it with v equal to the vertex form's optimum to 1e-8. The term moves the
#: optimum of (17) by at most ε·Σα of the optimal plan (~1e-9 here, below Clarabel's 1e-8 gap tolerance),
#: and the answer is accepted only when its cost (17), without the term, passes the vertex form's optimality
#: check (:meth:`CvxpyTubeMPC._checked_optimal`); the program whose constraints are checked is (20) itself.
TIE_BREAK_WEIGHT = 1e-9
#: Offset of a padded row 0·θ <= PAD_OFFSET: any positive value leaves the program the same; 1 is the
#: scale of the unit rows.
PAD_OFFSET = 1.0


@dataclass
class _Formulation:
    """Variables, parameters and constraint groups of one built problem."""

    problem: cp.Problem
    params: dict[str, cp.Parameter]
    z: cp.Variable
    alpha: cp.Variable
    v: cp.Variable
    Lambda: list[cp.Variable]
    groups: dict[str, list[cp.Constraint]] = field(default_factory=dict)
    slacks: dict[str, cp.Variable] = field(default_factory=dict)


def relaxed_groups(call, elastic: Callable[[], Any], groups: tuple[str, ...]) -> tuple[str, ...]:
    """Constraint groups whose slack in the elastic problem (``elastic()`` builds it and sets its
    parameters; it has ``problem`` and ``slacks``) exceeds :data:`ELASTIC_SLACK_TOL`: a diagnostic
    for an infeasible step of either formulation. Empty when the diagnostic itself fails: it must
    never hide the status of (20)."""
    try:
        form = elastic()
        status, _, _ = call.solve(form.problem)
    except Exception:  # noqa: BLE001 - diagnostics only
        return ()
    if status is not SolveStatus.OPTIMAL:
        return ()
    return tuple(g for g in groups if float(form.slacks[g].value) > ELASTIC_SLACK_TOL)


def offset_split(H_theta: np.ndarray, h_stages: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(κ, s) with h_l = H_θ κ_l + s_l per stage row l of ``h_stages`` (N, q): κ_l the least-squares
    point of H_θ κ ≈ h_l, s_l = h_l − H_θ κ_l its residual (orthogonal to the columns of H_θ).

    Why (15c) is written with c κ_l + Λ s_l instead of Λ h_θk: on the feasible set of (15d),
    Λ h_θk = Λ H_θ κ_l + Λ s_l = c κ_l + Λ s_l for any κ_l, so the program is the same. But on a thin
    Θ_k, h_θk is nearly in the range of H_θ (all of s_l is of the order of Θ_k's width), so the
    multiplier coefficients of a (15c) row, h_θk, nearly equal a combination of those of the (15d) rows,
    H_θ: on massera2017 with θ* = −1 (Θ_k = [−1, −1 + 1e-6], H_θ = [1; −1]) the row (−1 + 1e-6, 1)
    against (1, −1), and Clarabel stalled "AlmostSolved" (gap 1.06e-8) at steps the Drake plain form,
    which eliminates (15d) (multiplier_basis: the same κ, s for a basis point), solved. With the
    residual s_l the nearly dependent part is gone. For a slab of width w, κ is its mid-plane and
    s = (w/2, w/2)."""
    H = np.asarray(H_theta, float)
    h = np.asarray(h_stages, float)
    kappa = np.linalg.lstsq(H, h.T, rcond=None)[0].T    # (N, p)
    return kappa, h - kappa @ H.T


def _row(vec: np.ndarray) -> np.ndarray:
    return np.asarray(vec, float).reshape(1, -1)


def _col(vec: np.ndarray) -> np.ndarray:
    return np.asarray(vec, float).reshape(-1, 1)


def formulate(data: TubeMPCData, q: int, elastic: bool = False, u0_bounds: bool = False) -> _Formulation:
    """Build the QP (20) for H_θ with q rows.

    With ``elastic=True`` every constraint group g gets a scalar slack s_g >= 0 on its right-hand
    side (|lhs − rhs| <= s_g for the equalities (15d)) and the objective is Σ_g s_g: this
    problem is always feasible, and the groups with positive slack are those that cannot hold
    together (a diagnostic for infeasible steps).
    """
    A0, B0 = np.asarray(data.A0, float), np.asarray(data.B0, float)
    A, B = np.asarray(data.A, float), np.asarray(data.B, float)
    F, G, K = np.asarray(data.F, float), np.asarray(data.G, float), np.asarray(data.K, float)
    H_x, Xv = np.asarray(data.H_x, float), np.asarray(data.X0_vertices, float)
    w_bar, f_bar = np.asarray(data.w_bar, float), np.asarray(data.f_bar, float)
    H_T, h_T = np.asarray(data.H_T, float), np.asarray(data.h_T, float)
    n, m = B0.shape
    p = A.shape[0]
    N = int(data.N)
    nv, u = Xv.shape[0], H_x.shape[0]

    params = {
        "x_k": cp.Parameter(n, name="x_k"),
        "h_theta": cp.Parameter((N, q), name="h_theta"),
        "H_theta": cp.Parameter((q, p), name="H_theta"),
        # h_θ split as H_θ κ_l + s_l (offset_split): (15c) is written with c κ_l + Λ s_l (see below)
        "kappa": cp.Parameter((N, p), name="kappa"),
        "s_theta": cp.Parameter((N, q), name="s_theta"),
    }
    z = cp.Variable((n, N + 1), name="z")          # column l: tube centre z_l|k
    alpha = cp.Variable(N + 1, nonneg=True, name="alpha")  # α_l|k >= 0
    v = cp.Variable((m, N), name="v")               # column l: v_l|k
    # Λ^j_l for all j stacked: rows (j, i) j-major, i.e. row j·u + i is row i of Λ^j_l
    Lam = [cp.Variable((nv * u, q), nonneg=True, name=f"Lambda_{l}") for l in range(N)]
    slacks = {g: cp.Variable(nonneg=True, name=f"slack {g}") for g in GROUPS} if elastic else {}

    def s(group: str):
        return slacks[group] if elastic else 0.0

    groups: dict[str, list[cp.Constraint]] = {g: [] for g in GROUPS}
    ones_v = np.ones((1, nv))
    FGK = F + G @ K

    # (15a): (F + G K) z_l + G v_l + α_l f̄ <= 1, l = 0..N-1 (all l at once, columns)
    alpha_row = cp.reshape(alpha[:N], (1, N), order="F")
    groups[GROUP_15A].append(FGK @ z[:, :N] + G @ v + _col(f_bar) @ alpha_row <= 1.0 + s(GROUP_15A))

    # (15b): −H_x z_0 − α_0 1 <= −H_x x_k
    groups[GROUP_15B].append(-H_x @ z[:, 0] - alpha[0] <= -H_x @ params["x_k"] + s(GROUP_15B))

    for l in range(N):
        # vertices of X_l|k (14): x^j_l = z_l + α_l x^j, inputs u^j_l = K x^j_l + v_l
        X_l = cp.reshape(z[:, l], (n, 1), order="F") @ ones_v + alpha[l] * Xv.T   # (n, nv)
        U_l = K @ X_l + cp.reshape(v[:, l], (m, 1), order="F") @ ones_v              # (m, nv)
        # d^j_l = A0 x^j_l + B0 u^j_l − z_{l+1}
        d_l = A0 @ X_l + B0 @ U_l - cp.reshape(z[:, l + 1], (n, 1), order="F") @ ones_v
        # (15d): H_x D^j_l = Λ^j_l H_θk; column i' of D^j_l is A_i' x^j_l + B_i' u^j_l
        lam_H = Lam[l] @ params["H_theta"]  # (nv·u, p)
        c_l = [H_x @ (A[ip] @ X_l + B[ip] @ U_l) for ip in range(p)]     # c_l[i'] (u, nv): entry (i, j)
        for ip in range(p):
            rhs = cp.reshape(lam_H[:, ip], (u, nv), order="F")               # (u, nv): Λ^j_l[i] H_θ[:, i']
            if elastic:
                groups[GROUP_15D].append(cp.abs(c_l[ip] - rhs) <= s(GROUP_15D))
            else:
                groups[GROUP_15D].append(c_l[ip] == rhs)
        # column j of this (u, nv) matrix is Λ^j_l h_θk. Without the elastic slacks it is written as
        # c κ_l + Λ^j_l s_l (h_θk = H_θ κ_l + s_l, (15d): Λ H_θ = c), the same value on the feasible set;
        # Λ h_θk itself made the (15c) and (15d) rows nearly dependent on a thin Θ_k (see offset_split)
        if elastic:
            lam_h = cp.reshape(Lam[l] @ params["h_theta"][l], (u, nv), order="F")
        else:
            lam_h = (cp.reshape(Lam[l] @ params["s_theta"][l], (u, nv), order="F")
                     + sum(params["kappa"][l, ip] * c_l[ip] for ip in range(p)))
        # (15c): Λ^j_l h_θk + H_x d^j_l − α_{l+1} 1 <= −w̄, for all j (columns)
        groups[GROUP_15C].append(lam_h + H_x @ d_l - np.ones((u, 1)) @ cp.reshape(alpha[l + 1], (1, 1), order="F")
                                 <= -_col(w_bar) @ ones_v + s(GROUP_15C))

    # terminal set X_f: H_T z_N + h_T α_N <= 1 (α_N >= 0 is the variable's domain)
    groups[GROUP_TERMINAL].append(H_T @ z[:, N] + alpha[N] * h_T <= 1.0 + s(GROUP_TERMINAL))

    constraints = [con for g in GROUPS for con in groups[g]]
    if u0_bounds:
        # PE two-QP procedure (docs/explanation/paper.md §8): u0_lo <= K x_k + v_0|k <= u0_hi
        params["u0_lo"] = cp.Parameter(m, name="u0_lo")
        params["u0_hi"] = cp.Parameter(m, name="u0_hi")
        u0 = K @ params["x_k"] + v[:, 0]
        constraints += [u0 >= params["u0_lo"], u0 <= params["u0_hi"]]
    if elastic:
        objective = cp.Minimize(cp.sum(cp.hstack(list(slacks.values()))))
    elif data.minmax:
        # min-max cost (19), epigraph form as in the Drake backend: s_l >= ‖(Q^½ x^j_l, R^½ u^j_l)‖ for
        # every vertex j (l < N), s_N >= ‖P^½ x^j_N‖, minimise Σ s_l² (second-order cones, not
        # t_l >= ‖·‖², whose rotated-cone form loses the slack to cancellation when the cost is small);
        # vectorised over the vertex columns of X_l = z_l 1ᵀ + α_l [x^1 … x^v]
        Qh, Rh, Ph = (sqrtm_psd(np.asarray(M, float)) for M in (data.Q, data.R, data.P))
        s_epi = cp.Variable(N + 1, name="s")
        for l in range(N + 1):
            X_l = cp.reshape(z[:, l], (n, 1), order="F") @ ones_v + alpha[l] * Xv.T
            if l < N:
                U_l = K @ X_l + cp.reshape(v[:, l], (m, 1), order="F") @ ones_v
                body = cp.vstack([Qh @ X_l, Rh @ U_l])
            else:
                body = Ph @ X_l
            constraints.append(cp.norm(body, 2, axis=0) <= s_epi[l])
        objective = cp.Minimize(cp.sum_squares(s_epi))
    else:
        # (17), plus the tie-break ε·Σα whose weight is 0 except in CvxpyTubeMPC._tie_broken (the same
        # program otherwise: a zero linear term)
        params["alpha_weight"] = cp.Parameter(nonneg=True, name="alpha_weight", value=0.0)
        objective = certainty_equivalence_cost(data, params, v, constraints)
        objective = cp.Minimize(objective.args[0] + params["alpha_weight"] * cp.sum(alpha))
    problem = cp.Problem(objective, constraints)
    return _Formulation(problem, params, z, alpha, v, Lam, groups, slacks)


class CvxpyTubeMPC:
    """QP (20) built once; :meth:`solve` sets x_k, Θ_k, θ̂_k and re-solves the same problem."""

    def __init__(self, data: TubeMPCData, call, vertex_check=None) -> None:
        """``call``: the backend's ``SolverCall``; with Clarabel, a copy with
        :data:`PLAIN_FORM_CLARABEL_OPTIONS` under the user's options is used. ``vertex_check``: the
        vertex form of (20) on the same data (``CvxpyVertexTubeMPC``, built by the backend, which
        imports both forms) that checks the optimality of each certainty-equivalence answer
        (:meth:`_checked_optimal`); None: no check."""
        self.data = data
        self._vertex_check = vertex_check if call.name == "CLARABEL" and not data.minmax else None
        # the gap and feasibility tolerances in effect (Clarabel's defaults under the user's options)
        settings = {**clarabel_defaults(), **call.options} if call.name == "CLARABEL" else {}
        self._tolerances = {k: float(settings[k]) for k in ("tol_gap_abs", "tol_gap_rel", "tol_feas") if k in settings}
        if call.name == "CLARABEL":
            call = SolverCall(call.name, {**PLAIN_FORM_CLARABEL_OPTIONS, **call.options}, keep_solver=call.keep_solver)
        self._call = call
        self._elastic: _Formulation | None = None
        self._build(np.asarray(data.H_theta, float))

    def _build(self, H_theta: np.ndarray, capacity: int | None = None) -> None:
        """Formulate (20) for ``capacity`` rows of H_θ (default: its own number) and canonicalise it
        now (DPP), so the one-off cost of cvxpy's compilation is paid here and not inside the first
        solve. A H_θ with fewer rows than the capacity is padded (:meth:`_padded`)."""
        self.q = H_theta.shape[0]
        self.capacity = self.q if capacity is None else max(int(capacity), self.q)
        self.H_theta = H_theta
        self.form = formulate(self.data, self.capacity)
        self._elastic = None
        self._u0 = None
        n, p = self.data.B0.shape[0], self.data.A.shape[0]
        self._set_parameters(self.form, np.zeros(n), np.ones(self.q), np.zeros(p))
        try:
            self.form.problem.get_problem_data(self._call.name, enforce_dpp=True)
        except cp.error.SolverError:
            pass  # the solver cannot take this problem: ``solve`` reports it as a status

    @property
    def problem(self) -> cp.Problem:
        """The cvxpy problem (20) currently in use (DPP)."""
        return self.form.problem

    def _padded(self, h_stages: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(H_θ, h) with capacity − q rows 0·θ <= 1 appended (PAD_OFFSET). The program is the same in
        (z, α, v): a padded multiplier enters (15d) with coefficient 0 and (15c) with +1 (its s is 1),
        so Λ with the padded columns dropped satisfies (15c)-(15d) whenever the padded Λ does, and
        Λ_pad = 0 extends any feasible point; :meth:`solve` returns Λ without them."""
        pad = self.capacity - self.q
        if pad == 0:
            return self.H_theta, h_stages
        H = np.vstack([self.H_theta, np.zeros((pad, self.H_theta.shape[1]))])
        return H, np.hstack([h_stages, np.full((h_stages.shape[0], pad), PAD_OFFSET)])

    def _set_parameters(self, form: _Formulation, x, h_theta, theta_hat) -> None:
        d = self.data
        form.params["x_k"].value = x
        h_theta = np.asarray(h_theta, float)
        H, h_stages = self._padded(h_theta if h_theta.ndim == 2 else np.tile(h_theta, (int(d.N), 1)))
        form.params["h_theta"].value = h_stages
        form.params["H_theta"].value = H
        form.params["kappa"].value, form.params["s_theta"].value = offset_split(H, h_stages)
        if "A_cl_hat" in form.params and isinstance(form.params["A_cl_hat"], cp.Parameter):
            A_hat = d.A0 + np.tensordot(theta_hat, d.A, axes=1)
            B_hat = d.B0 + np.tensordot(theta_hat, d.B, axes=1)
            form.params["A_cl_hat"].value = A_hat + B_hat @ d.K
            form.params["B_hat"].value = B_hat

    #: ``solve(..., refine=True)`` is supported (the controller's first fallback for an answer that
    #: fails its checks, amcp_drake.online.controller).
    REFINES = True
    #: the formulation of (20) this program solves (the protocol's ``TubeMPCSolver.formulation``)
    formulation = "plain"

    def solve(self, x, h_theta, theta_hat, H_theta=None, u0_bounds=None, refine: bool = False) -> MPCSolution:
        """Solve (20) at x_k with Θ_k = {H_θ θ <= h_theta} and the point estimate θ̂_k.
        ``refine``: Clarabel with iterative refinement from the start (as in the Drake backend).

        ``h_theta`` may be (N, q): per-stage offsets of the predicted sets (26) (Section 4.1).
        ``u0_bounds`` = (lo, hi) adds lo <= K x_k + v_{0|k} <= hi (PE, docs/explanation/paper.md §8); finite bounds
        only on one side are allowed (the other ±inf), as in the Drake backend.

        ``H_theta`` replaces the shape of Θ_k: same number of rows -> parameter update only;
        a different number of rows -> the problem is rebuilt.
        """
        start = time.perf_counter()
        x = np.asarray(x, float).reshape(-1)
        h_theta = np.asarray(h_theta, float)
        if h_theta.ndim != 2:
            h_theta = h_theta.reshape(-1)
        theta_hat = np.asarray(theta_hat, float).reshape(-1)
        arrays = {"x": x, "h_theta": h_theta, "theta_hat": theta_hat}
        if H_theta is not None:
            arrays["H_theta"] = np.asarray(H_theta, float)
        for name, arr in arrays.items():
            if not np.all(np.isfinite(arr)):
                return MPCSolution(SolveStatus.ERROR, None, None, None, None, None, detail=f"non-finite {name}")
        n, p = self.data.B0.shape[0], self.data.A.shape[0]
        q = self.q if H_theta is None else (arrays["H_theta"].shape[0] if arrays["H_theta"].ndim == 2 else -1)
        expected = {"x": (n,), "h_theta": (q,) if h_theta.ndim == 1 else (int(self.data.N), q), "theta_hat": (p,)}
        if H_theta is not None:
            expected["H_theta"] = (q, p)
        for name, shape in expected.items():
            if arrays[name].shape != shape:
                return MPCSolution(SolveStatus.ERROR, None, None, None, None, None,
                                   detail=f"{name} has shape {arrays[name].shape}, expected {shape}")
        if H_theta is not None:
            if q > self.capacity or self.capacity - q >= 2 * ROW_CAPACITY_STEP:
                # more rows than the problem holds, or far fewer: a new problem, with room to grow
                self._build(arrays["H_theta"], ROW_CAPACITY_STEP * -(-q // ROW_CAPACITY_STEP))
            else:
                self.q, self.H_theta = q, arrays["H_theta"]  # parameter update only (padded rows)
        form = self.form
        if u0_bounds is not None:
            form = self._u0_form()
            m = self.data.B0.shape[1]
            lo, hi = (np.broadcast_to(np.asarray(b, float), (m,)).copy() for b in u0_bounds)
            # cvxpy parameters must be finite: an infinite side is replaced by a bound that the
            # input constraints of Z (or the horizon's feasibility) make inactive
            form.params["u0_lo"].value = np.where(np.isfinite(lo), lo, -U0_INF)
            form.params["u0_hi"].value = np.where(np.isfinite(hi), hi, U0_INF)
        self._set_parameters(form, x, h_theta, theta_hat)
        update_time = time.perf_counter() - start
        status, solver_time, detail, rungs = self._solve(form.problem, refine)
        checked = u0_bounds is None and h_theta.ndim == 1 and self._vertex_check is not None
        if status in RETRIED and checked and "alpha_weight" in form.params:
            sol = self._tie_broken(form, x, h_theta, theta_hat, H_theta, solver_time, update_time, detail)
            return replace(sol, attempts=backend_attempts(rungs, sol.status) + sol.attempts)
        if status is not SolveStatus.OPTIMAL:
            names = self._diagnose(x, h_theta, theta_hat) if status is SolveStatus.INFEASIBLE else ()
            return MPCSolution(status, None, None, None, None, None, solver_time, update_time, names, detail=detail,
                               attempts=backend_attempts(rungs, status))
        sol = replace(self._read(form, x, theta_hat), solver_time=solver_time, update_time=update_time, detail=detail)
        if checked:
            sol = self._checked_optimal(sol, form, x, h_theta, theta_hat, H_theta)
        return replace(sol, attempts=backend_attempts(rungs, sol.status) + sol.attempts)

    def _tie_broken(self, form: _Formulation, x, h_theta, theta_hat, H_theta, spent: float, update_time: float,
                    detail: str) -> MPCSolution:
        """The step solved once more with the tie-break ε·Σα (:data:`TIE_BREAK_WEIGHT`) after the retry ladder
        gave no answer (status of the last try in RETRIED): the answer is read as usual (its cost is (17) of
        its v, without the term) and kept only when :meth:`_checked_optimal` accepts it against the vertex
        form's optimum of the same step; otherwise, or when this solve ends without an answer too, the status
        is INACCURATE (the controller answers the step by the other formulation, checked)."""
        form.params["alpha_weight"].value = TIE_BREAK_WEIGHT
        try:
            status, elapsed, _ = self._call.solve(form.problem)
        finally:
            form.params["alpha_weight"].value = 0.0
        note = f"{detail}; re-solved with the tie-break {TIE_BREAK_WEIGHT:g}·Σα"
        if status is not SolveStatus.OPTIMAL:
            return MPCSolution(SolveStatus.INACCURATE, None, None, None, None, None, spent + elapsed, update_time,
                               detail=f"{note}: {status.value}",
                               attempts=(Attempt("tube_qp", "tie_break", SolveStatus.INACCURATE),))
        sol = replace(self._read(form, x, theta_hat), solver_time=spent + elapsed, update_time=update_time,
                      detail=note)
        sol = self._checked_optimal(sol, form, x, h_theta, theta_hat, H_theta)
        return replace(sol, attempts=(Attempt("tube_qp", "tie_break", sol.status), *sol.attempts))

    def _checked_optimal(self, sol: MPCSolution, form: _Formulation, x, h_theta, theta_hat, H_theta) -> MPCSolution:
        """``sol`` when its cost is within :data:`OPTIMALITY_SLACK` gap tolerances of the vertex form's
        optimum of the same step (the same program in (z, α, v); amcp_reference.tube_vertex, cvxpy's own),
        else the answer re-solved at a tighter feasibility tolerance (:data:`TIGHTER_FEASIBILITY`) when
        that one passes, else the status INACCURATE (the controller then answers the step by the other
        formulation, checked). No check when the vertex form gives no optimum (its vertices cannot be
        enumerated, or it ends otherwise): the answer is kept as it is, and the detail says so."""
        vertex = self._vertex_check.solve(x, h_theta, theta_hat, H_theta)
        extra = vertex.solver_time or 0.0
        if vertex.status is not SolveStatus.OPTIMAL:
            return replace(sol, solver_time=sol.solver_time + extra,
                           detail=f"{sol.detail}; optimality not checked (vertex form: {vertex.status.value})")
        options = self._tolerances
        slack = OPTIMALITY_SLACK * (options["tol_gap_abs"] + options["tol_gap_rel"] * abs(vertex.cost))
        excess = sol.cost - vertex.cost
        if excess <= slack:
            return replace(sol, solver_time=sol.solver_time + extra)
        tighter = {"tol_feas": TIGHTER_FEASIBILITY * options["tol_feas"]}
        status, spent, _ = self._call.solve(form.problem, tighter)
        resolve = Attempt("tube_qp", "tighter_feasibility", status, options=(("tol_feas", f"{tighter['tol_feas']:.0e}"),))
        note = (f"the first answer's cost was {excess:.2e} above the vertex form's optimum (allowed {slack:.1e}); "
                f"re-solved at tol_feas {tighter['tol_feas']:.0e}")
        if status is SolveStatus.OPTIMAL:
            again = self._read(form, x, theta_hat)
            if again.cost - vertex.cost <= slack:
                return replace(again, solver_time=sol.solver_time + extra + spent, update_time=sol.update_time,
                               detail=f"{sol.detail}; {note}", attempts=(*sol.attempts, resolve))
        return MPCSolution(SolveStatus.INACCURATE, None, None, None, None, None, sol.solver_time + extra + spent,
                           sol.update_time, detail=f"{sol.detail}; {note}: still above (status {status.value})",
                           attempts=(*sol.attempts, replace(resolve, status=SolveStatus.INACCURATE)))

    def _read(self, form: _Formulation, x, theta_hat) -> MPCSolution:
        """The answer held by ``form``'s variables after an optimal solve, with its cost: (19) of the plan
        for the min-max cost (not Σ s_l², backends.minmax_cost), else (17)."""
        nv, u = np.shape(self.data.X0_vertices)[0], np.shape(self.data.H_x)[0]
        v = np.asarray(form.v.value, float).T.copy()           # (N, m)
        z = np.asarray(form.z.value, float).T.copy()           # (N+1, n)
        alpha = np.asarray(form.alpha.value, float).copy()     # (N+1,)
        Lam = np.stack([np.asarray(L.value, float).reshape(nv, u, self.capacity)[..., :self.q]
                        for L in form.Lambda])  # (N, nv, u, q): padded columns dropped (_padded)
        cost = minmax_plan_cost(self.data, z, alpha, v) if self.data.minmax else nominal_cost(self.data, x, theta_hat, v)
        return MPCSolution(SolveStatus.OPTIMAL, v, z, alpha, Lam, cost)

    def _solve(self, problem: cp.Problem, refine: bool = False) -> tuple[SolveStatus, float, str, tuple]:
        """(status, solver time, detail, re-solves as (rung, options)): Clarabel with the retry ladder of
        :mod:`amcp_drake.backends.clarabel_retry`, any other solver once; ``refine``: iterative
        refinement from the first solve."""
        def once(extra_options):
            status, elapsed, detail = self._call.solve(problem, extra_options)
            return detail, status, elapsed

        if self._call.name != "CLARABEL":
            return (*self._call.solve(problem), ())
        # the first try of both backends (clarabel_retry.first_try), then the user's options and the ladder
        minmax = self.data.minmax
        detail, status, elapsed, note, rungs = solve_with_retries(once, *first_try(minmax, refine, self._call.options))
        return status, elapsed, f"{detail} ({note})" if note else detail, rungs

    def _u0_form(self) -> _Formulation:
        """The variant of (20) with the first-input bounds, built on first use for this q."""
        if getattr(self, "_u0", None) is None or self._u0[0] != self.capacity:
            self._u0 = (self.capacity, formulate(self.data, self.capacity, u0_bounds=True))
        return self._u0[1]

    def _diagnose(self, x, h_theta, theta_hat) -> tuple[str, ...]:
        """Groups relaxed by the elastic problem (minimum total slack); empty if it fails."""
        def elastic() -> _Formulation:
            if self._elastic is None:
                self._elastic = formulate(self.data, self.capacity, elastic=True)
            self._set_parameters(self._elastic, x, h_theta, theta_hat)
            return self._elastic

        return relaxed_groups(self._call, elastic, GROUPS)
