"""The tube MPC QP (20) in Drake, vertex form of (5b): ``DrakeBackend(formulation="vertex")``.

Same optimum as the plain (15a)-(15d) of :mod:`.drake_tube` (see :mod:`.vertex_form` for the
argument: the proof of Proposition 9 read backwards), without the multipliers Λ:

* (15a), (15b), the terminal set, α >= 0 and the cost (17)-(18) are those of the plain form;
* (15c)-(15d) are replaced by the N·u·S rows of :mod:`.vertex_form`, one block of u rows per
  prediction step l and vertex θ^s of Θ_k, with the coefficient of α_l maximised over the
  vertices x^j of X0 (exact because α_l >= 0).

The vertices of Θ_k are enumerated at every step (their number S changes when Θ_k degenerates).
The program is built once: each step replaces the matrix and bounds of the one tube-row
constraint with ``LinearConstraint.UpdateCoefficients`` (Drake allows the number of rows to
change), so no symbolic expression is built per step. The sparsity pattern of the rows depends
only on S and is cached.

Decision vector y = [z (N+1)·n | α (N+1) | v N·m]. :class:`~.base.MPCSolution` has
``Lambda=None``: this form has no multipliers (certificates of (15c)-(15d) need the plain form).
When the vertices cannot be enumerated (more than ``vertex_form.MAX_COMBINATIONS`` bases and a
flat Θ_k), the step is solved by the plain form instead, and ``detail`` says so. Clarabel runs
with :data:`~.vertex_form.CLARABEL_OPTIONS` (no iterative refinement); a step that ends
``AlmostSolved`` is solved again with the user's settings, then with the Clarabel retry ladder
(:func:`~.clarabel_retry.retry_ladder`, as the plain form and the cvxpy vertex form).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from amcp_drake.backends.base import Attempt, MPCSolution, TubeMPCData, backend_attempts
from amcp_drake.backends.clarabel_retry import RETRIED, retry_ladder
from amcp_drake.backends.condensed_cost import CondensedCost
from amcp_drake.backends.daqp_fast import DaqpFastPath
from amcp_drake.backends.drake_solver import DrakeSolver, infeasible_constraint_names, tries_note
from amcp_drake.backends.vertex_form import CLARABEL_OPTIONS, VertexEnumerationError, theta_vertices
from amcp_drake.model.arrays import all_finite, same_bits, scalar_operand
from amcp_drake.model.status import SolveStatus

_TWO = scalar_operand(2.0)  # the factor 2 of Drake's ½ yᵀQy + bᵀy as a 0-d array (model.arrays.scalar_operand)

TUBE_ROWS = "(5b) tube propagation at the vertices of Theta_k (vertex form of (15c)-(15d))"


class _TubeRows:
    """The N·S·u tube rows for S vertices of Θ_k as one preallocated CSC matrix.

    Row (l, s, i) has the columns z_l, z_{l+1} (contiguous), α_l, α_{l+1}, v_l. The pattern depends
    only on S; each step writes the (S, u, width) block of coefficients (the same for every l)
    into ``A.data`` through ``source``, the index into the block of each stored entry."""

    def __init__(self, mpc: DrakeVertexTubeMPC, S: int) -> None:
        n, m, N, u, a0, v0 = mpc.n, mpc.m, mpc.N, mpc.u, mpc.a0, mpc.v0
        width = 2 * n + 2 + m
        per_l = np.array([np.concatenate([np.arange(l * n, (l + 2) * n), [a0 + l, a0 + l + 1],
                                          np.arange(v0 + l * m, v0 + (l + 1) * m)]) for l in range(N)])
        indices = np.repeat(per_l[:, None, :], S * u, axis=1).reshape(-1)
        indptr = np.arange(0, N * S * u * width + 1, width)
        block_entries = S * u * width
        # stored entry e of the CSR form (row-major over (l, s, i, column)) is block entry e mod S·u·width
        order = np.arange(N * block_entries, dtype=float) + 1.0
        csc = sp.csr_matrix((order, indices, indptr), shape=(N * S * u, mpc.size)).tocsc()
        self.source = (csc.data.astype(np.int64) - 1) % block_entries
        self.A = csc
        self.lb = np.full(N * S * u, -np.inf)
        self.ub = np.tile(-mpc.w_bar, N * S)

    def write(self, block: np.ndarray) -> None:
        self.A.data[:] = block.reshape(-1)[self.source]


class DrakeVertexTubeMPC:
    """QP (20) in vertex form, built once; :meth:`solve` updates x_k, the rows of Θ_k's vertices, θ̂_k."""

    formulation = "vertex"
    #: no ``solve(..., refine=True)``: the vertex form re-solves with iterative refinement itself
    REFINES = False

    def __init__(self, data: TubeMPCData, solver, solver_options: dict | None = None, fast: bool = False) -> None:
        """``solver``: the backend's ``_Solver``; with Clarabel, a copy with
        :data:`~.vertex_form.CLARABEL_OPTIONS` under the user's ``solver_options`` is used.
        ``fast``: try the DAQP fast path of :mod:`.daqp_fast` first at every step (off by default)."""
        self.data = data
        self._plain_solver = solver
        if solver.name == "clarabel":
            solver = DrakeSolver("clarabel", {**CLARABEL_OPTIONS, **(solver_options or {})})
        self._solver = solver
        self._plain = None  # the plain form, built only if a step needs the fallback
        self._cost_model = CondensedCost(data)
        self._rows: dict[int, _TubeRows] = {}
        self._last_vertices: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._tube_S = -1  # number of vertices whose rows are in the program now (-1: none yet)
        self._vertex_version = 0   # incremented whenever Θ_k's vertices are enumerated anew
        self._drake_version = -1   # the version whose tube rows are in the Drake program
        self._fast: DaqpFastPath | None = None
        self._build()
        if fast:
            order = np.concatenate([np.arange(self.a0, self.v0), np.arange(self.a0), np.arange(self.v0, self.size)])
            self._fast = DaqpFastPath(order, self.v0 - self.a0, slice(self.v0, self.size), self._fixed_A,
                                      self._fixed_b, self._A15b, self.N * self.u)

    # -- construction ------------------------------------------------------------------------
    def _build(self) -> None:
        d = self.data
        n, m = np.shape(d.B0)
        N = int(d.N)
        H_x = np.asarray(d.H_x, float)
        u = H_x.shape[0]
        self.n, self.m, self.N, self.u = n, m, N, u
        self.a0 = (N + 1) * n
        self.v0 = self.a0 + N + 1
        self.size = self.v0 + N * m
        a0, v0, size = self.a0, self.v0, self.size
        self.H_x = H_x
        self.Xv = np.asarray(d.X0_vertices, float)
        self.Acl0 = d.A0 + d.B0 @ d.K
        self.Acl_i = d.A + d.B @ d.K        # (p, n, n)
        self.w_bar = np.asarray(d.w_bar, float)

        prog = self.prog = MathematicalProgram()
        y = self.y = prog.NewContinuousVariables(size, "y")

        # (15a): (F+GK) z_l + G v_l + α_l f̄ <= 1
        c = d.F.shape[0]
        FGK = d.F + d.G @ d.K
        A15a = sp.lil_matrix((N * c, size))
        for l in range(N):
            rows = slice(l * c, (l + 1) * c)
            A15a[rows, l * n:(l + 1) * n] = FGK
            A15a[rows, v0 + l * m:v0 + (l + 1) * m] = d.G
            A15a[rows, a0 + l] = np.asarray(d.f_bar, float).reshape(-1, 1)
        prog.AddLinearConstraint(A15a.tocsc(), np.full(N * c, -np.inf), np.ones(N * c), y
                                 ).evaluator().set_description("(15a) state and input constraints")

        # (15b): -H_x z_0 - α_0 1 <= -H_x x_k  (bounds updated per step)
        A15b = sp.lil_matrix((u, size))
        A15b[:, 0:n] = -H_x
        A15b[:, a0] = -np.ones((u, 1))
        self._A15b = A15b.toarray()
        self._c15b = prog.AddLinearConstraint(A15b.tocsc(), np.full(u, -np.inf), np.zeros(u), y).evaluator()
        self._c15b_ub = np.zeros(u)
        self._minus_H_x = -H_x
        self._c15b.set_description("(15b) x_k in X_0|k")

        # (5b) at the vertices of Θ_k: matrix replaced per step (placeholder: one void row)
        self._tube = prog.AddLinearConstraint(sp.csc_matrix((1, size)), np.array([-np.inf]), np.array([np.inf]),
                                              y).evaluator()
        self._tube.set_description(TUBE_ROWS)

        # terminal set: H_T z_N + h_T α_N <= 1
        r = d.H_T.shape[0]
        AT = sp.lil_matrix((r, size))
        AT[:, N * n:(N + 1) * n] = d.H_T
        AT[:, a0 + N] = np.asarray(d.h_T, float).reshape(-1, 1)
        prog.AddLinearConstraint(AT.tocsc(), np.full(r, -np.inf), np.ones(r), y
                                 ).evaluator().set_description("terminal set (z_N, alpha_N) in Xf")
        # the rows that never change, densely, for the fast path
        self._fixed_A = sp.vstack([A15a, AT]).toarray()
        self._fixed_b = np.ones(N * c + r)

        prog.AddBoundingBoxConstraint(0.0, np.inf, y[a0:v0]).evaluator().set_description("alpha >= 0")

        self._cost = prog.AddQuadraticCost(np.eye(N * m), np.zeros(N * m), 0.0, y[v0:], is_convex=True).evaluator()
        self._cost.set_description("(17) certainty-equivalence cost")

    def _rows_for(self, S: int) -> _TubeRows:
        """The preallocated tube rows for S vertices of Θ_k (built on first use for this S)."""
        if S not in self._rows:
            self._rows[S] = _TubeRows(self, S)
        return self._rows[S]

    def tube_rows(self, vertices: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
        """Matrix (N·S·u, size) and upper bound of the vertex-form rows for Θ_k's vertices (S, p),
        written into the preallocated matrix for S (the returned matrix is that one, not a copy)."""
        rows = self._rows_for(len(vertices))
        rows.write(self._block(vertices))
        return rows.A, rows.ub

    def _block(self, vertices: np.ndarray) -> np.ndarray:
        """(S, u, width) coefficients of the rows of one prediction step l (they repeat over l):
        [H_x A_cl(θ^s) | −H_x | c^s | −1 | H_x B(θ^s)] on (z_l, z_{l+1}, α_l, α_{l+1}, v_l)."""
        S = len(vertices)
        n, u = self.n, self.u
        A_cl = self.Acl0 + np.tensordot(vertices, self.Acl_i, axes=1)                 # (S, n, n)
        B_s = self.data.B0 + np.tensordot(vertices, self.data.B, axes=1)              # (S, n, m)
        HA = self.H_x @ A_cl                                                          # (S, u, n)
        HB = self.H_x @ B_s                                                           # (S, u, m)
        c_alpha = np.max(HA @ self.Xv.T, axis=2)                                      # (S, u)
        return np.concatenate([HA, np.broadcast_to(-self.H_x, (S, u, n)), c_alpha[..., None],
                               np.full((S, u, 1), -1.0), HB], axis=2)

    def _vertices(self, H: np.ndarray, h_theta: np.ndarray) -> tuple[np.ndarray, bool]:
        """Vertices of Θ_k = {H θ <= h_theta}, and whether they are those of the previous step
        (Θ_k unchanged: same H and h to the bit), in which case they are not enumerated again."""
        last = self._last_vertices
        if last is not None and same_bits(last[0], h_theta) and same_bits(last[1], H):
            return last[2], True
        vertices = theta_vertices(H, h_theta)
        self._last_vertices = (h_theta.copy(), H.copy(), vertices)
        return vertices, False

    # -- solve ---------------------------------------------------------------------------------
    def solve(self, x, h_theta, theta_hat, H_theta=None) -> MPCSolution:
        """Solve (20) at x_k with Θ_k = {H_θ θ <= h_theta} and point estimate θ̂_k."""
        start = time.perf_counter()
        x = np.asarray(x, float)
        h_theta = np.asarray(h_theta, float)
        theta_hat = np.asarray(theta_hat, float)
        H = np.asarray(self.data.H_theta if H_theta is None else H_theta, float)
        # one finiteness test of the four inputs (a concatenation is finite iff each part is); the loop names the culprit
        if not all_finite(np.concatenate((x.ravel(), h_theta.ravel(), theta_hat.ravel(), H.ravel()))):
            for name, arr in (("x", x), ("h_theta", h_theta), ("theta_hat", theta_hat), ("H_theta", H)):
                if not all_finite(arr):
                    return MPCSolution(SolveStatus.ERROR, None, None, None, None, None, detail=f"non-finite {name}")
        try:
            vertices, unchanged = self._vertices(H, h_theta)
        except VertexEnumerationError as exc:
            return self._solve_plain(x, h_theta, theta_hat, H_theta, str(exc))
        if not unchanged:
            self._vertex_version += 1
        S = len(vertices)
        b15b = self._minus_H_x.dot(x, out=self._c15b_ub)  # −H_x x_k, the upper bound of (15b)
        Hv, g, const = self._cost_model.matrices(x, theta_hat)
        g2 = _TWO * g  # 2g: Drake's linear term (½ yᵀ(2H)y + (2g)ᵀy) and the cost's 2gᵀv, computed once
        fast_note = ""
        if self._fast is not None and self._fast.active:
            cpu = time.thread_time()
            sol, fast_note = self._solve_fast(S, vertices, b15b, Hv, g, g2, const, start)
            if sol is not None:
                if self._fast.calibrating:
                    # the measured switch (daqp_fast.DaqpFastPath.calibrate): the same step by Clarabel, timed
                    fast_cpu, cpu = time.thread_time() - cpu, time.thread_time()
                    self._solve_clarabel(S, vertices, b15b, Hv, g2, const, start, "")
                    self._fast.calibrate(fast_cpu, time.thread_time() - cpu)
                return sol
        elif self._fast is not None:
            fast_note = f"; fast path off: {self._fast.off_reason}"
        return self._solve_clarabel(S, vertices, b15b, Hv, g2, const, start, fast_note)

    def _solve_clarabel(self, S, vertices, b15b, Hv, g2, const, start, fast_note: str) -> MPCSolution:
        """The step's QP (20) by the Drake program (Clarabel unless another solver was named)."""
        if self._drake_version != self._vertex_version or self._tube_S != S:
            rows = self._rows_for(S)
            rows.write(self._block(vertices))
            self._tube.UpdateCoefficients(rows.A, rows.lb, rows.ub)
            self._tube_S, self._drake_version = S, self._vertex_version
        self._c15b.UpdateUpperBound(b15b)
        self._cost.UpdateCoefficients(_TWO * Hv, g2, const, True)  # is_convex positional: pybind11's keyword path costs ~0.5 µs
        update_time = time.perf_counter() - start
        not_solved: list[str] = []  # what each try that did not end "optimal" returned (tries_note)

        def tried(solver, result):
            status = solver.status(result)
            if status is not SolveStatus.OPTIMAL:
                not_solved.append(solver.describe(result))
            return status

        result, solver_time = self._solver.solve(self.prog)
        status = tried(self._solver, result)
        detail = f"vertex form, {S} vertices of Theta_k{fast_note}"
        rungs: tuple = ()
        if status is SolveStatus.INACCURATE and self._solver is not self._plain_solver:
            # near-degenerate steps (states at the edge of the feasible set, tight tolerances) can end
            # AlmostSolved without iterative refinement: solve again with the user's settings
            result, extra = self._plain_solver.solve(self.prog)
            status = tried(self._plain_solver, result)
            solver_time += extra
            detail += "; re-solved with iterative refinement"
            rungs = (("refine", ()),)
        if status in RETRIED and self._plain_solver.name == "clarabel":
            def rung(extra_options):
                result, elapsed = self._plain_solver.solve(self.prog, extra_options)
                return result, tried(self._plain_solver, result), elapsed

            result, status, solver_time, note, ladder = retry_ladder(rung, result, status, solver_time)
            detail += f"; {note}"
            rungs += ladder
        if not_solved:
            detail += f"; {tries_note(not_solved)}"
        if status is not SolveStatus.OPTIMAL:
            names = infeasible_constraint_names(result, self.prog)
            return MPCSolution(status, None, None, None, None, None, solver_time, update_time, names,
                               detail=f"{self._plain_solver.describe(result)}; {detail}",
                               attempts=backend_attempts(rungs, status))
        yv = result.get_x_val()  # y is the program's only decision vector, in order
        return replace(self._solution(yv, Hv, g2, const, solver_time, update_time, detail),
                       attempts=backend_attempts(rungs, status))

    @property
    def fast_path_counts(self) -> dict[str, int] | None:
        """Fast path only: steps answered by DAQP (checked) and steps that fell back to Clarabel."""
        return None if self._fast is None else dict(self._fast.counts)

    @property
    def fast_path_off(self) -> str:
        """Fast path only: why the measured switch or the size limit turned it off ('' while it is on
        or when there is none)."""
        return "" if self._fast is None or self._fast.active else self._fast.off_reason

    def _solution(self, yv, Hv, g2, const, solver_time, update_time, detail) -> MPCSolution:
        """The answer read from y; ``g2`` = 2g (the cost is vᵀHv + 2gᵀv + c)."""
        N, n, m = self.N, self.n, self.m
        z = yv[: self.a0].reshape(N + 1, n)
        alpha = yv[self.a0:self.v0]
        vf = yv[self.v0:]
        v = vf.reshape(N, m)
        cost = float(vf.dot(Hv).dot(vf) + g2.dot(vf) + const)  # ndarray.dot: the BLAS call of @
        return MPCSolution(SolveStatus.OPTIMAL, v, z, alpha, None, cost, solver_time, update_time, detail=detail)

    def _solve_fast(self, S, vertices, b15b, Hv, g, g2, const, start) -> tuple[MPCSolution | None, str]:
        """The fast path (:mod:`.daqp_fast`): (solution, "") when DAQP's answer passed its checks,
        else (None, note for the detail of the Clarabel solve that follows); counted in
        ``fast_path_counts``."""
        model = self._fast.model(S)
        if model is None:
            return None, f"; fast path off: {self._fast.off_reason}"
        if model.version != self._vertex_version:
            rows = self._rows_for(S)
            rows.write(self._block(vertices))
            model.write_tube(rows.A.toarray(), rows.ub)
            model.version = self._vertex_version
        update_time = time.perf_counter() - start
        yv, detail, elapsed = self._fast.solve(model, b15b, Hv, g)
        if yv is None:
            return None, f"; fast path fell back to Clarabel: {detail}"
        return self._solution(yv, Hv, g2, const, elapsed, update_time,
                              f"vertex form, {S} vertices of Theta_k; fast path: {detail}"), ""

    def _solve_plain(self, x, h_theta, theta_hat, H_theta, reason: str) -> MPCSolution:
        """Fallback for a step whose Θ_k vertices cannot be enumerated: the plain form (15)."""
        from amcp_drake.backends.drake_tube import DrakeTubeMPC

        if self._plain is None:
            H0 = self.data.H_theta if H_theta is None else H_theta
            # h_theta0 describes Θ0 in the shape of data.H_theta only
            same = H_theta is None or np.array_equal(H_theta, self.data.H_theta)
            self._plain = DrakeTubeMPC(replace(self.data, H_theta=np.asarray(H0, float),
                                               h_theta0=self.data.h_theta0 if same else None), self._plain_solver)
        sol = self._plain.solve(x, h_theta, theta_hat, H_theta)
        return replace(sol, detail=f"plain form (15) fallback: {reason}; {sol.detail}".rstrip("; "),
                       attempts=(Attempt("tube_qp", "plain_form", sol.status), *sol.attempts))
