"""Experiment, not in the package (issue 16): the plain form (15) of Example 1 with (15d) solved for p of
the q multipliers of each row, against the package's plain form (DrakeTubeMPC), Clarabel without
iterative refinement in both, five random Θ_k.

    python benchmarks/plain_elimination.py

For the box H_θ = [e1; −e1; e2; −e2; e3; −e3], (15d) Λ H_θ = H_x D reads Λ_B − Λ_N = c (B: rows
+e_i, N: rows −e_i, c = H_x D^j_l, linear in z, α, v), so Λ_B = c + Λ_N: Λ_B >= 0 becomes the rows
−c − Λ_N <= 0 and (15c) Λ h = c·h_B + Λ_N·(h_B + h_N). 1 963 variables instead of 3 883, no
equalities. Prints the statuses, max |v_eliminated − v_plain| and the CPU time of each Solve.
"""

import time
import timeit

import numpy as np
import scipy.sparse as sp
from pydrake.solvers import MathematicalProgram

from amcp_drake.backends.clarabel_retry import NO_REFINEMENT
from amcp_drake.backends.condensed_cost import CondensedCost
from amcp_drake.backends.drake_solver import DrakeSolver
from amcp_drake.backends.drake_tube import _Layout
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC

s = lorenzen2019_spec(); dsg = design(s.problem, s.design, backend="drake")
ctrl = AdaptiveMPC(s.problem, dsg, backend="drake", formulation="plain")
d = ctrl.data
ref = ctrl.mpc
H_th = np.asarray(d.H_theta, float); q, p = H_th.shape
assert np.allclose(H_th[0::2], np.eye(p)) and np.allclose(H_th[1::2], -np.eye(p))
B_idx, N_idx = np.arange(0, q, 2), np.arange(1, q, 2)
n, m = d.B0.shape; N = d.N; Xv = np.asarray(d.X0_vertices); H_x = np.asarray(d.H_x); nv, u = len(Xv), len(H_x)
K = d.K; Acl0 = d.A0 + d.B0 @ K; Acl = d.A + d.B @ K
lay = _Layout(n, m, N, nv, u, p)  # Λ_N has p entries per row here (q - p = p for a box)
base = lay.L0
rows = N * nv * u
# G: (rows, p, base) coefficients of c_ρ = H_x D^j_l on [z | α | v]
G = np.zeros((rows, p, base))
C15 = np.zeros((rows, base))  # H_x d^j_l - α_{l+1} part of (15c)
HA0, HB0 = H_x @ Acl0, H_x @ d.B0
for l in range(N):
    for j in range(nv):
        for i in range(u):
            r = (l * nv + j) * u + i
            for ip in range(p):
                hx = H_x[i] @ Acl[ip]
                G[r, ip, lay.z(l)] = hx; G[r, ip, lay.a(l)] = hx @ Xv[j]; G[r, ip, lay.v(l)] = H_x[i] @ d.B[ip]
            C15[r, lay.z(l)] = HA0[i]; C15[r, lay.a(l)] = HA0[i] @ Xv[j]; C15[r, lay.v(l)] = HB0[i]
            C15[r, lay.z(l + 1)] = -H_x[i]; C15[r, lay.a(l + 1)] = -1.0
size = base + rows * p
prog = MathematicalProgram(); y = prog.NewContinuousVariables(size, "y")
c = d.F.shape[0]; FGK = d.F + d.G @ K
A15a = sp.lil_matrix((N * c, size))
for l in range(N):
    rr = slice(l * c, (l + 1) * c); A15a[rr, lay.z(l)] = FGK; A15a[rr, lay.v(l)] = d.G; A15a[rr, lay.a(l)] = d.f_bar.reshape(-1, 1)
prog.AddLinearConstraint(A15a.tocsc(), np.full(N * c, -np.inf), np.ones(N * c), y)
A15b = sp.lil_matrix((u, size)); A15b[:, lay.z(0)] = -H_x; A15b[:, lay.a(0)] = -np.ones((u, 1))
c15b = prog.AddLinearConstraint(A15b.tocsc(), np.full(u, -np.inf), np.zeros(u), y).evaluator()
# Λ_B >= 0: -c_ρ - Λ_N,ρ <= 0  (rows (ρ, ip))
LN = sp.identity(rows * p, format="csc")
AB = sp.hstack([sp.csc_matrix(-G.reshape(rows * p, base)), -LN], format="csc")
prog.AddLinearConstraint(AB, np.full(rows * p, -np.inf), np.zeros(rows * p), y)
# (15c): C15 y + c_ρ·h_B + Λ_N,ρ·(h_B + h_N) <= -w̄: coefficients written per step
def A15c(h):
    hB, hN = h[B_idx], h[N_idx]
    left = C15 + np.einsum("rpb,p->rb", G, hB)
    right = sp.kron(sp.identity(rows), sp.csr_matrix((hB + hN)[None, :]))
    return sp.hstack([sp.csc_matrix(left), right], format="csc")
c15c = prog.AddLinearConstraint(A15c(np.ones(q)), np.full(rows, -np.inf), np.tile(-d.w_bar, N * nv), y).evaluator()
r_ = d.H_T.shape[0]; AT = sp.lil_matrix((r_, size)); AT[:, lay.z(N)] = d.H_T; AT[:, lay.a(N)] = np.asarray(d.h_T).reshape(-1, 1)
prog.AddLinearConstraint(AT.tocsc(), np.full(r_, -np.inf), np.ones(r_), y)
prog.AddBoundingBoxConstraint(0.0, np.inf, y[lay.a0:lay.a0 + N + 1])
prog.AddBoundingBoxConstraint(0.0, np.inf, y[base:])
cost = prog.AddQuadraticCost(np.eye(N * m), np.zeros(N * m), 0.0, y[lay.v0:base], is_convex=True).evaluator()
cm = CondensedCost(d)
solver = DrakeSolver("clarabel", dict(NO_REFINEMENT))
x = np.asarray(s.scenario.x0, float); th = np.asarray(s.problem.theta_hat0, float)
rng = np.random.default_rng(0)
tr, te = [], []
for trial in range(5):
    h = np.asarray(dsg.h_theta0, float) * rng.uniform(0.3, 1.0, q)
    c15b.set_bounds(np.full(u, -np.inf), -H_x @ x)
    c15c.UpdateCoefficients(A15c(h), np.full(rows, -np.inf), np.tile(-d.w_bar, N * nv))
    Hv, g, cc = cm.matrices(x, th)
    cost.UpdateCoefficients(2 * Hv, 2 * g, cc, is_convex=True)
    res, t = solver.solve(prog)
    te_ = min(timeit.repeat(lambda: solver.solve(prog), number=5, repeat=3, timer=time.thread_time)) / 5
    v_e = res.get_x_val()[lay.v0:base]
    sol = ref.solve(x, h, th)
    tr_ = min(timeit.repeat(lambda: ref._solver.solve(ref.prog, dict(NO_REFINEMENT)), number=3, repeat=3, timer=time.thread_time)) / 3
    print(f"h scale trial {trial}: status {res.get_solution_result()} {sol.status}, |v_elim - v_plain| {np.max(np.abs(v_e - sol.v.reshape(-1))):.1e}, "
          f"Solve CPU: eliminated {1e3*te_:.2f} ms, plain {1e3*tr_:.2f} ms")
print("sizes: eliminated", size, "vars; plain", ref.layout.size)
