"""The solver configurations of the matrix: every solver reachable through Drake and through cvxpy,
each fed from the neutral data of a corpus problem.

A configuration is named ``drake:<solver>`` (Drake's ``<Solver>Solver``), ``cvxpy:<SOLVER>`` (cvxpy's
solver name) or ``py:<module>:<function>`` (any function ``f(problem, settings) -> Outcome``, used by the
tests for stub solvers). ``settings`` is ``"default"`` (the solver's own defaults) or ``"tight"``
(:data:`DRAKE_TIGHT`, :data:`CVXPY_TIGHT`: tolerances near 1e-9 where the solver has them).

Times are of the solve call alone (cvxpy's includes its compilation of the problem, which a cvxpy user
pays on every solve of a new problem). "success" is each stack's own word: Drake's ``result.is_success()``, cvxpy's status ``"optimal"``
(``"optimal_inaccurate"`` is a non-success: the solver says it is unsure).
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amcp_drake.studies.solver_matrix.corpus import CorpusProblem

#: Drake solvers tried (class name in pydrake.solvers), in the order of the matrix.
DRAKE_SOLVERS = {"clarabel": "ClarabelSolver", "osqp": "OsqpSolver", "scs": "ScsSolver", "clp": "ClpSolver",
                 "csdp": "CsdpSolver", "ipopt": "IpoptSolver", "nlopt": "NloptSolver", "snopt": "SnoptSolver",
                 "mosek": "MosekSolver", "gurobi": "GurobiSolver"}
#: cvxpy solvers tried where installed.
CVXPY_SOLVERS = ("CLARABEL", "OSQP", "SCS", "ECOS", "DAQP", "PIQP", "HIGHS", "PROXQP", "MOSEK")
#: Problem classes each cvxpy solver accepts (an SDP needs a PSD cone; HiGHS, DAQP, OSQP, PIQP,
#: PROXQP take QPs/LPs; ECOS takes LPs (a QP only through a second-order cone reformulation)).
CVXPY_CLASSES = {"CLARABEL": {"lp", "qp", "sdp"}, "SCS": {"lp", "qp", "sdp"}, "MOSEK": {"lp", "qp", "sdp"},
                 "OSQP": {"lp", "qp"}, "DAQP": {"lp", "qp"}, "PIQP": {"lp", "qp"}, "PROXQP": {"lp", "qp"},
                 "HIGHS": {"lp", "qp"}, "ECOS": {"lp", "qp"}}
#: Tight options per Drake solver (option names as Drake passes them on).
DRAKE_TIGHT: dict[str, dict[str, Any]] = {
    "clarabel": {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10, "tol_ktratio": 1e-8, "max_iter": 500},
    "osqp": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200000, "polishing": 1},
    "scs": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iters": 200000},
    "ipopt": {"tol": 1e-10},
    "snopt": {"Major optimality tolerance": 1e-9, "Major feasibility tolerance": 1e-9},
}
#: Tight keyword arguments of cvxpy's ``Problem.solve`` per solver.
CVXPY_TIGHT: dict[str, dict[str, Any]] = {
    "CLARABEL": {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10, "tol_ktratio": 1e-8, "max_iter": 500},
    "OSQP": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iter": 200000, "polish": True},
    "SCS": {"eps_abs": 1e-9, "eps_rel": 1e-9, "max_iters": 200000},
    "ECOS": {"abstol": 1e-10, "reltol": 1e-10, "feastol": 1e-10},
    "PIQP": {"eps_abs": 1e-10, "eps_rel": 1e-10},
    "PROXQP": {"eps_abs": 1e-9, "eps_rel": 0.0},
    "DAQP": {"primal_tol": 1e-10, "dual_tol": 1e-10},
}
SETTINGS = ("default", "tight")


@dataclass
class Outcome:
    """What a solver said: its success flag, its status text, its x (None when it gave none)."""

    success: bool
    status: str
    x: list[float] | None = None
    supported: bool = True
    detail: dict[str, Any] = field(default_factory=dict)


class Unavailable(RuntimeError):
    """The configuration is not installed or not licensed here."""


def available_configurations() -> list[str]:
    """Every drake:* and cvxpy:* configuration usable on this machine (imports pydrake and cvxpy)."""
    out = []
    try:
        import pydrake.solvers as ds

        for key, cls in DRAKE_SOLVERS.items():
            solver = getattr(ds, cls, None)
            if solver is not None and solver().available() and solver().enabled():
                out.append(f"drake:{key}")
    except ImportError:
        pass
    try:
        import cvxpy as cp

        installed = set(cp.installed_solvers())
        out.extend(f"cvxpy:{name}" for name in CVXPY_SOLVERS if name in installed and _cvxpy_licensed(name))
    except ImportError:
        pass
    return out


def _cvxpy_licensed(name: str) -> bool:
    if name != "MOSEK":
        return True
    try:
        import mosek

        env = mosek.Env()
        env.checkoutlicense(mosek.feature.pts)
        return True
    except Exception:  # noqa: BLE001 - no license: not offered
        return False


def solve(config: str, pr: CorpusProblem, settings: str) -> Outcome:
    """Solve ``pr`` with ``config`` (runs in the child process of :mod:`.runner`)."""
    stack, _, name = config.partition(":")
    if stack == "drake":
        return _solve_drake(name, pr, settings)
    if stack == "cvxpy":
        return _solve_cvxpy(name, pr, settings)
    if stack == "py":
        module, _, func = name.partition(":")
        return getattr(importlib.import_module(module), func)(pr, settings)
    raise Unavailable(f"unknown solver configuration {config!r} (drake:NAME, cvxpy:NAME or py:MODULE:FUNCTION)")


def _solve_drake(name: str, pr: CorpusProblem, settings: str) -> Outcome:
    import pydrake.solvers as ds

    cls = DRAKE_SOLVERS.get(name)
    if cls is None:
        raise Unavailable(f"unknown Drake solver {name!r}; choose one of {sorted(DRAKE_SOLVERS)}")
    solver = getattr(ds, cls)()
    if not (solver.available() and solver.enabled()):
        raise Unavailable(f"Drake solver {name} is not available or not licensed")
    prog = drake_program(pr)
    x = prog.decision_variables()
    if not solver.AreProgramAttributesSatisfied(prog):
        return Outcome(False, "unsupported: " + solver.ExplainUnsatisfiedProgramAttributes(prog).strip(), supported=False)
    options = ds.SolverOptions()
    if settings == "tight":
        for key, value in DRAKE_TIGHT.get(name, {}).items():
            options.SetOption(solver.solver_id(), key, value)
    wall, cpu = time.perf_counter(), time.process_time()
    result = solver.Solve(prog, None, options)
    timing = {"solve_wall_s": time.perf_counter() - wall, "solve_cpu_s": time.process_time() - cpu}
    details = result.get_solver_details()
    status = str(result.get_solution_result()).split(".")[-1]
    extra = getattr(details, "status", None)
    if extra is not None:
        status += f" ({extra})"
    sol = np.asarray(result.GetSolution(x), float)
    return Outcome(bool(result.is_success()), status, sol.tolist() if sol.size == pr.n else None, detail=timing)


def drake_program(pr: CorpusProblem):
    """The corpus problem as a Drake MathematicalProgram (every coefficient checked finite first: Drake
    aborts the process on a non-finite one)."""
    import scipy.sparse as sp
    from pydrake.solvers import MathematicalProgram

    for arr in (pr.q, pr.A.data, *([] if pr.P is None else [pr.P.data]), *(G.data for _, G, _ in pr.lmis),
                *(g0 for _, _, g0 in pr.lmis)):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{pr.id}: non-finite coefficient (Drake would abort the process)")
    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(pr.n, "x")
    if pr.P is not None and pr.P.nnz:
        prog.AddQuadraticCost(pr.P.toarray(), pr.q, pr.r, x, is_convex=True)
    else:
        prog.AddLinearCost(pr.q, pr.r, x)
    if pr.A.shape[0]:
        prog.AddLinearConstraint(sp.csc_matrix(pr.A), pr.lower, pr.upper, x)
    if np.any(np.isfinite(pr.lb)) or np.any(np.isfinite(pr.ub)):
        prog.AddBoundingBoxConstraint(pr.lb, pr.ub, x)
    for s, G, g0 in pr.lmis:
        cols = np.unique(G.nonzero()[1])
        Gd = G.tocsc()
        F = [g0.reshape(s, s, order="F")] + [Gd[:, j].toarray().reshape(s, s, order="F") for j in cols]
        F = [0.5 * (M + M.T) for M in F]
        prog.AddLinearMatrixInequalityConstraint(F, x[cols])
    return prog


def _solve_cvxpy(name: str, pr: CorpusProblem, settings: str) -> Outcome:
    import cvxpy as cp

    if name not in cp.installed_solvers():
        raise Unavailable(f"cvxpy solver {name} is not installed")
    if pr.problem_class not in CVXPY_CLASSES.get(name, {"lp", "qp"}):
        return Outcome(False, f"unsupported: {name} takes {sorted(CVXPY_CLASSES.get(name, ()))}", supported=False)
    problem, x = cvxpy_problem(pr)
    kwargs = dict(CVXPY_TIGHT.get(name, {})) if settings == "tight" else {}
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        problem.solve(solver=name, **kwargs)
    except cp.error.SolverError as exc:
        return Outcome(False, f"SolverError: {exc}"[:300])
    timing = {"solve_wall_s": time.perf_counter() - wall, "solve_cpu_s": time.process_time() - cpu}
    sol = None if x.value is None else np.asarray(x.value, float).tolist()
    return Outcome(problem.status == "optimal", str(problem.status), sol, detail=timing)


def cvxpy_problem(pr: CorpusProblem):
    import cvxpy as cp

    x = cp.Variable(pr.n)
    objective = pr.q @ x + pr.r
    if pr.P is not None and pr.P.nnz:
        objective = objective + 0.5 * cp.quad_form(x, cp.psd_wrap(pr.P))
    cons = []
    for M, lo, up in ((pr.A, pr.lower, pr.upper), (None, pr.lb, pr.ub)):
        if M is not None and M.shape[0] == 0:
            continue
        eq = np.isfinite(lo) & np.isfinite(up) & (lo == up)
        upper = np.isfinite(up) & ~eq
        lower = np.isfinite(lo) & ~eq
        for mask, make in ((eq, lambda e, b: e == b), (upper, lambda e, b: e <= b), (lower, lambda e, b: e >= b)):
            idx = np.flatnonzero(mask)
            if idx.size:
                expr = (M[idx] @ x) if M is not None else x[idx]
                cons.append(make(expr, (up if mask is not lower else lo)[idx]))
    for s, G, g0 in pr.lmis:
        M = cp.reshape(G @ x + g0, (s, s), order="F")
        cons.append(0.5 * (M + M.T) >> 0)
    return cp.Problem(cp.Minimize(objective), cons), x


def versions() -> dict[str, str]:
    """Installed versions of the packages that decide the matrix."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("drake", "cvxpy", "clarabel", "osqp", "scs", "ecos", "daqp", "piqp", "highspy", "proxsuite", "numpy",
                 "scipy"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            continue
    return out


__all__ = ["CVXPY_SOLVERS", "CVXPY_TIGHT", "DRAKE_SOLVERS", "DRAKE_TIGHT", "SETTINGS", "Outcome", "Unavailable",
           "available_configurations", "cvxpy_problem", "drake_program", "solve", "versions"]
