"""A cvxpy ``Problem`` as a corpus problem, and the recording of every problem the cvxpy backend solves
through its ``SolverCall`` during a run.

:func:`conic_to_problem` reads cvxpy's compiled data for Clarabel (``get_problem_data("CLARABEL")``:
``A x + s = b`` with ``s`` in the zero cone, the nonnegative orthant and scaled PSD triangles) into the
neutral form of :mod:`.corpus`: the zero rows become equalities, the orthant rows ``A x <= b``, each PSD
triangle an LMI block ``mat(g0 + G x) ⪰ 0``. Other cones raise :class:`.drake_export.UnsupportedProgram`.
The variables are cvxpy's compiled ones (what the solver sees), and the constant of the objective is
left out (it moves no solver).

:class:`CvxpyRecorder` wraps ``amcp_reference.solver_call.SolverCall.solve`` for a ``with`` block, like
:class:`.drake_export.ProgramRecorder` for Drake.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp

from amcp_drake.studies.solver_matrix.corpus import CorpusProblem
from amcp_drake.studies.solver_matrix.drake_export import Recorded, SolveSkipped, UnsupportedProgram, call_site_kind


def conic_to_problem(data: dict[str, Any], problem_id: str, kind: str, provenance: dict[str, Any] | None = None) -> CorpusProblem:
    dims = data["dims"]
    if dims.soc or dims.exp or getattr(dims, "p3d", None) or getattr(dims, "pnd", None):
        raise UnsupportedProgram(f"{problem_id}: a second-order, exponential or power cone")
    A = sp.csr_matrix(data["A"])
    b = np.asarray(data["b"], float)
    n = A.shape[1]
    nz, nn = int(dims.zero), int(dims.nonneg)
    lower = np.concatenate([b[:nz], np.full(nn, -np.inf)])
    upper = b[:nz + nn].copy()
    lmis = []
    k = nz + nn
    for s in dims.psd:
        G = sp.lil_matrix((s * s, n))
        g0 = np.zeros(s * s)
        for j in range(s):
            for i in range(j + 1):
                w = 1.0 if i == j else np.sqrt(2.0)
                row = -A[k] / w            # the entry (i, j) of M(x) = smat(b - A x)
                for pos in {i + j * s, j + i * s}:
                    G[pos] = row
                    g0[pos] = b[k] / w
                k += 1
        lmis.append((s, sp.csr_matrix(G), g0))
    if k != A.shape[0]:
        raise UnsupportedProgram(f"{problem_id}: {A.shape[0] - k} rows of an unknown cone")
    P = data.get("P")
    P = None if P is None or sp.csr_matrix(P).nnz == 0 else sp.csr_matrix(P)
    lb = np.full(n, -np.inf) if data.get("lower_bounds") is None else np.asarray(data["lower_bounds"], float)
    ub = np.full(n, np.inf) if data.get("upper_bounds") is None else np.asarray(data["upper_bounds"], float)
    return CorpusProblem(id=problem_id, kind=kind, P=P, q=np.asarray(data["c"], float), r=0.0, A=A[:nz + nn],
                         lower=lower, upper=upper, lb=lb, ub=ub, lmis=lmis, provenance=dict(provenance or {}))


@dataclass
class CvxpyRecorder:
    """``with CvxpyRecorder(context) as rec:`` records every cvxpy problem the cvxpy backend solves."""

    context: dict[str, Any] = field(default_factory=dict)
    solve: bool = True
    records: list[Recorded] = field(default_factory=list)
    unsupported: int = 0

    def __enter__(self) -> CvxpyRecorder:
        from amcp_reference.solver_call import SolverCall

        self._original = SolverCall.__dict__["solve"]
        recorder = self

        def solve(call_self, problem, extra_options=None):
            kind = call_site_kind(sys._getframe(1)) or "unknown"
            pid = f"{len(recorder.records):05d}"
            try:
                data, _, _ = problem.get_problem_data("CLARABEL")
                pr, err = conic_to_problem(data, pid, kind, {**recorder.context}), ""
            except (UnsupportedProgram, ValueError) as exc:
                recorder.unsupported += 1
                pr, err = None, str(exc)
            rec = Recorded(kind, pr, f"cvxpy:{call_self.name}", {**call_self.settings, **(extra_options or {})}, error=err)
            recorder.records.append(rec)
            if not recorder.solve or recorder.context.get("record_only"):
                raise SolveSkipped(kind)
            status, elapsed, detail = recorder._original(call_self, problem, extra_options)
            rec.success = str(problem.status) == "optimal"
            rec.solver_status = str(detail)
            return status, elapsed, detail

        SolverCall.solve = solve
        return self

    def __exit__(self, *exc) -> None:
        from amcp_reference.solver_call import SolverCall

        SolverCall.solve = self._original


__all__ = ["CvxpyRecorder", "conic_to_problem"]
