"""Steps that needed more than the first solve, counted from the notes the code writes (the bench and the campaign summary count them the same way).

A step's notes are the detail of the QP (20) answer it applied (``StepRecord.qp_detail``, from
``MPCSolution.detail``: the Clarabel retry ladder, the reduced plain form's fall back to every row of
(15c), the vertex form's fall back to the plain form, the cvxpy vertex form's fall back from its
compiled route to ``Problem.solve``, the cvxpy plain form's re-solve of an answer above the vertex
form's optimum) joined with the controller's answer-check notes
(``StepRecord.detail``: an answer re-solved with iterative refinement, or replaced by another method
after it failed its checks). Kinds that cannot occur for a backend or formulation count 0.
"""

from __future__ import annotations

#: Kind of extra work -> the text that marks it in a step's notes.
RESOLVE_MARKS = {
    "clarabel_retry": "Clarabel retr",                      # the retry ladder (clarabel_retry)
    "refined_resolve": "re-solved with iterative refinement",  # first try without refinement failed
    "minmax_default_tolerances": "re-solved at the default tolerances",  # min-max: the tight first try failed
    "every_row": "every row of (15c)",                      # reduced plain form -> every row
    "plain_fallback": "plain form (15) fallback",            # vertex form without Θ_k's vertices
    "compiled_route_fallback": "compiled route gave no answer",  # cvxpy vertex form: solved through Problem.solve
    "optimality_resolve": "above the vertex form's optimum",  # cvxpy plain form: re-solved at a tighter tol_feas
    # an answer failed its check, another method answered (the controller's notes end "...; fallback: ...";
    # the leading "; " keeps "plain form (15) fallback: " out of this count)
    "answer_check_fallback": "; fallback: ",
}


def step_notes(record) -> str:
    """The notes of one step (a ``StepRecord``): the applied QP answer's detail and the controller's notes."""
    return "; ".join([record.qp_detail, record.detail])


def count_resolves(details: list[str]) -> dict[str, int]:
    """Per kind of :data:`RESOLVE_MARKS`, the number of steps whose notes (``details``: one string
    per step, the QP's detail and the step's answer-check notes joined) contain its mark."""
    return {kind: sum(mark in d for d in details) for kind, mark in RESOLVE_MARKS.items()}


__all__ = ["RESOLVE_MARKS", "count_resolves", "step_notes"]
