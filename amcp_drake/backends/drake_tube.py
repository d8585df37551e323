"""The tube MPC QP (20) in Drake: constraints (15a)-(15d), terminal set, cost (17)-(18).

The program is built once per controller with sparse matrix constraints, reduced exactly:

* (15d) is solved for p of the q multipliers of each row (:mod:`.multiplier_basis`): the program
  holds the other q − p (Λ_N >= 0), the rows Λ_B = c M − Λ_N H_N M >= 0, and (15c) in the form
  c κ + Λ_N s + H_x d^j_l − α_{l+1} <= −w̄, with no equality rows for (15d);
* the rows (l, j, i) of (15c) that another vertex of X0 implies on all of Θ0 are left out
  (:mod:`.dominated_rows`; when Θ_k is not inside Θ0, H_θ changes or no Θ0 is given, the step is
  solved by the program with every row, ``prune=False``).

Both keep the feasible set in (z, α, v). Example 1, 8 facets, N = 10: 303 variables instead of
3 883, Clarabel 17 -> 1.6 ms CPU.

(15c) is written in the deviations e_l = z_{l+1} − A_cl(0) z_l − B_0 v_l of the tube centres from the
nominal dynamics (N·n more variables and as many equality rows, the same feasible set in (z, α, v)): a
row of (15c) then reads α_l [H_x A_cl(0) x^j]_i + c κ + Λ_N s − [H_x]_i e_l − α_{l+1} <= −w̄_i, without
the nominal parts [H_x A_cl(0)]_i z_l + [H_x B_0]_i v_l and −[H_x]_i z_{l+1}, which cancel to round-off on
every row and are large where X0 is thin (‖[H_x]_i‖ from 4.8 to 146 on ``mass_chain3``, A_cl(0) near I). Written
with them, the programs of ``mass_chain3``/``mass_chain4`` (n = 6, 8) stalled "AlmostSolved" under
Clarabel settings that vary by machine (see :data:`NOMINAL_DEVIATION_FORM` and docs/decisions.md). Each
row of (15c) is multiplied by ρ/‖[H_x]_i‖, ρ the median of X0's facet norms, so that rows of facets of norm
4.8 and 146 (``mass_chain3``) reach Clarabel at one scale whatever its equilibration does, and the program
does not depend on the state units (a plain 1/‖[H_x]_i‖ brings the rows to the scale of the states: in
mega units, x̃ = 1e8 x, Clarabel then ended NumericalError at every step).

The full Λ is recovered (kept rows from the solution, left-out rows from their own LPs), so the answer
checks and certificates re-check (15c), (15d) and Λ >= 0 on every row as before. Each step updates:

* the right-hand side of (15b) (it holds x_k),
* the (15c) coefficients from h_θk (``LinearConstraint.UpdateCoefficients`` on a preallocated
  matrix whose values are written in place),
* the quadratic cost in v (``QuadraticCost.UpdateCoefficients``), condensed from (18) with θ̂_k.

Decision vector y = [z (N+1)·n | α (N+1) | v N·m | Λ_N (kept rows)·(q−p) | e N·n], Λ_N of the ρ-th kept
row (kept rows in (l, j, i) order) at offset ρ·(q−p) + r.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from amcp_drake.backends.base import Attempt, MPCSolution, TubeMPCData, backend_attempts
from amcp_drake.backends.clarabel_retry import first_try, solve_with_retries
from amcp_drake.backends.condensed_cost import CondensedCost
from amcp_drake.backends.dominated_rows import kept_vertices
from amcp_drake.backends.drake_solver import infeasible_constraint_names, tries_note
from amcp_drake.backends.minmax_cost import minmax_plan_cost
from amcp_drake.backends.multiplier_basis import (
    FeasibleBases,
    MultiplierBasis,
    feasible_bases,
    optimal_multipliers,
)
from amcp_drake.backends.vertex_form import VertexEnumerationError, theta_vertices
from amcp_drake.model.status import SolveStatus

#: A new H_θk (the exact update (7) changes it at most steps) meant a new program (~20-30 ms on campaign
#: seed 13 #6, about half a solve). A program built for a new H_θ holds the next multiple of this many
#: rows; a H_θ with fewer rows is padded with rows 0·θ <= PAD_OFFSET and written into the same program
#: (its multiplier basis and the rows Λ_B >= 0, :meth:`DrakeTubeMPC._set_theta_shape`); it is built
#: again only for more rows than it holds or at least twice this many fewer. The first program holds
#: exactly the design's rows (the updates (9) and the window never change H_θ: not affected). 1: a H_θ
#: with the same number of rows, or one fewer, is written in place. Padding more costs the solver about
#: what it saves: CPU per step on campaign 13 #6 / #139 (median of 5, interleaved, loaded machine) with
#: 1: 59.3 / 31.8 ms, 2: 53.3 / 33.6, 4: 50.5 / 35.1, 8: 54.9 / 41.5. (The cvxpy backend, whose
#: rebuild is a canonicalisation of 0.35-0.6 s, pads to multiples of 8: amcp_reference.tube_mpc.)
ROW_CAPACITY_STEP = 1
#: Offset of a padded row: a padded multiplier λ >= 0 enters (15d) with coefficient 0 and (15c) with
#: PAD_OFFSET > 0, so Λ without the padded columns satisfies (15c)-(15d) whenever the padded Λ does (the
#: program is the same in (z, α, v)); 1 is the scale of the unit rows.
PAD_OFFSET = 1.0
#: Description of the rows e_l = z_{l+1} − A_cl(0) z_l − B_0 v_l that define the deviations used by (15c)
#: (module docstring). Why this form: on ``mass_chain3`` (n = 6, ‖[H_x]_i‖ up to 146) the program with
#: z_{l+1} in (15c) ended "AlmostSolved" (step length collapsing with the dual residual growing from 3e-8
#: to 4e-6 in one iteration) at 1 to 3 of 5 steps under Clarabel settings that emulate another machine
#: (max_step_fraction 0.95, equilibrate_max_iter 5, tolerances 1e-9 with max_iter 400, iterative
#: refinement on): a fallback answered those steps. Fixing z alone made it "Solved" under every one of
#: 9 settings; tie-breaks (ε·Σα, ε·ΣΛ_N, ε‖(z, α, Λ_N)‖² below 1e-4) did not. With e_l and the rows of
#: (15c) divided by ‖[H_x]_i‖: no fallback under 7 settings profiles (10 before). docs/results.md, "The Drake
#: plain form under other Clarabel settings".
NOMINAL_DEVIATION_FORM = "(15c) tube centre deviations e_l = z_{l+1} - A_cl(0) z_l - B_0 v_l"


def _sqrtm(M: np.ndarray) -> np.ndarray:
    vals, vecs = np.linalg.eigh(0.5 * (M + M.T))
    return (vecs * np.sqrt(np.clip(vals, 0.0, None))) @ vecs.T


class _Layout:
    """Offsets of the blocks of the decision vector; ``rows`` rows of (15c) with q multipliers Λ_N each."""

    def __init__(self, n: int, m: int, N: int, nv: int, u: int, q: int, rows: int) -> None:
        self.n, self.m, self.N, self.nv, self.u, self.q = n, m, N, nv, u, q
        self.z0 = 0
        self.a0 = (N + 1) * n
        self.v0 = self.a0 + N + 1
        self.L0 = self.v0 + N * m
        self.e0 = self.L0 + rows * q
        self.size = self.e0 + N * n

    def e(self, l: int) -> slice:
        return slice(self.e0 + l * self.n, self.e0 + (l + 1) * self.n)

    def z(self, l: int) -> slice:
        return slice(self.z0 + l * self.n, self.z0 + (l + 1) * self.n)

    def a(self, l: int) -> int:
        return self.a0 + l

    def v(self, l: int) -> slice:
        return slice(self.v0 + l * self.m, self.v0 + (l + 1) * self.m)


class DrakeTubeMPC:
    """QP (20) built once; :meth:`solve` updates x_k, h_θk, θ̂_k and solves."""

    def __init__(self, data: TubeMPCData, solver, prune: bool = True) -> None:
        self.data = data
        self._solver = solver
        self._prune = prune
        self._all_rows: DrakeTubeMPC | None = None  # the program with every row, on first need
        self._bases_cache: dict[tuple[bytes, bytes], FeasibleBases | None] = {}
        self._cost_model = CondensedCost(data)
        self._build(np.asarray(data.H_theta, float))

    # -- construction ------------------------------------------------------------------------
    def _build(self, H_theta: np.ndarray, capacity: int | None = None) -> None:
        """The program for H_θ; ``capacity``: the number of rows it holds (H_θ padded, see
        ROW_CAPACITY_STEP; then every row of (15c) is kept), default exactly H_θ's."""
        d = self.data
        n, m = d.B0.shape
        N = d.N
        Xv = np.asarray(d.X0_vertices, float)
        H_x = np.asarray(d.H_x, float)
        nv, u = Xv.shape[0], H_x.shape[0]
        q, p = H_theta.shape
        self.H_theta = H_theta
        self._capacity = None if capacity is None else max(int(capacity), q)
        q = q if capacity is None else self._capacity
        K = d.K
        FGK = d.F + d.G @ K
        Acl0 = d.A0 + d.B0 @ K
        Acl_i = d.A + d.B @ K  # (p, n, n)
        #: X0's extent along each state: the unit of the deviation variables (S e_l, see the rows e_l below)
        self._e_extent = np.max(np.abs(Xv), axis=0)
        self.basis = MultiplierBasis.of(self._padded(H_theta, q))
        keep, self._theta0_h = self._kept_vertices(Acl0, Acl_i)
        lay = self.layout = _Layout(n, m, N, nv, u, q - p, N * int(keep.sum()))

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

        # (15c)-(15d) with (15d) solved for p of the q multipliers of each row (.multiplier_basis):
        # Λ_N >= 0 are variables, Λ_B = c M − Λ_N H_N M >= 0 are rows, (15c) reads
        # c κ + Λ_N s + H_x d^j_l − α_{l+1} <= −w̄ with (κ, s) from h_θk, written per step
        self._build_tube_rows(prog, y, Acl0, Acl_i, keep)

        # terminal set: H_T z_N + h_T α_N <= 1
        r = d.H_T.shape[0]
        AT = sp.lil_matrix((r, lay.size))
        AT[:, lay.z(N)] = d.H_T
        AT[:, lay.a(N)] = np.asarray(d.h_T, float).reshape(-1, 1)
        prog.AddLinearConstraint(AT.tocsc(), np.full(r, -np.inf), np.ones(r), y
                                 ).evaluator().set_description("terminal set (z_N, alpha_N) in Xf")

        # α >= 0 and Λ_N >= 0
        prog.AddBoundingBoxConstraint(0.0, np.inf, y[lay.a0:lay.a0 + N + 1]).evaluator().set_description("alpha >= 0")
        prog.AddBoundingBoxConstraint(0.0, np.inf, y[lay.L0:lay.e0]).evaluator().set_description("Lambda >= 0")
        # e_l = z_{l+1} − A_cl(0) z_l − B_0 v_l, the deviations (15c) is written in (module docstring), held in
        # units of X0's extent along each state (the variable is S e_l, S = diag(1 / extent)), so that these rows
        # and (15c), like (15a)-(15b), do not depend on the state units (in x̃ = t x a row in state units mixes
        # coefficients 1 on z and t·B_0 on v, and Clarabel's answers lost their optimality at t = 1e8)
        S = np.diag(1.0 / self._e_extent)
        Ae = sp.lil_matrix((N * n, lay.size))
        for l in range(N):
            rows = slice(l * n, (l + 1) * n)
            Ae[rows, lay.z(l + 1)] = S
            Ae[rows, lay.z(l)] = -S @ Acl0
            Ae[rows, lay.v(l)] = -S @ np.asarray(d.B0, float)
            Ae[rows, lay.e(l)] = -np.eye(n)
        prog.AddLinearEqualityConstraint(Ae.tocsc(), np.zeros(N * n), y).evaluator().set_description(
            NOMINAL_DEVIATION_FORM)

        # optional bound lo <= K x_k + v_0 <= hi on the first input (PE two-QP procedure, docs/explanation/paper.md §8);
        # inactive (±inf) unless ``solve`` gets ``u0_bounds``
        self._c_u0 = prog.AddBoundingBoxConstraint(np.full(m, -np.inf), np.full(m, np.inf), y[lay.v(0)]).evaluator()
        self._c_u0.set_description("PE bound on u_0|k")

        self._v_vars = y[lay.v0:lay.L0]
        if d.minmax:
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
        s = prog.NewContinuousVariables(N + 1, "s")
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

    def _build_tube_rows(self, prog, y, Acl0: np.ndarray, Acl_i: np.ndarray, keep: np.ndarray) -> None:
        """Rows ρ = (l, j, i) of (15c) and of Λ_B >= 0 (.multiplier_basis), vectorised, for the rows
        kept by :func:`.dominated_rows.kept_vertices` (all rows when ``prune`` is off or Θ0 is unknown).

        Each row touches the 2n + m + 2 columns [z_l | α_l | v_l | e_l | α_{l+1}] of y (``_cols``)
        and its own q − p columns of Λ_N. ``_C_vals`` (rows, E) are the coefficients of
        H_x d^j_l − α_{l+1} (15c) in the deviation form (module docstring: zero on z_l and v_l, −[H_x]_i on
        e_l); ``_G_vals`` (rows, E, p) those of c_ρ = H_x D^j_l (zero on e_l, α_{l+1}):
        c_ρ[r] = Σ_e G[ρ, e, r] y[cols[ρ, e]]. The (15c) matrix is preallocated in CSC;
        each step writes C + G κ and s into its data through ``_perm15c`` (nothing is rebuilt)."""
        d, lay, basis = self.data, self.layout, self.basis
        N, nv, u = lay.N, lay.nv, lay.u
        l_all = np.repeat(np.arange(N), nv * u)                 # stage of row ρ = (l·v + j)·u + i
        j_all = np.tile(np.repeat(np.arange(nv), u), N)         # vertex x^j of row ρ
        i_all = np.tile(np.arange(u), N * nv)                   # facet [H_x]_i of row ρ
        kept = keep[i_all, j_all]
        self._kept_rows, self._left_out = np.flatnonzero(kept), np.flatnonzero(~kept)
        self._stage_of_row, self._stage_left_out = l_all[kept], l_all[~kept]
        self._cols, self._C_vals, self._G_vals = self._row_coefficients(l_all[kept], j_all[kept], i_all[kept], Acl0, Acl_i)
        self._E_c = lay.n + 1 + lay.m                           # c_ρ lives on [z_l | α_l | v_l]
        if len(self._left_out):
            cols, _, G = self._row_coefficients(l_all[~kept], j_all[~kept], i_all[~kept], Acl0, Acl_i)
            self._cols_left_out, self._G_left_out = cols[:, :self._E_c], G[:, :self._E_c]
        rows = self._rows15c = len(self._kept_rows)
        qn = lay.q
        E = self._cols.shape[1]
        lam_cols = lay.L0 + np.arange(rows * qn).reshape(rows, qn)
        # (15c): base entries then Λ_N entries, in this order in ``values``; CSC order via _perm15c
        r15 = np.concatenate([np.repeat(np.arange(rows), E), np.repeat(np.arange(rows), qn)])
        c15 = np.concatenate([self._cols.ravel(), lam_cols.ravel()])
        A = sp.csc_matrix((np.arange(1.0, len(r15) + 1.0), (r15, c15)), shape=(rows, lay.size))
        A.sort_indices()
        self._perm15c = A.data.astype(np.int64) - 1
        self._A15c = A
        # each row of (15c) scaled by ρ/‖[H_x]_i‖, ρ the median facet norm (module docstring): the rows reach
        # Clarabel at one scale, and the program is the same in any state units (x̃ = t x scales every norm by 1/t)
        norms = np.linalg.norm(np.asarray(d.H_x, float), axis=1)
        self._scale15c = float(np.median(norms)) / norms[i_all[kept]]
        self._ub15c = -np.asarray(d.w_bar, float)[i_all[kept]] * self._scale15c
        self._lb15c = np.full(rows, -np.inf)
        self._c15c = prog.AddLinearConstraint(self._matrix_15c(np.zeros(basis.q)), self._lb15c, self._ub15c, y
                                              ).evaluator()
        self._c15c.set_description("(15c) tube propagation with multipliers")
        # Λ_B >= 0 as −c_ρ M + Λ_N H_N M <= 0, rows (ρ, b): coefficients fixed for a basis (written
        # again in place by _set_theta_shape); CSC order of the values via _perm_b, as for (15c)
        p = len(basis.basic)
        E_c = self._E_c
        rb = np.arange(rows * p).reshape(rows, p)
        r_b = np.concatenate([np.broadcast_to(rb[:, None, :], (rows, E_c, p)).ravel(),
                              np.broadcast_to(rb[:, None, :], (rows, qn, p)).ravel()])
        c_b = np.concatenate([np.broadcast_to(self._cols[:, :E_c, None], (rows, E_c, p)).ravel(),
                              np.broadcast_to(lam_cols[:, :, None], (rows, qn, p)).ravel()])
        AB = sp.csc_matrix((np.arange(1.0, len(r_b) + 1.0), (r_b, c_b)), shape=(rows * p, lay.size))
        AB.sort_indices()
        self._perm_b = AB.data.astype(np.int64) - 1
        self._AB = AB
        self._bounds_b = (np.full(rows * p, -np.inf), np.zeros(rows * p))
        # the same description as Λ_N >= 0: together they are Λ >= 0 of (15c)-(15d) ((15d) holds by
        # construction), and the property suite's mutant "tube_lambda_nonneg_dropped" drops both
        self._c_basis = prog.AddLinearConstraint(self._matrix_basis_rows(), *self._bounds_b, y).evaluator()
        self._c_basis.set_description("Lambda >= 0")

    def _matrix_basis_rows(self) -> sp.csc_matrix:
        """The matrix of the rows Λ_B = c M − Λ_N H_N M >= 0 for the current basis (−G M on [z | α | v],
        H_N M on Λ_N), written into the preallocated matrix; returns that matrix."""
        rows, qn, basis = self._rows15c, self.layout.q, self.basis
        GM = -(self._G_vals[:, :self._E_c] @ basis.M)          # (rows, E_c, p)
        HNM = np.broadcast_to(basis.HNM[None], (rows, qn, basis.HNM.shape[1]))
        self._AB.data[:] = np.concatenate([GM.ravel(), HNM.ravel()])[self._perm_b]
        return self._AB

    @staticmethod
    def _padded(H_theta: np.ndarray, rows: int) -> np.ndarray:
        """H_θ with rows of zeros appended up to ``rows`` (ROW_CAPACITY_STEP)."""
        pad = rows - H_theta.shape[0]
        return H_theta if pad == 0 else np.vstack([H_theta, np.zeros((pad, H_theta.shape[1]))])

    def _padded_offsets(self, h_theta: np.ndarray) -> np.ndarray:
        """h_θ (q,) or (N, q) with PAD_OFFSET appended for the padded rows."""
        pad = self.basis.q - self.H_theta.shape[0]
        if pad == 0:
            return h_theta
        return np.concatenate([h_theta, np.full(np.shape(h_theta)[:-1] + (pad,), PAD_OFFSET)], axis=-1)

    def _set_theta_shape(self, H_theta: np.ndarray) -> None:
        """Solve with another H_θ from now on: written into the program when it holds a capacity of
        rows (ROW_CAPACITY_STEP) and H_θ fits, else a program built for it (with room to grow)."""
        q = H_theta.shape[0]
        cap = self._capacity
        if cap is not None and H_theta.shape[1] == self.H_theta.shape[1] and cap - 2 * ROW_CAPACITY_STEP < q <= cap:
            basis = MultiplierBasis.of(self._padded(H_theta, cap))
            self.H_theta, self.basis = H_theta, basis
            self._c_basis.UpdateCoefficients(self._matrix_basis_rows(), *self._bounds_b)
            return
        self._build(H_theta, ROW_CAPACITY_STEP * -(-q // ROW_CAPACITY_STEP))

    def _kept_vertices(self, Acl0: np.ndarray, Acl_i: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(mask (u, v) of the rows (l, j, i) kept, h_θ0 the pruning was made for) (:mod:`.dominated_rows`):
        all rows and None unless ``prune`` is on, Θ0 is known (``TubeMPCData.h_theta0``) and the
        program is built for its shape."""
        d = self.data
        all_rows = np.ones((len(d.H_x), len(d.X0_vertices)), dtype=bool)
        h0 = getattr(d, "h_theta0", None)
        if (not self._prune or h0 is None or self._capacity is not None
                or not np.array_equal(self.H_theta, np.asarray(d.H_theta, float))):
            return all_rows, None
        try:
            theta0_vertices = theta_vertices(self.H_theta, np.asarray(h0, float))
        except VertexEnumerationError:
            return all_rows, None
        return kept_vertices(d.H_x, Acl0, Acl_i, d.X0_vertices, theta0_vertices), np.asarray(h0, float)

    def _row_coefficients(self, l_of, j_of, i_of, Acl0, Acl_i) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cols (r, E), C (r, E), G (r, E, p)) of the rows (l_of, j_of, i_of) (see _build_tube_rows)."""
        d, lay = self.data, self.layout
        n, m = lay.n, lay.m
        Xv = np.asarray(d.X0_vertices, float)
        H_x = np.asarray(d.H_x, float)
        rows = len(l_of)
        cols = np.concatenate([lay.z0 + l_of[:, None] * n + np.arange(n), (lay.a0 + l_of)[:, None],
                               lay.v0 + l_of[:, None] * m + np.arange(m),
                               lay.e0 + l_of[:, None] * n + np.arange(n), (lay.a0 + l_of + 1)[:, None]],
                              axis=1)                          # (rows, E), E = 2n + m + 2
        # [H_x A_cl(0)]_i (z_l + α_l x^j) + [H_x B_0]_i v_l − [H_x]_i z_{l+1} = α_l [H_x A_cl(0) x^j]_i − [H_x]_i e_l
        HA0 = H_x @ Acl0
        C = np.concatenate([np.zeros((rows, n)), (HA0 @ Xv.T)[i_of, j_of][:, None], np.zeros((rows, m)),
                            -(H_x * self._e_extent)[i_of], -np.ones((rows, 1))], axis=1)
        Gz = np.einsum("ia,pab->ibp", H_x, Acl_i)              # (u, n, p): [H_x]_i A_cl,r
        Gv = np.einsum("ia,pab->ibp", H_x, np.asarray(d.B, float))  # (u, m, p): [H_x]_i B_r
        G = np.zeros((rows, cols.shape[1], Gz.shape[2]))
        G[:, :n] = Gz[i_of]
        G[:, n] = np.einsum("rbp,rb->rp", Gz[i_of], Xv[j_of])  # [H_x]_i A_cl,r x^j on α_l
        G[:, n + 1:n + 1 + m] = Gv[i_of]
        return cols, C, G

    def _matrix_15c(self, h_theta: np.ndarray) -> sp.csc_matrix:
        """Constraint matrix of (15c) for offsets h_θk (q,), or of (28b) for per-stage offsets
        h_{θ l|k} (N, q) of the predicted sets (26) (row ρ of stage l uses row l): coefficients
        C + G κ on [z | α | v] and s on Λ_N, (κ, s) = ``basis.offsets(h)``. Written into the
        preallocated matrix; returns that matrix."""
        kappa, slack = self.basis.offsets(self._padded_offsets(h_theta))
        if np.ndim(h_theta) == 2:
            kappa, slack = kappa[self._stage_of_row], slack[self._stage_of_row]
            base = self._C_vals + np.einsum("rep,rp->re", self._G_vals, kappa)
            lam = slack * self._scale15c[:, None]
        else:
            base = self._C_vals + self._G_vals @ kappa
            lam = slack[None, :] * self._scale15c[:, None]
        base = base * self._scale15c[:, None]
        self._A15c.data[:] = np.concatenate([base.ravel(), lam.ravel()])[self._perm15c]
        return self._A15c

    def _multipliers(self, yv: np.ndarray, h_theta: np.ndarray) -> np.ndarray | None:
        """Λ (N, v, u, q) of (15c)-(15d) from the solution: on kept rows Λ_N read and
        Λ_B = c M − Λ_N H_N M; on left-out rows the optimal multipliers of the row's own LP
        (:func:`.multiplier_basis.optimal_multipliers`, per stage for per-stage offsets). None when
        those cannot be found (the caller solves the program with every row)."""
        lay = self.layout
        E = self._E_c
        q = self.basis.q
        c = np.einsum("re,rep->rp", yv[self._cols[:, :E]], self._G_vals[:, :E])
        lam_n = yv[lay.L0:lay.e0].reshape(self._rows15c, lay.q)
        lam = np.empty((lay.N * lay.nv * lay.u, q))
        lam[self._kept_rows] = self.basis.full(c, lam_n)
        lam = lam[:, :self.H_theta.shape[0]]  # without the padded columns (PAD_OFFSET)
        if len(self._left_out):
            c_out = np.einsum("re,rep->rp", yv[self._cols_left_out], self._G_left_out)
            stages = [slice(None)] if np.ndim(h_theta) == 1 else range(lay.N)
            for stage in stages:
                rows = slice(None) if np.ndim(h_theta) == 1 else self._stage_left_out == stage
                h = h_theta if np.ndim(h_theta) == 1 else h_theta[stage]
                found = optimal_multipliers(self.H_theta, h, c_out[rows], self._bases_of(h))
                if found is None:
                    return None
                lam[self._left_out[rows]] = found
        return lam.reshape(lay.N, lay.nv, lay.u, self.H_theta.shape[0])

    def _bases_of(self, h: np.ndarray) -> FeasibleBases | None:
        """:func:`.multiplier_basis.feasible_bases` of (H_θ, h), reused while h is the same to the bit
        (Θ_k unchanged, most steps once it has settled; per-stage offsets keep one entry per stage)."""
        key = (h.tobytes(), self.H_theta.tobytes())
        cache = self._bases_cache
        if key not in cache:
            if len(cache) > self.layout.N:
                cache.clear()
            cache[key] = feasible_bases(self.H_theta, h)
        return cache[key]

    # -- solve ---------------------------------------------------------------------------------
    #: Θ_k ⊆ Θ0 is taken to hold when h_θk <= h_θ0 + THETA0_TOL·max(1, |h_θ0|) row-wise (same H_θ):
    #: the set updates keep Θ_k nested to rounding (answer_checks.SET_NESTED_TOL bounds the rest);
    #: a row left out is then implied up to α_l·‖∇g‖·THETA0_TOL, far below the answer checks' 1e-6.
    THETA0_TOL = 1e-9

    def _inside_theta0(self, h_theta: np.ndarray) -> bool:
        h0 = self._theta0_h
        return h0 is not None and bool(np.all(h_theta <= h0 + self.THETA0_TOL * np.maximum(1.0, np.abs(h0))))

    def _with_every_row(self, x, h_theta, theta_hat, H_theta, u0_bounds, refine, why: str) -> MPCSolution:
        """The step solved by the program with every row of (15c) (built on first need)."""
        from dataclasses import replace

        if self._all_rows is None:
            self._all_rows = DrakeTubeMPC(self.data, self._solver, prune=False)
        sol = self._all_rows.solve(x, h_theta, theta_hat, H_theta, u0_bounds=u0_bounds, refine=refine)
        return replace(sol, detail=f"every row of (15c): {why}; {sol.detail}".rstrip("; "),
                       attempts=(Attempt("tube_qp", "every_row", sol.status), *sol.attempts))

    def _solve(self, refine: bool = False):
        """(result, status, solver time, retry note, re-solves as (rung, options)): Clarabel with the retry ladder of
        :mod:`.clarabel_retry`, any other solver once; ``refine``: Clarabel's iterative refinement
        from the first solve (the backend's own options, no :data:`NO_REFINEMENT` try)."""
        not_solved: list[str] = []  # what each try that did not end "optimal" returned (tries_note)

        def once(extra_options):
            result, elapsed = self._solver.solve(self.prog, extra_options)
            status = self._solver.status(result)
            if status is not SolveStatus.OPTIMAL:
                not_solved.append(self._solver.describe(result))
            return result, status, elapsed

        if self._solver.name != "clarabel":
            return (*once(None), "", ())
        # the first try of both backends (clarabel_retry.first_try), then Clarabel's defaults and the ladder
        result, status, elapsed, note, rungs = solve_with_retries(once, *first_try(self.data.minmax, refine,
                                                                                     self._solver.option_values))
        return result, status, elapsed, "; ".join(t for t in (note, tries_note(not_solved)) if t), rungs

    #: ``solve(..., refine=True)`` is supported (the controller's first fallback for an answer that
    #: fails its checks, amcp_drake.online.controller).
    REFINES = True
    #: the formulation of (20) this program solves (the protocol's ``TubeMPCSolver.formulation``)
    formulation = "plain"

    def solve(self, x, h_theta, theta_hat, H_theta=None, u0_bounds=None, refine: bool = False) -> MPCSolution:
        """Solve (20) at x_k with Θ_k = {H_θ θ <= h_theta} and point estimate θ̂_k.

        ``u0_bounds`` = (lo, hi) adds lo <= K x_k + v_{0|k} <= hi (±inf allowed), the PE
        constraint of docs/explanation/paper.md §8. ``refine``: Clarabel with iterative refinement from the start (the
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
            self._set_theta_shape(np.asarray(H_theta, float))
        if len(self._left_out) and not self._inside_theta0(h_theta):
            return self._with_every_row(x, h_theta, theta_hat, H_theta, u0_bounds, refine,
                                        "Theta_k not inside Theta_0, the rows left out of (15c) may be needed")
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
        if not self.data.minmax:
            Hv, g, const = self._cost_model.matrices(x, theta_hat)
            self._cost.UpdateCoefficients(2.0 * Hv, 2.0 * g, const, is_convex=True)
        update_time = time.perf_counter() - start
        result, status, solver_time, detail, rungs = self._solve(refine)
        if status is not SolveStatus.OPTIMAL:
            names = infeasible_constraint_names(result, self.prog)
            return MPCSolution(status, None, None, None, None, None, solver_time, update_time, names,
                               detail=f"{self._solver.describe(result)} ({detail})" if detail
                               else self._solver.describe(result), attempts=backend_attempts(rungs, status))
        yv = result.get_x_val()[: self.layout.size]  # y first, then the epigraph s of (19) if any
        N, n, m = lay.N, lay.n, lay.m
        z = yv[: lay.a0].reshape(N + 1, n)
        alpha = yv[lay.a0:lay.v0]
        v = yv[lay.v0:lay.L0].reshape(N, m)
        Lam = self._multipliers(yv, h_theta)
        if Lam is None:
            return self._with_every_row(x, h_theta, theta_hat, H_theta, u0_bounds, refine,
                                        "no optimal multipliers found for the rows left out of (15c)")
        vf = v.reshape(-1)
        if self.data.minmax:  # (19) of the plan, not the solver's Σ s_l² (see .minmax_cost)
            cost = minmax_plan_cost(self.data, z, alpha, v)
        else:
            cost = float(vf @ Hv @ vf + 2 * g @ vf + const)
        return MPCSolution(status, v, z, alpha, Lam, cost, solver_time, update_time, detail=detail,
                           attempts=backend_attempts(rungs, status))
