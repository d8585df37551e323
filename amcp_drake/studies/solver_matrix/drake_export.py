"""A Drake ``MathematicalProgram`` as a corpus problem, and the recording of every program the Drake
backend solves during a run.

:func:`program_to_problem` reads the costs and constraints of a program (quadratic and linear costs;
linear, linear-equality and bounding-box constraints; PSD and LMI constraints) into the neutral form
of :mod:`.corpus`. A program with any other cost or constraint raises :class:`UnsupportedProgram`
(the exporter counts it and leaves it out).

:class:`ProgramRecorder` wraps ``DrakeSolver.solve`` for the duration of a ``with`` block (the class
attribute is put back on exit): every program that reaches a solver is converted at that moment (the
programs are built once and their coefficients updated, so the copy must be taken before the next
update) and tagged with the paper's problem it belongs to, read from the call site (:data:`CALL_SITES`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from amcp_drake.studies.solver_matrix.corpus import CorpusProblem

#: (module, function or qualified name, or None for any) of a caller -> corpus kind: the first entry found
#: on the call stack decides (Drake's programs, then the cvxpy backend's).
CALL_SITES = (
    ("amcp_drake.online.controller", "_irredundant_rows", "exact_update_lp"),
    ("amcp_drake.backends.drake_", "_gain_lmi", "gain_sdp"),
    ("amcp_drake.backends.drake_", "project", "projection_qp"),
    ("amcp_drake.backends.drake_set_update", None, "set_update_lp"),
    ("amcp_drake.backends.drake_vertex", None, "tube_qp_vertex"),
    ("amcp_drake.backends.drake_tube", None, "tube_qp_plain"),
    ("amcp_drake.backends.drake_", "support", "support_lp"),
    ("amcp_reference.offline", "_gain_lmi", "gain_sdp"),
    ("amcp_reference.online", "ProjectionQP.solve", "projection_qp"),
    ("amcp_reference.online", "SetUpdateLP.solve", "set_update_lp"),
    ("amcp_reference.tube_vertex", None, "tube_qp_vertex"),
    ("amcp_reference.tube_mpc", None, "tube_qp_plain"),
    ("amcp_reference.offline", "SupportLP.solve", "support_lp"),
)


class UnsupportedProgram(ValueError):
    """A program with a cost or constraint the neutral form does not hold."""


def program_to_problem(prog, problem_id: str, kind: str, provenance: dict[str, Any] | None = None) -> CorpusProblem:
    """The data of ``prog`` (its current coefficients) as a :class:`~.corpus.CorpusProblem`."""
    n = prog.num_vars()
    P = sp.lil_matrix((n, n))
    q = np.zeros(n)
    r = 0.0
    handled_costs = 0
    for b in prog.quadratic_costs():
        idx = prog.FindDecisionVariableIndices(b.variables())
        e = b.evaluator()
        Q = np.asarray(e.Q(), float)
        for a, i in enumerate(idx):
            for c, j in enumerate(idx):
                if Q[a, c] != 0.0:
                    P[i, j] += Q[a, c]
        np.add.at(q, idx, np.asarray(e.b(), float))
        r += float(e.c())
        handled_costs += 1
    for b in prog.linear_costs():
        idx = prog.FindDecisionVariableIndices(b.variables())
        e = b.evaluator()
        np.add.at(q, idx, np.asarray(e.a(), float))
        r += float(e.b())
        handled_costs += 1
    if handled_costs != len(prog.GetAllCosts()):
        raise UnsupportedProgram(f"{problem_id}: a cost other than linear/quadratic")

    rows, lower, upper = [], [], []
    lb, ub = np.full(n, -np.inf), np.full(n, np.inf)
    handled = 0
    for b in (*prog.linear_constraints(), *prog.linear_equality_constraints()):
        idx = prog.FindDecisionVariableIndices(b.variables())
        e = b.evaluator()
        Aloc = sp.coo_matrix(e.get_sparse_A())
        rows.append(sp.csr_matrix((Aloc.data, (Aloc.row, np.asarray(idx)[Aloc.col])), shape=(Aloc.shape[0], n)))
        lower.append(np.asarray(e.lower_bound(), float))
        upper.append(np.asarray(e.upper_bound(), float))
        handled += 1
    for b in prog.bounding_box_constraints():
        idx = np.asarray(prog.FindDecisionVariableIndices(b.variables()))
        e = b.evaluator()
        np.maximum.at(lb, idx, np.asarray(e.lower_bound(), float))
        np.minimum.at(ub, idx, np.asarray(e.upper_bound(), float))
        handled += 1
    lmis = []
    for b in prog.positive_semidefinite_constraints():
        idx = np.asarray(prog.FindDecisionVariableIndices(b.variables()))
        s = b.evaluator().matrix_rows()
        G = sp.csr_matrix((np.ones(s * s), (np.arange(s * s), idx)), shape=(s * s, n))  # column-major flattening
        lmis.append((s, G, np.zeros(s * s)))
        handled += 1
    for b in prog.linear_matrix_inequality_constraints():
        idx = np.asarray(prog.FindDecisionVariableIndices(b.variables()))
        F = [np.asarray(f, float) for f in b.evaluator().F()]
        s = F[0].shape[0]
        cols = np.column_stack([f.reshape(-1, order="F") for f in F[1:]]) if len(F) > 1 else np.zeros((s * s, 0))
        G = sp.lil_matrix((s * s, n))
        for a, j in enumerate(idx):
            G[:, j] = G[:, j] + cols[:, a:a + 1]
        lmis.append((s, sp.csr_matrix(G), F[0].reshape(-1, order="F")))
        handled += 1
    if handled != len(prog.GetAllConstraints()):
        raise UnsupportedProgram(f"{problem_id}: a constraint other than linear/bounding box/PSD/LMI")
    A = sp.vstack(rows, format="csr") if rows else sp.csr_matrix((0, n))
    P_out = sp.csr_matrix(P) if P.nnz else None
    if P_out is not None:
        P_out = sp.csr_matrix(0.5 * (P_out + P_out.T))
    return CorpusProblem(id=problem_id, kind=kind, P=P_out, q=q, r=r, A=A,
                         lower=np.concatenate(lower) if lower else np.zeros(0),
                         upper=np.concatenate(upper) if upper else np.zeros(0),
                         lb=lb, ub=ub, lmis=lmis, provenance=dict(provenance or {}))


def call_site_kind(frame) -> str | None:
    """The corpus kind of the first entry of :data:`CALL_SITES` found anywhere on the call stack (the
    exact update's redundancy LPs go through the backend's support LPs, so the order decides)."""
    stack = []
    while frame is not None:
        code = frame.f_code
        stack.append((frame.f_globals.get("__name__", ""), code.co_name, getattr(code, "co_qualname", code.co_name)))
        frame = frame.f_back
    for site_module, site_func, kind in CALL_SITES:
        if any(module == site_module and site_func in (None, func, qualname) for module, func, qualname in stack):
            return kind
    return None


@dataclass
class Recorded:
    """One program as it reached the solver, with the status the backend got."""

    kind: str
    problem: CorpusProblem | None
    solver: str
    options: dict[str, Any]
    success: bool | None = None
    solver_status: str = ""
    error: str = ""


@dataclass
class ProgramRecorder:
    """``with ProgramRecorder(context) as rec:`` records every Drake program solved inside the block.

    ``context`` is a dict read at each solve (the caller updates it, e.g. with the step index) and
    stored as the problem's provenance. ``solve=False`` (or ``context["record_only"]``) records without
    solving and raises :class:`SolveSkipped` in place of the solve (for inputs known to abort the process)."""

    context: dict[str, Any] = field(default_factory=dict)
    solve: bool = True
    records: list[Recorded] = field(default_factory=list)
    unsupported: int = 0

    def __enter__(self) -> ProgramRecorder:
        from amcp_drake.backends.drake_solver import DrakeSolver

        self._original = DrakeSolver.__dict__["solve"]
        recorder = self

        def solve(solver_self, prog, extra_options=None):
            kind = call_site_kind(sys._getframe(1)) or "unknown"
            options = {**solver_self.option_values, **(extra_options or {})}
            pid = f"{len(recorder.records):05d}"
            try:
                problem = program_to_problem(prog, pid, kind, {**recorder.context})
            except UnsupportedProgram as exc:
                recorder.unsupported += 1
                problem, err = None, str(exc)
            else:
                err = ""
            rec = Recorded(kind, problem, solver_self.name, options, error=err)
            recorder.records.append(rec)
            if not recorder.solve or recorder.context.get("record_only"):
                raise SolveSkipped(kind)
            result, elapsed = recorder._original(solver_self, prog, extra_options)
            rec.success = bool(result.is_success())
            rec.solver_status = str(getattr(result.get_solver_details(), "status", result.get_solution_result()))
            return result, elapsed

        DrakeSolver.solve = solve
        return self

    def __exit__(self, *exc) -> None:
        from amcp_drake.backends.drake_solver import DrakeSolver

        DrakeSolver.solve = self._original


class SolveSkipped(RuntimeError):
    """Raised in place of a solve by a recorder with ``solve=False``."""


__all__ = ["CALL_SITES", "ProgramRecorder", "Recorded", "SolveSkipped", "UnsupportedProgram", "call_site_kind",
           "program_to_problem"]
