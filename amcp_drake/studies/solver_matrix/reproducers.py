"""Standalone reproducers of the matrix's wrong answers and crashes, and their re-check.

For every (solver configuration, verdict) with verdict ``wrong`` or ``crash``, the smallest corpus
problem that shows it (:attr:`.corpus.CorpusProblem.size`) is written out as one self-contained
script: pure pydrake or pure cvxpy with numpy/scipy, the problem's data inline, nothing from this
project. It prints the installed versions and what is wrong, and exits :data:`REPRODUCES` (3) when the
defect reproduces, :data:`DOES_NOT` (0) when it does not, :data:`MISSING` (4) when a package it needs
is missing. A crash's script reproduces by an exception (exit 3) or by an abort (the process ended by
one of :data:`CRASH_SIGNALS`); a status returned is "does not reproduce", whatever the answer.

Nothing of a corpus file is pasted into the script as code: the problem's data is one string literal
written by :func:`repr` of its JSON, the header one :func:`repr` literal, the file name derived from
the validated id (:data:`.corpus.ID_PATTERN`, :func:`reproducer_name`).

Beside the scripts, :data:`MANIFEST_NAME` records for each file its SHA-256 and what it was written
from (the problem's data, solver, settings, verdict). :func:`recheck` runs only the scripts of that
manifest whose bytes are exactly what this version writes for the recorded entry (the hash checked on
the file, on the manifest and on the script written again from the entry, whose reference is verified
again as on corpus load: :func:`.reference.check_reference`), so a foreign or edited
script, a forged manifest entry, a symbolic link, a hidden file or a folder is reported and never
run. Each script runs from a private temporary copy, in a child process with a minimal environment
(:func:`clean_environment`), in a process group of its own that is killed when it ends or at the time
limit; its outcome is "reproduces" only on the documented exit code (or a crash signal of a crash's
script), any other ending (an uncaught exception, a syntax error, another code) is "error".
"""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from amcp_drake.model.errors import ProblemFileError
from amcp_drake.studies.solver_matrix.corpus import CorpusProblem, check_id, write_json_atomic, write_text_atomic
from amcp_drake.studies.solver_matrix.reference import check_reference
from amcp_drake.studies.solver_matrix.runner import TOLERANCES, MatrixRun
from amcp_drake.studies.solver_matrix.solvers import CVXPY_TIGHT, DRAKE_SOLVERS, DRAKE_TIGHT

