"""The tube MPC QP (20) in cvxpy, vertex form of (5b): ``CvxpyBackend(formulation="vertex")``.

Same optimum as the plain (15a)-(15d) of :mod:`amcp_reference.tube_mpc`, without the
multipliers Λ (the argument is in :mod:`amcp_drake.backends.vertex_form`): for every prediction
step l and every vertex θ^s of Θ_k,

    H_x (A_cl(θ^s) z_l + B(θ^s) v_l − z_{l+1}) + c^s α_l − α_{l+1} 1 <= −w̄,
    c^s_i = max_j [H_x A_cl(θ^s) x^j]_i  (x^j the vertices of X0; exact because α_l >= 0).

One DPP problem is built per vertex capacity S_cap. Parameters, set at every step:

* ``x_k`` (n,), ``A_cl_hat`` (n, n), ``B_hat`` (n, m): as in the plain form;
* the vertex slots s < S_cap stacked (three parameters, not three per slot: cvxpy's cost of
  setting and applying parameters grows with their number): ``A_cl_stack`` (S_cap·n, n) with
  block s = A_cl(θ^s), ``B_stack`` (S_cap·n, m) with block s = B(θ^s), ``c_stack`` (S_cap·u, 1).
  The constraint is then kron(I, H_x) (A_cl_stack z_l + B_stack v_l − kron(1, I) z_{l+1}) + ... .

Θ_k has S <= S_cap vertices: the unused slots repeat the last vertex (a repeated row changes
nothing). When S exceeds the capacity the problem is rebuilt for S vertices (and cached).
``MPCSolution.Lambda`` is None (this form has no multipliers). The vertices come from
:func:`amcp_drake.backends.vertex_form.theta_vertices` (basis enumeration, exact for flat Θ_k);
the fallback to the plain form is taken when they cannot be enumerated. Clarabel runs with
:data:`amcp_drake.backends.vertex_form.CLARABEL_OPTIONS` (no iterative refinement); a step that
ends ``optimal_inaccurate`` is solved again with the user's settings, then with the Clarabel retry
ladder (:func:`amcp_drake.backends.clarabel_retry.retry_ladder`, as the Drake vertex form).

With Clarabel (and ``compiled=True``, the default) each step is first solved from cvxpy's compiled
program by a Clarabel solver kept between steps, without ``Problem.solve``
(:mod:`amcp_reference.compiled_clarabel`: the same data; Example 1, 8 facets: 1.56 against 2.74 ms
CPU per step); a step that route
does not answer with "Solved" is solved again through ``Problem.solve`` as before.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cvxpy as cp
import numpy as np

from amcp_drake.backends.base import Attempt, MPCSolution, TubeMPCData, backend_attempts
from amcp_drake.backends.clarabel_retry import RETRIED, retry_ladder
from amcp_drake.backends.vertex_form import (
    CLARABEL_OPTIONS,
    VertexEnumerationError,
    theta_vertices,
)
from amcp_drake.model.status import SolveStatus

from .compiled_clarabel import SOLVED, CompiledClarabel
from .nominal_cost import certainty_equivalence_cost, nominal_cost
from .tube_mpc import GROUP_15A, GROUP_15B, GROUP_TERMINAL, relaxed_groups

GROUP_VERTEX = "(5b) tube propagation at the vertices of Theta_k (vertex form of (15c)-(15d))"
VERTEX_GROUPS = (GROUP_15A, GROUP_15B, GROUP_VERTEX, GROUP_TERMINAL)
#: Problems kept per vertex capacity (Θ_k's vertex count changes only when it degenerates).
MAX_CACHED = 4


@dataclass
class _VertexFormulation:
    problem: cp.Problem
    params: dict[str, cp.Parameter]
    capacity: int
    z: cp.Variable
    alpha: cp.Variable
    v: cp.Variable
    slacks: dict[str, cp.Variable] = field(default_factory=dict)
    #: the compiled route (None: off, e.g. another solver than Clarabel)
    compiled: CompiledClarabel | None = None


def formulate_vertex(data: TubeMPCData, capacity: int, elastic: bool = False) -> _VertexFormulation:
    """Build (20) in vertex form with ``capacity`` vertex slots. ``elastic``: one slack per
    constraint group, objective Σ slacks (a diagnostic, as in :func:`tube_mpc.formulate`)."""
    B0 = np.asarray(data.B0, float)
    F, G, K = np.asarray(data.F, float), np.asarray(data.G, float), np.asarray(data.K, float)
    H_x = np.asarray(data.H_x, float)
    w_bar, f_bar = np.asarray(data.w_bar, float), np.asarray(data.f_bar, float)
    H_T, h_T = np.asarray(data.H_T, float), np.asarray(data.h_T, float)
    n, m = B0.shape
    N = int(data.N)
    u = H_x.shape[0]

    params = {"x_k": cp.Parameter(n, name="x_k")}
    z = cp.Variable((n, N + 1), name="z")
    # α >= 0 as a constraint, not a variable attribute: cvxpy replaces a variable with an attribute
    # by a new one in its compiled program, and the compiled route reads α there by its own id
    alpha = cp.Variable(N + 1, name="alpha")
    v = cp.Variable((m, N), name="v")
    slacks = {g: cp.Variable(nonneg=True, name=f"slack {g}") for g in VERTEX_GROUPS} if elastic else {}

    def s(group: str):
        return slacks[group] if elastic else 0.0

    alpha_now = cp.reshape(alpha[:N], (1, N), order="F")
    alpha_next = cp.reshape(alpha[1:], (1, N), order="F")
    constraints = [
        # (15a): (F + G K) z_l + G v_l + α_l f̄ <= 1
        (F + G @ K) @ z[:, :N] + G @ v + f_bar.reshape(-1, 1) @ alpha_now <= 1.0 + s(GROUP_15A),
        # (15b): −H_x z_0 − α_0 1 <= −H_x x_k
        -H_x @ z[:, 0] - alpha[0] <= -H_x @ params["x_k"] + s(GROUP_15B),
        # terminal set X_f
        H_T @ z[:, N] + alpha[N] * h_T <= 1.0 + s(GROUP_TERMINAL),
        alpha >= 0,
    ]
    # (5b) at every vertex slot s (block rows s·u..(s+1)·u) and every l (column l)
    params["A_cl_stack"] = cp.Parameter((capacity * n, n), name="A_cl_stack")
    params["B_stack"] = cp.Parameter((capacity * n, m), name="B_stack")
    params["c_stack"] = cp.Parameter((capacity * u, 1), name="c_stack")
    H_blocks = np.kron(np.eye(capacity), H_x)                 # (S_cap·u, S_cap·n)
    repeat = np.kron(np.ones((capacity, 1)), np.eye(n))       # (S_cap·n, n): z_{l+1} in every block
    propagated = params["A_cl_stack"] @ z[:, :N] + params["B_stack"] @ v - repeat @ z[:, 1:]
    constraints.append(H_blocks @ propagated + params["c_stack"] @ alpha_now - np.ones((capacity * u, 1)) @ alpha_next
                       <= -np.tile(w_bar, capacity).reshape(-1, 1) @ np.ones((1, N)) + s(GROUP_VERTEX))
    if elastic:
        objective = cp.Minimize(cp.sum(cp.hstack(list(slacks.values()))))
    else:
        objective = certainty_equivalence_cost(data, params, v, constraints)
    return _VertexFormulation(cp.Problem(objective, constraints), params, capacity, z, alpha, v, slacks)


class CvxpyVertexTubeMPC:
    """QP (20) in vertex form; :meth:`solve` enumerates Θ_k's vertices, sets parameters, solves."""

    formulation = "vertex"
    #: no ``solve(..., refine=True)``: the vertex form re-solves with iterative refinement itself
    REFINES = False

    def __init__(self, data: TubeMPCData, call, compiled: bool = True, plain_fallback: bool = True) -> None:
        """``call``: the backend's ``SolverCall``; with Clarabel, a copy with
        :data:`amcp_drake.backends.vertex_form.CLARABEL_OPTIONS` under the user's options is used.
        ``compiled``: with Clarabel, solve each step first from cvxpy's compiled program
        (:mod:`amcp_reference.compiled_clarabel`); False: always through ``Problem.solve``.
        ``plain_fallback``: solve a step whose Θ_k vertices cannot be enumerated by the plain form; False
        (the plain form's own optimality check, which must not call the plain form): the status ERROR."""
        from .solver_call import SolverCall

        self.data = data
        self.compiled = bool(compiled) and call.name == "CLARABEL"
        self.plain_fallback = plain_fallback
        self._plain_call = call
        if call.name == "CLARABEL":
            call = SolverCall(call.name, {**CLARABEL_OPTIONS, **call.options}, keep_solver=True)
        self._call = call
        self._forms: dict[int, _VertexFormulation] = {}
        self._elastic: dict[int, _VertexFormulation] = {}
        self._plain = None
        self._last_vertices: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # (h_θ, H_θ, vertices)
        self._last_form: _VertexFormulation | None = None  # the problem whose vertex parameters are current
        self.H_theta = np.asarray(data.H_theta, float)
        # capacity guess: the vertex count of {H_θ θ <= 1}; grows when Θ_k has more vertices
        try:
            guess = len(theta_vertices(self.H_theta, np.ones(len(self.H_theta))))
        except VertexEnumerationError:
            guess = 2 ** np.shape(data.A)[0]
        self.capacity = guess
        self._form(guess)

    def _form(self, capacity: int) -> _VertexFormulation:
        """The problem with ``capacity`` slots, compiled now (DPP) so the first solve is not charged."""
        if capacity not in self._forms:
            form = formulate_vertex(self.data, capacity)
            n, p = np.shape(self.data.B0)[0], np.shape(self.data.A)[0]
            self._set_parameters(form, np.zeros(n), np.zeros((1, p)), np.zeros(p))
            try:
                form.problem.get_problem_data(self._call.name, enforce_dpp=True)
            except cp.error.SolverError:
                pass  # reported as a status by ``solve``
            else:
                if self.compiled:
                    form.compiled = CompiledClarabel(form.problem, self._call.settings, read=(form.v, form.z, form.alpha))
            if len(self._forms) >= MAX_CACHED:
                self._forms.pop(next(iter(self._forms)))
            self._forms[capacity] = form
        return self._forms[capacity]

    @property
    def problem(self) -> cp.Problem:
        return self._forms[self.capacity].problem

    def _set_parameters(self, form: _VertexFormulation, x, vertices, theta_hat) -> None:
        """Parameters of ``form`` for x_k, Θ_k's vertices (None: keep the vertex parameters) and θ̂_k."""
        d = self.data
        form.params["x_k"].value = x
        if vertices is not None:
            H_x, Xv = np.asarray(d.H_x, float), np.asarray(d.X0_vertices, float)
            n, m = np.shape(d.B0)
            slots = np.asarray(vertices, float)[np.minimum(np.arange(form.capacity), len(vertices) - 1)]  # repeat last
            B_v = d.B0 + np.tensordot(slots, d.B, axes=1)                                  # (S_cap, n, m)
            A_cl = d.A0 + np.tensordot(slots, d.A, axes=1) + B_v @ d.K                       # (S_cap, n, n)
            form.params["A_cl_stack"].value = A_cl.reshape(-1, n)
            form.params["B_stack"].value = B_v.reshape(-1, m)
            form.params["c_stack"].value = np.max(H_x @ A_cl @ Xv.T, axis=2).reshape(-1, 1)  # c^s_i = max_j
        if "A_cl_hat" in form.params:
            B_hat = d.B0 + np.tensordot(theta_hat, d.B, axes=1)
            form.params["A_cl_hat"].value = d.A0 + np.tensordot(theta_hat, d.A, axes=1) + B_hat @ d.K
            form.params["B_hat"].value = B_hat

    def solve(self, x, h_theta, theta_hat, H_theta=None) -> MPCSolution:
        """Solve (20) at x_k with Θ_k = {H_θ θ <= h_theta} and the point estimate θ̂_k."""
        start = time.perf_counter()
        x = np.asarray(x, float).reshape(-1)
        h_theta = np.asarray(h_theta, float).reshape(-1)
        theta_hat = np.asarray(theta_hat, float).reshape(-1)
        H = self.H_theta if H_theta is None else np.atleast_2d(np.asarray(H_theta, float))
        n, p = np.shape(self.data.B0)[0], np.shape(self.data.A)[0]
        for name, arr, shape in (("x", x, (n,)), ("h_theta", h_theta, (H.shape[0],)), ("theta_hat", theta_hat, (p,)),
                                 ("H_theta", H, (H.shape[0], p))):
            if not np.all(np.isfinite(arr)):
                return MPCSolution(SolveStatus.ERROR, None, None, None, None, None, detail=f"non-finite {name}")
            if arr.shape != shape:
                return MPCSolution(SolveStatus.ERROR, None, None, None, None, None,
                                   detail=f"{name} has shape {arr.shape}, expected {shape}")
        last = self._last_vertices
        unchanged = last is not None and np.array_equal(last[0], h_theta) and np.array_equal(last[1], H)
        try:
            # Θ_k's vertices are enumerated only when Θ_k changed (to the bit), as in the Drake backend
            vertices = last[2] if unchanged else theta_vertices(H, h_theta)
        except VertexEnumerationError as exc:
            if not self.plain_fallback:
                return MPCSolution(SolveStatus.ERROR, None, None, None, None, None, detail=f"vertex form: {exc}")
            return self._solve_plain(x, h_theta, theta_hat, H_theta, str(exc))
        self._last_vertices = (h_theta.copy(), H.copy(), vertices)
        self.capacity = max(self.capacity, len(vertices))
        form = self._form(self.capacity)
        # the vertex parameters keep their values while Θ_k and the problem are those of the last step
        self._set_parameters(form, x, None if unchanged and form is self._last_form else vertices, theta_hat)
        self._last_form = form
        update_time = time.perf_counter() - start
        answer, compiled_time = self._solve_compiled(form)
        if answer is not None:
            v, z, alpha = answer
            cost = nominal_cost(self.data, x, theta_hat, v)
            detail = f"optimal (compiled route); vertex form, {len(vertices)} vertices of Theta_k"
            return MPCSolution(SolveStatus.OPTIMAL, v, z, alpha, None, cost, compiled_time, update_time, detail=detail)
        status, solver_time, detail = self._call.solve(form.problem)
        solver_time += compiled_time
        detail = f"{detail}; vertex form, {len(vertices)} vertices of Theta_k"
        rungs: tuple = ()
        if form.compiled is not None:  # say why the route did not answer (a user sees why a step is slower)
            reason = form.compiled.reason
            detail += "; compiled route gave no answer, solved through Problem.solve" if reason is None else f"; {reason}"
            rungs = (("problem_solve", ()),) if reason is None else ()
        if status is SolveStatus.INACCURATE and self._call is not self._plain_call:
            # AlmostSolved without iterative refinement (near-degenerate step): again with the user's settings
            status, extra, _ = self._plain_call.solve(form.problem)
            solver_time += extra
            detail += "; re-solved with iterative refinement"
            rungs += (("refine", ()),)
        if status in RETRIED and self._plain_call.name == "CLARABEL":
            def once(extra_options):  # a rung of the ladder with the user's settings underneath
                rung_status, spent, rung_detail = self._plain_call.solve(form.problem, extra_options)
                return rung_detail, rung_status, spent

            _, status, solver_time, note, ladder = retry_ladder(once, None, status, solver_time)
            detail += f"; {note}"
            rungs += ladder
        if status is not SolveStatus.OPTIMAL:
            names = self._diagnose(x, vertices) if status is SolveStatus.INFEASIBLE else ()
            return MPCSolution(status, None, None, None, None, None, solver_time, update_time, names, detail=detail,
                               attempts=backend_attempts(rungs, status))
        v = np.asarray(form.v.value, float).T.copy()
        z = np.asarray(form.z.value, float).T.copy()
        alpha = np.asarray(form.alpha.value, float).copy()
        cost = nominal_cost(self.data, x, theta_hat, v)
        return MPCSolution(status, v, z, alpha, None, cost, solver_time, update_time, detail=detail,
                           attempts=backend_attempts(rungs, status))

    def _solve_compiled(self, form: _VertexFormulation) -> tuple[tuple[np.ndarray, ...] | None, float]:
        """((v, z, α) or None, Clarabel's solve time) by the compiled route. None when the route is
        off or Clarabel did not end "Solved" (its solver is then dropped, as ``SolverCall`` drops a
        kept solver without an answer); a solver's exception or panic is None too: the caller solves
        the step through ``Problem.solve``, which turns any failure into a status."""
        from .solver_call import is_solver_panic

        compiled = form.compiled
        if compiled is None or compiled.reason is not None:
            return None, 0.0
        try:
            sol = compiled.solve()
        except BaseException as exc:  # a solver's Rust panic is a BaseException, not an Exception
            if not (isinstance(exc, Exception) or is_solver_panic(exc)):
                raise
            compiled.forget_solver()
            return None, 0.0
        elapsed = float(sol.solve_time)
        if str(sol.status) != SOLVED:
            compiled.forget_solver()
            return None, elapsed
        x = sol.x
        v = compiled.value(form.v, x).T.copy()           # (N, m)
        z = compiled.value(form.z, x).T.copy()           # (N+1, n)
        alpha = compiled.value(form.alpha, x).copy()     # (N+1,)
        return (v, z, alpha), elapsed

    def _diagnose(self, x, vertices) -> tuple[str, ...]:
        """Groups relaxed by the elastic problem (minimum total slack); empty if it fails."""
        def elastic() -> _VertexFormulation:
            if self.capacity not in self._elastic:
                self._elastic[self.capacity] = formulate_vertex(self.data, self.capacity, elastic=True)
            form = self._elastic[self.capacity]
            self._set_parameters(form, x, vertices, np.zeros(np.shape(self.data.A)[0]))
            return form

        return relaxed_groups(self._call, elastic, VERTEX_GROUPS)

    def _solve_plain(self, x, h_theta, theta_hat, H_theta, reason: str) -> MPCSolution:
        """Fallback for a step whose Θ_k vertices cannot be enumerated: the plain form (15)."""
        from dataclasses import replace

        from .tube_mpc import CvxpyTubeMPC

        if self._plain is None:
            H0 = self.H_theta if H_theta is None else np.asarray(H_theta, float)
            self._plain = CvxpyTubeMPC(replace(self.data, H_theta=H0), self._plain_call)
        sol = self._plain.solve(x, h_theta, theta_hat, H_theta)
        return replace(sol, detail=f"plain form (15) fallback: {reason}; {sol.detail}",
                       attempts=(Attempt("tube_qp", "plain_form", sol.status), *sol.attempts))
