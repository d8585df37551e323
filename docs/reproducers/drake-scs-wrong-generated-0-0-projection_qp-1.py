#!/usr/bin/env python3
"drake:scs (default settings) on one problem of the amcp-drake solver corpus: wrong.\n\nProblem generated-0-0-projection_qp-1: projection_qp (12), QP, 1 variables, 2 rows:\n    minimise 1/2 x'Px + q'x + r  s.t.  lower <= A x <= upper,  lb <= x <= ub,  mat(g0 + G x) PSD\nSeen: success reported but infeasible by 3.04e-06 (tol 1e-06)\nThe reference answer is verified (KKT residuals below 1e-7; an LP's optimal basis in exact rational\narithmetic; an infeasible problem by a Farkas certificate).\nExit 3: reproduces; 0: does not; 4: a package is missing (any other ending is an error of the script, not a finding). Needs numpy, scipy and pydrake only.\n"
import json

DATA = json.loads('{"format":"amcp-solver-corpus","version":1,"id":"generated-0-0-projection_qp-1","kind":"projection_qp","equation":"(12)","class":"qp","n":1,"objective":{"P":{"shape":[1,1],"row":[0],"col":[0],"val":[2.0]},"q":[0.0],"r":0.0},"linear":{"A":{"shape":[2,1],"row":[0,1],"col":[0,0],"val":[1.0,-1.0]},"lower":[null,null],"upper":[-1.0,4.300633114690164]},"bounds":{"lower":[null],"upper":[null]},"lmi":[],"reference":{"status":"optimal","objective":1.0000000000368128,"x":[-1.0000000000184064]}}')
FEAS_TOL, OPT_TOL = 1e-06, 1e-06
CRASH_ONLY = False
SOLVER_CLASS = 'ScsSolver'
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
    import pydrake
    from pydrake.solvers import MathematicalProgram, SolverOptions
    import pydrake.solvers as ds
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(4)
from importlib.metadata import version
print(f"drake {version('drake')}, numpy {np.__version__}, python {sys.version.split()[0]}")
for arr in (q, A.data, *(G.data for _, G, _ in LMIS)):
    assert np.all(np.isfinite(arr)), "Drake aborts the process on a non-finite coefficient"
prog = MathematicalProgram()
x = prog.NewContinuousVariables(n, "x")
if P is not None and P.nnz:
    prog.AddQuadraticCost(P.toarray(), q, r, x, is_convex=True)
else:
    prog.AddLinearCost(q, r, x)
if A.shape[0]:
    prog.AddLinearConstraint(sp.csc_matrix(A), lower, upper, x)
if np.isfinite(lb).any() or np.isfinite(ub).any():
    prog.AddBoundingBoxConstraint(lb, ub, x)
for s, G, g0 in LMIS:
    cols = np.unique(G.nonzero()[1])
    F = [g0.reshape(s, s, order="F")] + [G.tocsc()[:, j].toarray().reshape(s, s, order="F") for j in cols]
    prog.AddLinearMatrixInequalityConstraint([0.5 * (M + M.T) for M in F], x[cols])
solver = getattr(ds, SOLVER_CLASS)()
options = SolverOptions()
for key, value in OPTIONS.items():
    options.SetOption(solver.solver_id(), key, value)
try:
    result = solver.Solve(prog, None, options)
except BaseException as exc:
    print(f"REPRODUCES: the solve raised {type(exc).__name__}: {exc}")
    sys.exit(3)
status = str(result.get_solution_result())
details = getattr(result.get_solver_details(), "status", None)
judge(result.is_success(), status + ("" if details is None else f" ({details})"), result.GetSolution(x))