#: Exit codes of a reproducer (1 and 2 are Python's own: an uncaught exception, a bad command line).
REPRODUCES, DOES_NOT, MISSING = 3, 0, 4
#: Signals that end a crash's script when the solver aborts the process (they count as "reproduces").
CRASH_SIGNALS = (signal.SIGABRT, signal.SIGSEGV, signal.SIGBUS, signal.SIGILL, signal.SIGFPE)
#: Seconds a reproducer may run in :func:`recheck`.
RECHECK_TIME_LIMIT = 120.0
#: The manifest written beside the scripts.
MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT, MANIFEST_VERSION = "amcp-reproducers", 1
#: Outcomes of :func:`recheck`.
OUTCOMES = ("reproduces", "no longer reproduces", "cannot run", "timeout", "error", "refused")

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
'''

_DRAKE = r'''
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
'''

_CVXPY = r'''
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
'''


@dataclass
class Reproducer:
    solver: str
    verdict: str
    problem: str
    path: Path


#: Characters of a solver configuration in a file name (``drake:clarabel`` -> ``drake-clarabel``).
_SOLVER_CHARS = frozenset("abcdefghijklmnopqrstuvwxyz0123456789_")


def reproducer_name(solver: str, verdict: str, problem_id: str, settings: str = "default") -> str:
    """The file name of a reproducer, derived (never taken) from its parts: ``<stack>-<name>-<verdict>-<id>.py``
    (``-tight`` before ``.py`` for tight settings). ValueError for a part outside the safe characters."""
    stack, _, name = solver.partition(":")
    if stack not in ("drake", "cvxpy") or not name or not set(name.lower()) <= _SOLVER_CHARS:
        raise ValueError(f"no reproducer file name for the solver configuration {solver!r}")
    if verdict not in ("wrong", "crash") or settings not in TOLERANCES:
        raise ValueError(f"no reproducer file name for verdict {verdict!r}, settings {settings!r}")
    check_id(problem_id)
    return f"{stack}-{name.lower()}-{verdict}-{problem_id}{'-tight' if settings == 'tight' else ''}.py"


def script_text(pr: CorpusProblem, solver: str, settings: str, verdict: str, detail: str) -> str:
    """The standalone script of ``solver`` on ``pr`` (see the module docstring). Every text that comes from
    the corpus or the run (the id, the detail, the data) is in a literal written by :func:`repr`."""
    stack, _, name = solver.partition(":")
    data = {k: v for k, v in pr.to_dict().items() if k not in ("provenance",)}
    data["reference"] = {k: pr.reference.get(k) for k in ("status", "objective", "x") if k in pr.reference}
    tol = TOLERANCES[settings]
    if stack == "drake" and name in DRAKE_SOLVERS:
        options = DRAKE_TIGHT.get(name, {}) if settings == "tight" else {}
        head = f"SOLVER_CLASS = {DRAKE_SOLVERS[name]!r}\nOPTIONS = {options!r}\n"
        body = _DRAKE
    elif stack == "cvxpy" and name:
        options = CVXPY_TIGHT.get(name, {}) if settings == "tight" else {}
        head = f"SOLVER = {name!r}\nOPTIONS = {options!r}\n"
        body = _CVXPY
    else:
        raise ValueError(f"no standalone reproducer for {solver!r} (drake:* and cvxpy:* only)")
    doc = (f"{solver} ({settings} settings) on one problem of the amcp-drake solver corpus: {verdict}.\n\n"
           f"Problem {pr.id}: {pr.kind} {pr.equation}, {pr.problem_class.upper()}, {pr.n} variables, {pr.A.shape[0]} rows"
           f"{', ' + str(len(pr.lmis)) + ' LMI block(s)' if pr.lmis else ''}:\n"
           "    minimise 1/2 x'Px + q'x + r  s.t.  lower <= A x <= upper,  lb <= x <= ub,  mat(g0 + G x) PSD\n"
           f"Seen: {detail[:300]}\n"
           + ("Only a crash counts (an exception or an abort); the answer returned is not judged.\n" if verdict == "crash" else
              "The reference answer is verified (KKT residuals below 1e-7; an LP's optimal basis in exact rational\n"
              "arithmetic; an infeasible problem by a Farkas certificate).\n")
           + f"Exit {REPRODUCES}: reproduces; {DOES_NOT}: does not; {MISSING}: a package is missing (any other ending is an "
           f"error of the script, not a finding). Needs numpy, scipy and {'pydrake' if stack == 'drake' else 'cvxpy'} only.\n")
    payload = json.dumps(data, separators=(",", ":"), allow_nan=False)
    return (f"#!/usr/bin/env python3\n{doc!r}\nimport json\n\nDATA = json.loads({payload!r})\n"
            f"FEAS_TOL, OPT_TOL = {tol['feas']!r}, {tol['opt']!r}\nCRASH_ONLY = {verdict == 'crash'!r}\n"
            f"{head}{_COMMON}{body}")


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def manifest_entry(pr: CorpusProblem | None, solver: str, settings: str, verdict: str, detail: str) -> tuple[str, str, dict]:
    """(file name, script text, manifest entry) of one reproducer; ``pr`` None: :data:`NONFINITE_SCRIPT`."""
    if pr is None:
        return NONFINITE_NAME, NONFINITE_SCRIPT, {"builtin": "nonfinite", "solver": "drake", "verdict": "crash",
                                                  "sha256": _sha256(NONFINITE_SCRIPT.encode())}
    text = script_text(pr, solver, settings, verdict, detail)
    problem = {**pr.to_dict(), "provenance": {},
               "reference": {k: pr.reference[k] for k in ("status", "objective", "x") if k in pr.reference}}
    entry = {"solver": solver, "settings": settings, "verdict": verdict, "detail": detail[:300], "problem": problem,
             "sha256": _sha256(text.encode())}
    return reproducer_name(solver, verdict, pr.id, settings), text, entry


def write_reproducer_folder(folder: Path, items: list[tuple[CorpusProblem | None, str, str, str, str]]) -> list[Path]:
    """Write the scripts of ``items`` (problem or None, solver, settings, verdict, detail) and their
    :data:`MANIFEST_NAME` into ``folder`` (each file atomically, the manifest last); returns the scripts."""
    manifest: dict[str, Any] = {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "exit_codes": {
        "reproduces": REPRODUCES, "does not reproduce": DOES_NOT, "cannot run": MISSING}, "files": {}}
    paths = []
    for item in items:
        name, text, entry = manifest_entry(*item)
        paths.append(write_text_atomic(folder / name, text))
        manifest["files"][name] = entry
    manifest["files"] = dict(sorted(manifest["files"].items()))   # one text for one set of scripts
    write_json_atomic(folder / MANIFEST_NAME, manifest, indent=1)
    return paths


def write_reproducers(run: MatrixRun, out_dir: Path) -> list[Reproducer]:
    """One script per (solver, wrong|crash): the smallest problem showing it; with a Drake configuration
    also :data:`NONFINITE_SCRIPT` (a NaN coefficient, which no corpus file can hold); and the manifest.
    Nothing is written (no folder created) when there is no reproducer."""
    problems = {p.id: p for p in run.problems}
    chosen: dict[tuple[str, str], Any] = {}
    for cell in run.cells:
        if cell.verdict not in ("wrong", "crash") or cell.solver.split(":", 1)[0] not in ("drake", "cvxpy"):
            continue
        key = (cell.solver, cell.verdict)
        if key not in chosen or problems[cell.problem].size < problems[chosen[key].problem].size:
            chosen[key] = cell
    items: list[tuple[CorpusProblem | None, str, str, str, str]] = []
    out: list[Reproducer] = []
    if any(c.split(":", 1)[0] == "drake" for c in run.configurations):
        items.append((None, "drake", run.settings, "crash", ""))
        out.append(Reproducer("drake", "crash", "(none: NaN coefficient)", out_dir / NONFINITE_NAME))
    for (solver, verdict), cell in sorted(chosen.items()):
        pr = problems[cell.problem]
        items.append((pr, solver, run.settings, verdict, cell.detail))
        out.append(Reproducer(solver, verdict, pr.id, out_dir / reproducer_name(solver, verdict, pr.id, run.settings)))
    if items:
        write_reproducer_folder(out_dir, items)
    return out


NONFINITE_NAME = "drake-nonfinite-constraint.py"
#: The known finding that no corpus problem can hold (JSON has no NaN): Drake on a non-finite coefficient.
NONFINITE_SCRIPT = r'''#!/usr/bin/env python3
"""Drake: a NaN in a linear constraint's matrix ends the Python process (SystemExit from a C++
DRAKE_THROW_UNLESS) instead of raising an ordinary exception; a NaN in a linear cost is answered with
kSolverSpecificError. Exit 3: reproduces (SystemExit seen); 0: an ordinary exception or a status; 4:
pydrake missing (any other exit code is an error of the script, not a finding). Needs numpy and pydrake
only.
"""
import sys

