"""Steps that needed more than the first solve, counted from the typed attempts the step records (the
bench and the campaign summary count them the same way).

A step's attempts (``StepRecord.attempts``, :mod:`amcp_drake.online.policy`) are the controller's
rungs (first try, re-solve with iterative refinement, other formulation, fallbacks), each holding the
backend's own re-solves inside it (``Attempt.inner``, from ``MPCSolution.attempts``: the Clarabel retry
ladder, the backend's re-solve after a first try without refinement or at the min–max tolerances, the
reduced plain form's fall back to every row of (15c), the vertex form's fall back to the plain form,
the cvxpy vertex form's fall back from its compiled route to ``Problem.solve``, the cvxpy plain form's
re-solve of an answer above the vertex form's optimum). The backend's re-solves are counted in the
answers of (20) the step reports (``StepRecord.qp_detail``: the first answer and the one applied).
Kinds that cannot occur for a backend or formulation count 0.
"""

from __future__ import annotations

#: Kind of extra work -> the backend's rung (``Attempt.rung`` of ``MPCSolution.attempts``) that is it.
BACKEND_RUNGS = {
    "clarabel_retry": "clarabel_retry",                 # the retry ladder (clarabel_retry)
    "minmax_default_tolerances": "default_tolerances",  # min-max: the tight first try failed
    "every_row": "every_row",                           # reduced plain form -> every row
    "plain_fallback": "plain_form",                     # vertex form without Θ_k's vertices
    "compiled_route_fallback": "problem_solve",         # cvxpy vertex form: solved through Problem.solve
    "optimality_resolve": "tighter_feasibility",        # cvxpy plain form: re-solved at a tighter tol_feas
}
#: Every kind counted, in report order: ``refined_resolve`` is a re-solve with iterative refinement (the
#: backend's after a first try without it, or the controller's after an answer failed its checks);
#: ``answer_check_fallback`` an answer of another method after the backend's failed its checks.
RESOLVE_KINDS = ("clarabel_retry", "refined_resolve", "minmax_default_tolerances", "every_row", "plain_fallback",
                 "compiled_route_fallback", "optimality_resolve", "answer_check_fallback")


def _reported(attempts) -> list:
    """The attempts of (20) whose answers the step reports: the first and the one applied."""
    tube = [a for a in attempts if a.problem == "tube_qp"]
    if not tube:
        return []
    used = next((a for a in tube if a.accepted), None)
    return [tube[0]] if used is None or used is tube[0] else [tube[0], used]


def step_kinds(record) -> frozenset[str]:
    """The kinds of :data:`RESOLVE_KINDS` that occurred at one step (a ``StepRecord``)."""
    attempts = record.attempts or ()
    rungs = {i.rung for a in _reported(attempts) for i in a.inner}
    kinds = {kind for kind, rung in BACKEND_RUNGS.items() if rung in rungs}
    if "refine" in rungs or any(a.rung == "refine" and a.accepted for a in attempts):
        kinds.add("refined_resolve")
    if any(e["outcome"] == "fallback" for e in record.answers or ()):
        kinds.add("answer_check_fallback")
    return frozenset(kinds)


def count_resolves(steps: list[frozenset[str]]) -> dict[str, int]:
    """Per kind of :data:`RESOLVE_KINDS`, the number of steps (``steps``: :func:`step_kinds` of each)
    at which it occurred."""
    return {kind: sum(kind in s for s in steps) for kind in RESOLVE_KINDS}


__all__ = ["BACKEND_RUNGS", "RESOLVE_KINDS", "count_resolves", "step_kinds"]
