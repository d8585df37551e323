"""Standalone reproducers of the matrix's wrong answers and crashes, and their re-check.

For every (solver configuration, verdict) with verdict ``wrong`` or ``crash``, the smallest corpus
problem that shows it (:attr:`.corpus.CorpusProblem.size`) is written out as one self-contained
script: pure pydrake or pure cvxpy with numpy/scipy, the problem's data inline, nothing from this
project. It prints the installed versions and what is wrong, and exits 1 when the defect reproduces,
0 when it does not, 3 when a package it needs is missing (an abort or a panic ends it by a signal or an
uncaught exception, which :func:`recheck` counts as reproduced). A crash's script reproduces only by
an exception or an abort; a status returned is "does not reproduce", whatever the answer.

:func:`recheck` runs every ``*.py`` of a folder in a child process with a time limit and says which
still reproduce on the installed versions.
"""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from amcp_drake.studies.solver_matrix.corpus import CorpusProblem, write_text_atomic
from amcp_drake.studies.solver_matrix.runner import TOLERANCES, MatrixRun
from amcp_drake.studies.solver_matrix.solvers import CVXPY_TIGHT, DRAKE_SOLVERS, DRAKE_TIGHT

#: Exit codes of a reproducer.
REPRODUCES, DOES_NOT, MISSING = 1, 0, 3
#: Seconds a reproducer may run in :func:`recheck`.
RECHECK_TIME_LIMIT = 120.0

_COMMON = r'''
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
            sys.exit(1)
        print("does not reproduce: no success reported on the infeasible problem")
        sys.exit(0)
    if not success:
        print("does not reproduce: no success reported (an honest failure, not a wrong answer)")
        sys.exit(0)
    if x is None or not np.all(np.isfinite(x)):
        print("REPRODUCES: success reported without a finite solution")
        sys.exit(1)
    x = np.asarray(x, float)
    viol = violation(x)
    gap = (objective(x) - ref["objective"]) / (1 + abs(ref["objective"]))
    print(f"violation {viol:.3e} (tol {FEAS_TOL:g}); objective {objective(x):.12g} vs verified optimum "
          f"{ref['objective']:.12g}: relative gap {gap:.3e} (tol {OPT_TOL:g}); "
          f"max |x - x_ref| = {np.max(np.abs(x - np.array(ref['x']))):.3e}")
    if viol > FEAS_TOL or gap > OPT_TOL:
        print("REPRODUCES: success reported but the answer is " + " and ".join(
            t for t, bad in (("infeasible", viol > FEAS_TOL), ("suboptimal", gap > OPT_TOL)) if bad))
        sys.exit(1)
    print("does not reproduce: the answer is feasible and optimal within the tolerances")
    sys.exit(0)
'''

_DRAKE = r'''
try:
    import pydrake
    from pydrake.solvers import MathematicalProgram, SolverOptions
    import pydrake.solvers as ds
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(3)
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
    sys.exit(1)
status = str(result.get_solution_result())
details = getattr(result.get_solver_details(), "status", None)
judge(result.is_success(), status + ("" if details is None else f" ({details})"), result.GetSolution(x))
'''

_CVXPY = r'''
try:
    import cvxpy as cp
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(3)
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
    sys.exit(3)
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
    sys.exit(1)
judge(prob.status == "optimal", prob.status, x.value)
'''


@dataclass
class Reproducer:
    solver: str
    verdict: str
    problem: str
    path: Path


def script_text(pr: CorpusProblem, solver: str, settings: str, verdict: str, detail: str) -> str:
    """The standalone script of ``solver`` on ``pr`` (see the module docstring)."""
    stack, _, name = solver.partition(":")
    data = {k: v for k, v in pr.to_dict().items() if k not in ("provenance",)}
    data["reference"] = {k: pr.reference.get(k) for k in ("status", "objective", "x") if k in pr.reference}
    tol = TOLERANCES[settings]
    if stack == "drake":
        options = DRAKE_TIGHT.get(name, {}) if settings == "tight" else {}
        head = f"SOLVER_CLASS = {DRAKE_SOLVERS[name]!r}\nOPTIONS = {options!r}\n"
        body = _DRAKE
    elif stack == "cvxpy":
        options = CVXPY_TIGHT.get(name, {}) if settings == "tight" else {}
        head = f"SOLVER = {name!r}\nOPTIONS = {options!r}\n"
        body = _CVXPY
    else:
        raise ValueError(f"no standalone reproducer for {solver!r} (drake:* and cvxpy:* only)")
    doc = (f'"""{solver} ({settings} settings) on one problem of the amcp-drake solver corpus: {verdict}.\n\n'
           f"Problem {pr.id}: {pr.kind} {pr.equation}, {pr.problem_class.upper()}, {pr.n} variables, {pr.A.shape[0]} rows"
           f"{', ' + str(len(pr.lmis)) + ' LMI block(s)' if pr.lmis else ''}:\n"
           "    minimise 1/2 x'Px + q'x + r  s.t.  lower <= A x <= upper,  lb <= x <= ub,  mat(g0 + G x) PSD\n"
           f"Seen: {detail[:300]}\n"
           + ("Only a crash counts (an exception or an abort); the answer returned is not judged.\n" if verdict == "crash" else
              "The reference answer is verified (KKT residuals below 1e-7; an LP's optimal basis in exact rational\n"
              "arithmetic; an infeasible problem by a Farkas certificate).\n")
           + "Exit 1: reproduces; 0: does not; 3: a package is missing. Needs numpy, scipy and "
           f"{'pydrake' if stack == 'drake' else 'cvxpy'} only.\n"
           '"""\n')
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False)
    return (f"#!/usr/bin/env python3\n{doc}import json\n\nDATA = json.loads(r'''{payload}''')\n"
            f"FEAS_TOL, OPT_TOL = {tol['feas']!r}, {tol['opt']!r}\nCRASH_ONLY = {verdict == 'crash'!r}\n"
            f"{head}{_COMMON}{body}")


