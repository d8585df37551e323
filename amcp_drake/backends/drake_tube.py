"""The tube MPC QP (20) in Drake: constraints (15a)-(15d), terminal set, cost (17)-(18).

The program is built once per controller with sparse matrix constraints. Each step updates:

* the right-hand side of (15b) (it holds x_k),
* the Λ-coefficients h_θk of (15c) (``LinearConstraint.UpdateCoefficients``),
* the quadratic cost in v (``QuadraticCost.UpdateCoefficients``), condensed from (18) with θ̂_k.

Decision vector y = [z (N+1)·n | α (N+1) | v N·m | Λ N·v·u·q], Λ ordered (l, j, i, r):
Λ^j_{l|k}[i, r] sits at offset ((l·v + j)·u + i)·q + r.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from amcp_drake.backends.base import MPCSolution, TubeMPCData
from amcp_drake.backends.clarabel_retry import NO_REFINEMENT, solve_with_retries
from amcp_drake.backends.condensed_cost import CondensedCost
from amcp_drake.backends.drake_solver import infeasible_constraint_names
from amcp_drake.model.status import SolveStatus


def _sqrtm(M: np.ndarray) -> np.ndarray:
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


class _Layout:
    """Offsets of the blocks of the decision vector."""

    def __init__(self, n: int, m: int, N: int, nv: int, u: int, q: int) -> None:
        self.n, self.m, self.N, self.nv, self.u, self.q = n, m, N, nv, u, q
        self.z0 = 0
        self.a0 = (N + 1) * n
        self.v0 = self.a0 + N + 1
        self.L0 = self.v0 + N * m
        self.size = self.L0 + N * nv * u * q

    def z(self, l: int) -> slice:
        return slice(self.z0 + l * self.n, self.z0 + (l + 1) * self.n)

    def a(self, l: int) -> int:
        return self.a0 + l

    def v(self, l: int) -> slice:
        return slice(self.v0 + l * self.m, self.v0 + (l + 1) * self.m)

    def lam(self, l: int, j: int, i: int) -> slice:
        start = self.L0 + ((l * self.nv + j) * self.u + i) * self.q
        return slice(start, start + self.q)


class DrakeTubeMPC:
    """QP (20) built once; :meth:`solve` updates x_k, h_θk, θ̂_k and solves."""

    def __init__(self, data: TubeMPCData, solver) -> None:
        self.data = data
        self._solver = solver
        self._cost_model = CondensedCost(data)
        self._build(np.asarray(data.H_theta, float))

    # -- construction ------------------------------------------------------------------------
    def _build(self, H_theta: np.ndarray) -> None:
        d = self.data
        n, m = d.B0.shape
        N = d.N
        Xv = np.asarray(d.X0_vertices, float)
        H_x = np.asarray(d.H_x, float)
        nv, u = Xv.shape[0], H_x.shape[0]
        q, p = H_theta.shape
        self.H_theta = H_theta
        lay = self.layout = _Layout(n, m, N, nv, u, q)
        K = d.K
        FGK = d.F + d.G @ K
        Acl0 = d.A0 + d.B0 @ K
        Acl_i = d.A + d.B @ K  # (p, n, n)

        prog = self.prog = MathematicalProgram()
        y = self.y = prog.NewContinuousVariables(lay.size, "y")

        # (15a): (F+GK) z_l + G v_l + α_l f̄ <= 1
        c = d.F.shape[0]
        A15a = sp.lil_matrix((N * c, lay.size))
        for l in range(N):
            rows = slice(l * c, (l + 1) * c)
            A15a[rows, lay.z(l)] = FGK
            A15a[rows, lay.v(l)] = d.G
            A15a[rows, lay.a(l)] = d.f_bar.reshape(-1, 1)
        prog.AddLinearConstraint(A15a.tocsc(), np.full(N * c, -np.inf), np.ones(N * c), y
                                 ).evaluator().set_description("(15a) state and input constraints")

        # (15b): -H_x z_0 - α_0 1 <= -H_x x_k  (rhs updated per step)
        A15b = sp.lil_matrix((u, lay.size))
        A15b[:, lay.z(0)] = -H_x
        A15b[:, lay.a(0)] = -np.ones((u, 1))
        self._c15b = prog.AddLinearConstraint(A15b.tocsc(), np.full(u, -np.inf), np.zeros(u), y).evaluator()
        self._c15b.set_description("(15b) x_k in X_0|k")

        # (15c): Λ h_θ + H_x d^j_l - α_{l+1} 1 <= -w̄; d^j_l = Acl0 (z_l + α_l x^j) + B0 v_l - z_{l+1}
        rows15c = N * nv * u
        C = sp.lil_matrix((rows15c, lay.size))
        HA = H_x @ Acl0
        HB = H_x @ d.B0
        for l in range(N):
            for j in range(nv):
                rows = slice((l * nv + j) * u, (l * nv + j + 1) * u)
                C[rows, lay.z(l)] = HA
                C[rows, lay.a(l)] = (HA @ Xv[j]).reshape(-1, 1)
                C[rows, lay.v(l)] = HB
                C[rows, lay.z(l + 1)] = -H_x
                C[rows, lay.a(l + 1)] = -np.ones((u, 1))
        self._C15c = C.tocsc()
        self._rows15c = rows15c
        self._ub15c = np.tile(-d.w_bar, N * nv)
        self._A15c = self._preallocate_15c()
        self._lb15c = np.full(rows15c, -np.inf)
        self._c15c = prog.AddLinearConstraint(self._matrix_15c(np.zeros(q)), self._lb15c, self._ub15c, y).evaluator()
        self._c15c.set_description("(15c) tube propagation with multipliers")

        # (15d): H_x D^j_l = Λ^j_l H_θ, entry (i, i'): [H_x]_i (Acl_i' (z_l + α_l x^j) + B_i' v_l) - Λ[i,:] H_θ[:, i'] = 0
        rows15d = N * nv * u * p
        A15d = sp.lil_matrix((rows15d, lay.size))
        for l in range(N):
            for j in range(nv):
                for i in range(u):
                    for ip in range(p):
                        row = ((l * nv + j) * u + i) * p + ip
                        hx = H_x[i] @ Acl_i[ip]
                        A15d[row, lay.z(l)] = hx
                        A15d[row, lay.a(l)] = hx @ Xv[j]
                        A15d[row, lay.v(l)] = H_x[i] @ d.B[ip]
                        A15d[row, lay.lam(l, j, i)] = -H_theta[:, ip]
        prog.AddLinearEqualityConstraint(A15d.tocsc(), np.zeros(rows15d), y
                                         ).evaluator().set_description("(15d) H_x D = Lambda H_theta")

        # terminal set: H_T z_N + h_T α_N <= 1
        r = d.H_T.shape[0]
        AT = sp.lil_matrix((r, lay.size))
        AT[:, lay.z(N)] = d.H_T
        AT[:, lay.a(N)] = np.asarray(d.h_T, float).reshape(-1, 1)
        prog.AddLinearConstraint(AT.tocsc(), np.full(r, -np.inf), np.ones(r), y
                                 ).evaluator().set_description("terminal set (z_N, alpha_N) in Xf")

        # α >= 0 and Λ >= 0
        prog.AddBoundingBoxConstraint(0.0, np.inf, y[lay.a0:lay.a0 + N + 1]).evaluator().set_description("alpha >= 0")
        prog.AddBoundingBoxConstraint(0.0, np.inf, y[lay.L0:]).evaluator().set_description("Lambda >= 0")

        # optional bound lo <= K x_k + v_0 <= hi on the first input (PE two-QP procedure, spec §8);
        # inactive (±inf) unless ``solve`` gets ``u0_bounds``
        self._c_u0 = prog.AddBoundingBoxConstraint(np.full(m, -np.inf), np.full(m, np.inf), y[lay.v(0)]).evaluator()
        self._c_u0.set_description("PE bound on u_0|k")

        self._v_vars = y[lay.v0:lay.L0]
        self._minmax = getattr(d, "cost", "certainty_equivalence") == "minmax"
        if self._minmax:
            self._add_minmax_cost(prog, y, Xv)
            return
        # cost (17) in v only; coefficients set per step
        self._cost = prog.AddQuadraticCost(np.eye(N * m), np.zeros(N * m), 0.0, self._v_vars, is_convex=True).evaluator()
        self._cost.set_description("(17) certainty-equivalence cost")

    def _add_minmax_cost(self, prog, y, Xv) -> None:
        """Min-max cost (19) in epigraph form: minimise Σ_{l=0}^{N} s_l² with, for every vertex j,
        s_l >= ‖(Q^½ x^j_l, R^½ u^j_l)‖ (l < N) and s_N >= ‖P^½ x^j_N‖, x^j_l = z_l + α_l x^j,
        u^j_l = K x^j_l + v_l: then s_l² = max_j (‖x^j_l‖²_Q + ‖u^j_l‖²_R), the stage term of (19).

        Second-order cones (Lorentz) plus a quadratic cost, not rotated cones t_l >= ‖·‖²: the
        rotated form reaches Clarabel as a cone in ((t_l+1)/2, (t_l−1)/2, ·), whose slack t_l − ‖·‖²
        is lost to cancellation against the constant ½ when the cost is small (measured: 21 of 40
        random min-max runs stopped "inaccurate" with it, 7 of those 21 steps with this form before
        the retries of :mod:`.clarabel_retry`)."""
        d, lay = self.data, self.layout
        n, m, N = lay.n, lay.m, lay.N
        s = self._s = prog.NewContinuousVariables(N + 1, "s")
        base = y[:lay.L0]  # [z | α | v]
        nb = lay.L0
        Qh, Rh, Ph = (_sqrtm(np.asarray(M, float)) for M in (d.Q, d.R, d.P))
        for l in range(N + 1):
            for j, xj in enumerate(Xv):
                # x^j_l = z_l + α_l x^j as a matrix on base
                Ex = np.zeros((n, nb))
                Ex[:, lay.z(l)] = np.eye(n)
                Ex[:, lay.a(l)] = xj
                if l < N:
                    Eu = d.K @ Ex
                    Eu[:, lay.v(l)] += np.eye(m)
                    body = np.vstack([Qh @ Ex, Rh @ Eu])
                else:
                    body = Ph @ Ex
                A = np.zeros((body.shape[0] + 1, nb + 1))
                A[0, nb] = 1.0          # s_l
                A[1:, :nb] = body
                prog.AddLorentzConeConstraint(A, np.zeros(A.shape[0]), np.concatenate([base, [s[l]]])
                                              ).evaluator().set_description(f"(19) epigraph s_{l} vertex {j}")
        prog.AddQuadraticCost(2.0 * np.eye(N + 1), np.zeros(N + 1), 0.0, s, is_convex=True
                              ).evaluator().set_description("(19) min-max cost")

    def _preallocate_15c(self) -> sp.csc_matrix:
        """The matrix of (15c) with its Λ block allocated once: [C | kron(I, h_θᵀ)]. Row ρ = (l, j, i)
        of (15c) holds Λ^j_{l|k}[i, :] h_θ in the q columns L0 + ρ·q + r, one entry per column, so in
        CSC order the Λ entries are the last ``rows15c·q`` stored values, in (ρ, r) order; each step
        writes h_θ (or the per-stage offsets) there (:meth:`_matrix_15c`) and nothing is rebuilt."""
        lay = self.layout
        rows, q = self._rows15c, lay.q
        left = self._C15c[:, : lay.L0].tocsc()
        left.sort_indices()
        lam = sp.csc_matrix((np.ones(rows * q), np.repeat(np.arange(rows), q), np.arange(rows * q + 1)),
                            shape=(rows, rows * q))
        A = sp.hstack([left, lam], format="csc")
        self._lam_values = A.data[left.nnz:].reshape(rows, q)  # a view into A.data
        return A

    def _matrix_15c(self, h_theta: np.ndarray) -> sp.csc_matrix:
        """Constraint matrix of (15c) for offsets h_θk (q,), or of (28b) for per-stage offsets
        h_{θ l|k} (N, q) of the predicted sets (26): the rows of stage l (ordered (l, j, i)) get
        Λ^j_{l|k} h_{θ l|k}. Written into the preallocated matrix; returns that matrix."""
        if h_theta.ndim == 1:
            self._lam_values[:] = h_theta
        else:
            per_stage = self.layout.nv * self.layout.u
            self._lam_values.reshape(len(h_theta), per_stage, -1)[:] = h_theta[:, None, :]
        return self._A15c

    # -- solve ---------------------------------------------------------------------------------
    def _solve(self, refine: bool = False):
        """(result, status, solver time, retry note): Clarabel with the retry ladder of
        :mod:`.clarabel_retry`, any other solver once; ``refine``: Clarabel's iterative refinement
        from the first solve (the backend's own options, no :data:`NO_REFINEMENT` try)."""
        def once(extra_options):
            result, elapsed = self._solver.solve(self.prog, extra_options)
            return result, self._solver.status(result), elapsed

        if self._solver.name != "clarabel":
            return (*once(None), "")
        # certainty-equivalence cost: no iterative refinement first (NO_REFINEMENT); the min-max
        # cone program (19) keeps Clarabel's defaults (its stalls are what the ladder is for)
        first = None if (self._minmax or refine) else {k: v for k, v in NO_REFINEMENT.items()
                                                       if k not in self._solver.option_values}
        return solve_with_retries(once, first)

    #: ``solve(..., refine=True)`` is supported (the controller's first fallback for an answer that
    #: fails its checks, amcp_drake.online.controller).
    REFINES = True

    def solve(self, x, h_theta, theta_hat, H_theta=None, u0_bounds=None, refine: bool = False) -> MPCSolution:
        """Solve (20) at x_k with Θ_k = {H_θ θ <= h_theta} and point estimate θ̂_k.

        ``u0_bounds`` = (lo, hi) adds lo <= K x_k + v_{0|k} <= hi (±inf allowed), the PE
        constraint of spec §8. ``refine``: Clarabel with iterative refinement from the start (the
        first try is otherwise without it, :data:`.clarabel_retry.NO_REFINEMENT`). ``h_theta`` may be (N, q): per-stage offsets of the predicted sets (26) (Section 4.1),
        stage l of (15c)/(28b) then uses row l."""
        start = time.perf_counter()
        x = np.asarray(x, float)
        h_theta = np.asarray(h_theta, float)
        theta_hat = np.asarray(theta_hat, float)
        for name, arr in (("x", x), ("h_theta", h_theta), ("theta_hat", theta_hat)):
            if not np.all(np.isfinite(arr)):
                return MPCSolution(SolveStatus.ERROR, None, None, None, None, None, detail=f"non-finite {name}")
        if h_theta.ndim == 2 and h_theta.shape != (self.data.N, self.H_theta.shape[0]):
            return MPCSolution(SolveStatus.ERROR, None, None, None, None, None,
                               detail=f"h_theta has shape {h_theta.shape}, expected (q,) or (N, q)")
        if H_theta is not None and (np.shape(H_theta) != self.H_theta.shape or not np.array_equal(H_theta, self.H_theta)):
            self._build(np.asarray(H_theta, float))
        lay = self.layout
        H_x = np.asarray(self.data.H_x, float)
        self._c15b.set_bounds(np.full(lay.u, -np.inf), -H_x @ x)
        self._c15c.UpdateCoefficients(self._matrix_15c(h_theta), self._lb15c, self._ub15c)
        Kx = self.data.K @ x
        if u0_bounds is None:
            self._c_u0.set_bounds(np.full(lay.m, -np.inf), np.full(lay.m, np.inf))
        else:
            lo, hi = (np.broadcast_to(np.asarray(b, float), (lay.m,)) for b in u0_bounds)
            self._c_u0.set_bounds(lo - Kx, hi - Kx)
        if not self._minmax:
            Hv, g, const = self._cost_model.matrices(x, theta_hat)
            self._cost.UpdateCoefficients(2.0 * Hv, 2.0 * g, const, is_convex=True)
        update_time = time.perf_counter() - start
        result, status, solver_time, detail = self._solve(refine)
        if status is not SolveStatus.OPTIMAL:
            names = infeasible_constraint_names(result, self.prog)
            return MPCSolution(status, None, None, None, None, None, solver_time, update_time, names,
                               detail=f"{result.get_solution_result()} ({detail})" if detail
                               else str(result.get_solution_result()))
        yv = result.get_x_val()[: self.layout.size]  # y first, then the epigraph s of (19) if any
        N, n, m = lay.N, lay.n, lay.m
        z = yv[: lay.a0].reshape(N + 1, n)
        alpha = yv[lay.a0:lay.v0]
        v = yv[lay.v0:lay.L0].reshape(N, m)
        Lam = yv[lay.L0:].reshape(N, lay.nv, lay.u, lay.q)
        vf = v.reshape(-1)
        if self._minmax:
            cost = float(np.sum(result.GetSolution(self._s) ** 2))
        else:
            cost = float(vf @ Hv @ vf + 2 * g @ vf + const)
        return MPCSolution(status, v, z, alpha, Lam, cost, solver_time, update_time, detail=detail)