import numpy as np

try:
    from pydrake.solvers import ClarabelSolver, MathematicalProgram
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(4)
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
    sys.exit(3)
except Exception as exc:  # noqa: BLE001
    print(f"does not reproduce: an ordinary exception {type(exc).__name__}: {exc}")
    sys.exit(0)
print(f"does not reproduce: the solve returned {result.get_solution_result()}")
sys.exit(0)
'''


@dataclass
class Recheck:
    script: str
    outcome: str        # one of OUTCOMES
    returncode: int | None
    last_line: str


def read_manifest(folder: Path) -> dict[str, dict[str, Any]]:
    """The entries of ``folder``'s :data:`MANIFEST_NAME` (file name -> entry), read strictly;
    ProblemFileError naming the field when it is missing or malformed."""
    from amcp_drake.model.json_strict import decode_utf8, loads_strict, read_bytes_limited

    path = folder / MANIFEST_NAME
    source = str(path)
    if path.is_symlink() or not path.is_file():
        raise ProblemFileError("--recheck", f"a folder of reproducers written by amcp solvers, with its {MANIFEST_NAME}",
                               f"{folder}: no {MANIFEST_NAME} (a regular file)")
    data = loads_strict(decode_utf8(read_bytes_limited(path, what="reproducer manifest"), source), source)
    if not isinstance(data, dict) or data.get("format") != MANIFEST_FORMAT or data.get("version") != MANIFEST_VERSION:
        raise ProblemFileError(f"{source}: format", f"{MANIFEST_FORMAT!r} version {MANIFEST_VERSION}",
                               repr(data.get("format") if isinstance(data, dict) else type(data).__name__)[:80])
    files = data.get("files")
    if not isinstance(files, dict) or not all(isinstance(e, dict) for e in files.values()):
        raise ProblemFileError(f"{source}: files", "an object: file name -> entry", type(files).__name__)
    return files


Item = tuple[CorpusProblem | None, str, str, str, str]


def manifest_item(name: str, entry: dict[str, Any]) -> Item:
    """What a manifest entry says a script was written from: (problem or None for the built-in
    :data:`NONFINITE_SCRIPT`, solver, settings, verdict, detail), the problem read strictly and, for a
    wrong answer, its reference verified again. ValueError (or ProblemFileError naming the field) when the
    entry does not describe one."""
    if entry.get("builtin") == "nonfinite":
        return None, "drake", "default", "crash", ""
    solver, settings, verdict, detail = (entry.get(k) for k in ("solver", "settings", "verdict", "detail"))
    if not all(isinstance(v, str) for v in (solver, settings, verdict, detail)) or settings not in TOLERANCES:
        raise ValueError("an entry without solver, settings, verdict and detail")
    problem = entry.get("problem")
    reference = problem.get("reference") if isinstance(problem, dict) else None
    source = f"{MANIFEST_NAME}: {name}.problem"
    pr = CorpusProblem.from_dict(problem, source, require_reference=verdict != "crash" or bool(reference))
    if verdict != "crash":   # a wrong answer is judged by the reference: verified again, as on corpus load
        check_reference(pr, source)
    return pr, solver, settings, verdict, detail


def expected_script(name: str, entry: dict[str, Any]) -> str:
    """The script this version writes for a manifest entry, under the name it derives for it; ValueError
    (or ProblemFileError from the problem's data) when the entry does not describe one."""
    expected_name, text, _ = manifest_entry(*manifest_item(name, entry))
    if name != expected_name:
        raise ValueError(f"the entry's file name is {expected_name!r}")
    return text


def rewrite_folder(folder: Path) -> list[Path]:
    """Write the scripts of ``folder`` again with this version's template, from the entries of its
    manifest (their data, never their scripts), and the manifest with them; the scripts the old manifest
    listed under other names are removed. How a kept folder (``docs/reproducers``) follows a change of the
    template. Every file is staged and moved into place when all are complete."""
    from amcp_drake.studies.solver_matrix.staging import staged

    folder = Path(folder)
    files = read_manifest(folder)
    items = [manifest_item(name, entry) for name, entry in sorted(files.items())]
    with staged(folder) as stage:
        paths = [folder / p.name for p in write_reproducer_folder(stage, items)]
    written = {p.name for p in paths}
    for name in set(files) - written:
        old = folder / name
        if Path(name).name == name and not name.startswith(".") and old.is_file() and not old.is_symlink():
            old.unlink()
    return paths


def vet(folder: Path, files: dict[str, dict[str, Any]]) -> tuple[list[tuple[str, str, str]], list[Recheck]]:
    """(runnable: (name, text, verdict), refused) of ``folder``: every entry of the folder other than the
    manifest is either a manifest script that checks or refused with the reason."""
    runnable, refused = [], []
    with os.scandir(folder) as it:
        entries = sorted(it, key=lambda e: e.name)
    names = {e.name for e in entries}
    for e in entries:
        if e.name == MANIFEST_NAME:
            continue
        why = None
        if e.name.startswith("."):
            why = "a hidden file"
        elif e.is_symlink():
            why = "a symbolic link"
        elif e.is_dir(follow_symlinks=False):
            why = "a folder"
        elif not e.is_file(follow_symlinks=False):
            why = "not a regular file"
        elif e.name not in files:
            why = f"not written by amcp solvers (not in {MANIFEST_NAME})"
        if why is not None:
            refused.append(Recheck(e.name, "refused", None, f"not run: {why}"))
            continue
        entry = files[e.name]
        try:
            text = expected_script(e.name, entry)
        except (ValueError, ProblemFileError) as exc:
            refused.append(Recheck(e.name, "refused", None, f"not run: its manifest entry describes no reproducer ({exc})"[:300]))
            continue
        size = e.stat(follow_symlinks=False).st_size
        digest = _sha256(Path(folder, e.name).read_bytes()) if size == len(text.encode()) else ""
        if not (digest == entry.get("sha256") == _sha256(text.encode())):
            refused.append(Recheck(e.name, "refused", None, "not run: its SHA-256 differs from the manifest's or from the "
                                   "script this version writes for the entry (changed since written, or written by "
                                   "another version: write it again with amcp solvers)"))
            continue
        runnable.append((e.name, text, str(entry.get("verdict"))))
    for name in sorted(set(files) - names):
        refused.append(Recheck(name, "refused", None, f"not run: listed in {MANIFEST_NAME} but missing"))
    return runnable, refused


def previous_reproducers(folder: Path) -> list[Path]:
    """The scripts of an earlier run in ``folder`` that this version wrote and nobody changed since (each
    one :func:`recheck` would run): the ones a new run replaces. Any other file is not among them; an
    unreadable folder or manifest gives none."""
    try:
        runnable, _ = vet(Path(folder), read_manifest(Path(folder)))
    except (OSError, ProblemFileError, ValueError):
        return []
    return [Path(folder) / name for name, _, _ in runnable]


def printable(text: str) -> str:
    """``text`` with every non-printable character (a terminal escape sequence, a newline) written as its
    Python escape, for a terminal line about a file name from someone else's folder."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def clean_environment(home: str) -> dict[str, str]:
    """The environment of a reproducer: PATH and (when set) PYTHONPATH of the caller, HOME and TMPDIR a
    private temporary folder, a UTF-8 locale; nothing else of the caller's environment."""
    env = {"PATH": os.environ.get("PATH", os.defpath), "HOME": home, "TMPDIR": home, "LC_ALL": "C.UTF-8",
           "PYTHONDONTWRITEBYTECODE": "1", "PYTHONNOUSERSITE": "1"}
    if os.environ.get("PYTHONPATH"):
        env["PYTHONPATH"] = os.environ["PYTHONPATH"]
    return env


def run_isolated(text: str, name: str, time_limit: float) -> tuple[int | None, str]:
    """Run the script ``text`` as ``name`` from a private temporary folder (also its HOME and working
    folder) with :func:`clean_environment`, in a new session (its own process group), killed with every
    process it started when it ends or at ``time_limit``; (exit code or None at the time limit, output)."""
    with tempfile.TemporaryDirectory(prefix="amcp-recheck-") as tmp:
        script = Path(tmp) / name
        script.write_text(text, encoding="utf-8")
        log = Path(tmp) / ".output"
        with open(log, "wb") as handle:
            proc = subprocess.Popen([sys.executable, "-s", str(script)], stdin=subprocess.DEVNULL, stdout=handle,
                                    stderr=subprocess.STDOUT, cwd=tmp, env=clean_environment(tmp), start_new_session=True)
            try:
                rc: int | None = proc.wait(timeout=time_limit)
            except subprocess.TimeoutExpired:
                rc = None
            finally:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)   # the script and whatever it started
                except (ProcessLookupError, PermissionError):
                    pass
                proc.wait()
        return rc, log.read_text(encoding="utf-8", errors="replace")


def outcome_of(rc: int | None, verdict: str) -> str:
    """The outcome of a reproducer's ending (module docstring)."""
    if rc is None:
        return "timeout"
    if rc == REPRODUCES or (verdict == "crash" and rc < 0 and -rc in {int(s) for s in CRASH_SIGNALS}):
        return "reproduces"
    return {DOES_NOT: "no longer reproduces", MISSING: "cannot run"}.get(rc, "error")


def recheck(folder: Path, time_limit: float = RECHECK_TIME_LIMIT) -> list[Recheck]:
    """Run every reproducer of ``folder`` that its manifest vouches for (module docstring) and report the
    rest as refused; never raises for what a script does. ProblemFileError without a readable manifest."""
    folder = Path(folder)
    runnable, out = vet(folder, read_manifest(folder))
    for name, text, verdict in runnable:
        rc, output = run_isolated(text, name, time_limit)
        lines = [ln for ln in output.splitlines() if ln.strip()]
        last = next((ln for ln in reversed(lines) if ln.startswith(("REPRODUCES", "does not reproduce", "cannot run"))),
                    lines[-1] if lines else "")
        if rc is None:
            last = f"no end within {time_limit:g} s"
        elif rc < 0:
            last = f"killed by signal {-rc} ({last[-200:]})"
        elif outcome_of(rc, verdict) == "error":
            last = f"exit code {rc}, not one of the reproducer's own ({last[-200:]})"
        out.append(Recheck(name, outcome_of(rc, verdict), rc, last[:300]))
    return sorted(out, key=lambda r: r.script)


__all__ = ["CRASH_SIGNALS", "DOES_NOT", "MANIFEST_NAME", "MISSING", "OUTCOMES", "RECHECK_TIME_LIMIT", "REPRODUCES", "Recheck",
           "Reproducer", "clean_environment", "expected_script", "manifest_entry", "outcome_of", "previous_reproducers", "printable",
           "manifest_item", "read_manifest", "recheck", "rewrite_folder", "vet",
           "reproducer_name", "run_isolated", "script_text", "write_reproducer_folder", "write_reproducers"]