def write_reproducers(run: MatrixRun, out_dir: Path) -> list[Reproducer]:
    """One script per (solver, wrong|crash): the smallest problem showing it; with a Drake configuration
    also :data:`NONFINITE_SCRIPT` (a NaN coefficient, which no corpus file can hold)."""
    problems = {p.id: p for p in run.problems}
    chosen: dict[tuple[str, str], Any] = {}
    for cell in run.cells:
        if cell.verdict not in ("wrong", "crash") or cell.solver.split(":", 1)[0] not in ("drake", "cvxpy"):
            continue
        key = (cell.solver, cell.verdict)
        if key not in chosen or problems[cell.problem].size < problems[chosen[key].problem].size:
            chosen[key] = cell
    out = []
    if any(c.split(":", 1)[0] == "drake" for c in run.configurations):
        out.append(Reproducer("drake", "crash", "(none: NaN coefficient)",
                              write_text_atomic(out_dir / NONFINITE_NAME, NONFINITE_SCRIPT)))
    for (solver, verdict), cell in sorted(chosen.items()):
        pr = problems[cell.problem]
        name = f"{solver.replace(':', '-').lower()}-{verdict}-{pr.id}.py"
        path = write_text_atomic(out_dir / name, script_text(pr, solver, run.settings, verdict, cell.detail))
        out.append(Reproducer(solver, verdict, pr.id, path))
    return out


NONFINITE_NAME = "drake-nonfinite-constraint.py"
#: The known finding that no corpus problem can hold (JSON has no NaN): Drake on a non-finite coefficient.
NONFINITE_SCRIPT = r'''#!/usr/bin/env python3
"""Drake: a NaN in a linear constraint's matrix ends the Python process (SystemExit from a C++
DRAKE_THROW_UNLESS) instead of raising an ordinary exception; a NaN in a linear cost is answered with
kSolverSpecificError. Exit 1: reproduces (SystemExit seen); 0: an ordinary exception or a status; 3:
pydrake missing. Needs numpy and pydrake only.
"""
import sys

import numpy as np

try:
    from pydrake.solvers import ClarabelSolver, MathematicalProgram
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(3)
from importlib.metadata import version

print(f"drake {version('drake')}, numpy {np.__version__}, python {sys.version.split()[0]}")
prog = MathematicalProgram()
x = prog.NewContinuousVariables(1, "x")
prog.AddLinearCost(np.array([1.0]), 0.0, x)
try:
    prog.AddLinearConstraint(np.array([[np.nan]]), np.array([1.0]), np.array([np.inf]), x)
    result = ClarabelSolver().Solve(prog)
except SystemExit as exc:
    print(f"REPRODUCES: a NaN coefficient raised SystemExit({exc.code}): an uncaught one ends the interpreter")
    sys.exit(1)
except Exception as exc:  # noqa: BLE001
    print(f"does not reproduce: an ordinary exception {type(exc).__name__}: {exc}")
    sys.exit(0)
print(f"does not reproduce: the solve returned {result.get_solution_result()}")
sys.exit(0)
'''


@dataclass
class Recheck:
    script: str
    outcome: str        # "reproduces", "no longer reproduces", "cannot run", "timeout"
    returncode: int | None
    last_line: str


def recheck(folder: Path, time_limit: float = RECHECK_TIME_LIMIT) -> list[Recheck]:
    """Run every reproducer of ``folder`` in a child process; never raises for what a script does."""
    out = []
    for script in sorted(Path(folder).glob("*.py")):
        try:
            child = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=time_limit)
        except subprocess.TimeoutExpired:
            out.append(Recheck(script.name, "timeout", None, f"no end within {time_limit:g} s"))
            continue
        lines = [ln for ln in (child.stdout + "\n" + child.stderr).splitlines() if ln.strip()]
        last = next((ln for ln in reversed(lines) if ln.startswith(("REPRODUCES", "does not reproduce", "cannot run"))),
                    lines[-1] if lines else "")
        rc = child.returncode
        outcome = ("no longer reproduces" if rc == DOES_NOT else "cannot run" if rc == MISSING else "reproduces")
        if rc < 0:
            last = f"killed by signal {-rc} ({last[-200:]})"
        out.append(Recheck(script.name, outcome, rc, last[:300]))
    return out


__all__ = ["DOES_NOT", "MISSING", "RECHECK_TIME_LIMIT", "REPRODUCES", "Recheck", "Reproducer", "recheck", "script_text",
           "write_reproducers"]
