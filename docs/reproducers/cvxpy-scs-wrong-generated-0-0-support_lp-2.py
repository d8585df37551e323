#!/usr/bin/env python3
"cvxpy:SCS (default settings) on one problem of the amcp-drake solver corpus: wrong.\n\nProblem generated-0-0-support_lp-2: support_lp (14), A.1, LP, 1 variables, 2 rows:\n    minimise 1/2 x'Px + q'x + r  s.t.  lower <= A x <= upper,  lb <= x <= ub,  mat(g0 + G x) PSD\nSeen: success reported but suboptimal by 2.04e-06 (tol 1e-06)\nThe reference answer is verified (KKT residuals below 1e-7; an LP's optimal basis in exact rational\narithmetic; an infeasible problem by a Farkas certificate).\nExit 3: reproduces; 0: does not; 4: a package is missing (any other ending is an error of the script, not a finding). Needs numpy, scipy and cvxpy only.\n"
import json

DATA = json.loads('{"format":"amcp-solver-corpus","version":1,"id":"generated-0-0-support_lp-2","kind":"support_lp","equation":"(14), A.1","class":"lp","n":1,"objective":{"P":null,"q":[-1.0],"r":0.0},"linear":{"A":{"shape":[2,1],"row":[0,1],"col":[0,0],"val":[1.0,-1.0]},"lower":[null,null],"upper":[0.3,0.4]},"bounds":{"lower":[null],"upper":[null]},"lmi":[],"reference":{"status":"optimal","objective":-0.3,"x":[0.3]}}')
FEAS_TOL, OPT_TOL = 1e-06, 1e-06
CRASH_ONLY = False
SOLVER = 'SCS'
OPTIONS = {}

import json, sys
import numpy as np
import scipy.sparse as sp

def sparse(d):
    return sp.csr_matrix((d["val"], (d["row"], d["col"])), shape=tuple(d["shape"]))

def vec(v, fill):
    return np.array([fill if a is None else a for a in v], float)

P = None if DATA["objective"]["P"] is None else sparse(DATA["objective"]["P"])
q, r = np.array(DATA["objective"]["q"], float), float(DATA["objective"]["r"])
A = sparse(DATA["linear"]["A"])
lower, upper = vec(DATA["linear"]["lower"], -np.inf), vec(DATA["linear"]["upper"], np.inf)
lb, ub = vec(DATA["bounds"]["lower"], -np.inf), vec(DATA["bounds"]["upper"], np.inf)
LMIS = [(b["size"], sparse(b["G"]), np.array(b["g0"], float)) for b in DATA["lmi"]]
n = q.size

def objective(x):
    return float(q @ x + r + (0.0 if P is None else 0.5 * x @ (P @ x)))

def violation(x):
    """largest violation, each row relative to 1 + |bound|; an LMI: -lambda_min / (1 + max|g0|)"""
    worst, Ax = 0.0, A @ x
    for val, bnd, sgn in ((Ax, upper, 1), (Ax, lower, -1), (x, ub, 1), (x, lb, -1)):
        f = np.isfinite(bnd)
        if f.any():
            worst = max(worst, float(np.max(sgn * (val[f] - bnd[f]) / (1 + np.abs(bnd[f])), initial=0.0)))
    for s, G, g0 in LMIS:
        M = (g0 + G @ x).reshape(s, s, order="F")
        worst = max(worst, -float(np.linalg.eigvalsh(0.5 * (M + M.T))[0]) / (1 + float(np.max(np.abs(g0)))))
    return worst

def judge(success, status, x):
    ref = DATA["reference"]
    print(f"solver status: {status} (success reported: {success})")
    if CRASH_ONLY:
        print(f"does not reproduce: the solve returned the status {status}, without an exception or an abort")
        sys.exit(0)
    if ref["status"] == "infeasible":
        if success:
            print(f"REPRODUCES: success reported on a problem with a verified infeasibility certificate")
            sys.exit(3)
        print("does not reproduce: no success reported on the infeasible problem")
        sys.exit(0)
    if not success:
        print("does not reproduce: no success reported (an honest failure, not a wrong answer)")
        sys.exit(0)
    if x is None or not np.all(np.isfinite(x)):
        print("REPRODUCES: success reported without a finite solution")
        sys.exit(3)
    x = np.asarray(x, float)
    viol = violation(x)
    gap = (objective(x) - ref["objective"]) / (1 + abs(ref["objective"]))
    print(f"violation {viol:.3e} (tol {FEAS_TOL:g}); objective {objective(x):.12g} vs verified optimum "
          f"{ref['objective']:.12g}: relative gap {gap:.3e} (tol {OPT_TOL:g}); "
          f"max |x - x_ref| = {np.max(np.abs(x - np.array(ref['x']))):.3e}")
    if viol > FEAS_TOL or gap > OPT_TOL:
        print("REPRODUCES: success reported but the answer is " + " and ".join(
            t for t, bad in (("infeasible", viol > FEAS_TOL), ("suboptimal", gap > OPT_TOL)) if bad))
        sys.exit(3)
    print("does not reproduce: the answer is feasible and optimal within the tolerances")
    sys.exit(0)

try:
    import cvxpy as cp
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(4)
from importlib.metadata import PackageNotFoundError, version
vs = []
for pkg in ("cvxpy", "clarabel", "osqp", "scs", "ecos", "daqp", "piqp", "highspy", "proxsuite"):
    try:
        vs.append(f"{pkg} {version(pkg)}")
    except PackageNotFoundError:
        pass
print(", ".join(vs) + f", numpy {np.__version__}, python {sys.version.split()[0]}")
if SOLVER not in cp.installed_solvers():
    print(f"cannot run: cvxpy solver {SOLVER} not installed")
    sys.exit(4)
x = cp.Variable(n)
obj = q @ x + r + (0 if P is None or not P.nnz else 0.5 * cp.quad_form(x, cp.psd_wrap(P)))
cons = []
for M, lo, up in ((A, lower, upper), (None, lb, ub)):
    if M is not None and M.shape[0] == 0:
        continue
    eq = np.isfinite(lo) & np.isfinite(up) & (lo == up)
    for mask, bnd, op in ((eq, up, "=="), (np.isfinite(up) & ~eq, up, "<="), (np.isfinite(lo) & ~eq, lo, ">=")):
        idx = np.flatnonzero(mask)
        if idx.size:
            e = M[idx] @ x if M is not None else x[idx]
            cons.append(e == bnd[idx] if op == "==" else (e <= bnd[idx] if op == "<=" else e >= bnd[idx]))
for s, G, g0 in LMIS:
    Mx = cp.reshape(G @ x + g0, (s, s), order="F")
    cons.append(0.5 * (Mx + Mx.T) >> 0)
prob = cp.Problem(cp.Minimize(obj), cons)
try:
    prob.solve(solver=SOLVER, **OPTIONS)
except cp.error.SolverError as exc:
    judge(False, f"SolverError: {exc}", None)
except BaseException as exc:
    print(f"REPRODUCES: the solve raised {type(exc).__name__}: {exc}")
    sys.exit(3)
judge(prob.status == "optimal", prob.status, x.value)
