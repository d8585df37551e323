"""The answer policy of the online loop as data: for each problem, the rungs tried in order until an
answer passes its checks (docs/decisions.md, "Verified solver answers").

A :class:`Policy` lists a problem's rungs: the first try, then the re-solves and fallbacks, each with
the reason that lets it run (the first answer failed a check; its status is one of no answer; any
other status). :func:`run` tries them in order, each through a function the controller gives (the
rung's solve and its answer checks), and returns the answer used (None: nothing usable) and the
typed :class:`~amcp_drake.backends.base.Attempt` of every rung that ran. Everything a step records
about how an answer was obtained is rendered from these attempts: the provenance entry
(:func:`answer_entry`, ``StepRecord.answers``), the notes (:func:`notes`, ``StepRecord.detail``) and
the solver details (:func:`solver_details`, ``StepRecord.qp_detail``).

The rungs of the tube QP (20): the backend's first answer; the same QP solved again with iterative
refinement (a solver with ``REFINES``: the first try runs without it for speed); the other
formulation ("plain" <-> "vertex") of the same backend. Of the set update (9): the backend's LP;
HiGHS' per-row support LPs; Θ_{k−1} kept (always a valid outer set of Θ_{k−1} ∩ Δ_k, and nested (10)).
Of the projection (12): the backend's QP; the least-distance point by NNLS; θ̂_{k−1}; the Chebyshev
centre of S.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from amcp_drake.backends.base import Attempt
from amcp_drake.backends.clarabel_retry import RETRIED
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answer_checks, answers

#: Why a rung after the first may run, from the first attempt: ``"check"`` (an "optimal" answer failed
#: an answer check), ``"no_answer"`` (a status of the policy's ``no_answer``: no answer for numerical
#: reasons), ``"status"`` (any other status that is not "optimal").
REASONS = ("check", "no_answer", "status")


@dataclass(frozen=True)
class Rung:
    """One rung: ``name`` (``Attempt.rung``); ``outcome`` of the provenance entry when its answer is used
    (``"first"``, ``"resolved"``: the same backend and solver again, ``"fallback"``: another method);
    ``kind`` of that entry (``{formulation}`` is replaced by the attempt's option); ``after``: the
    reasons (:data:`REASONS`) that let it run; the notes written when its answer is used (``accepted``),
    when its answer failed too (``failed``; ``{failed}``: its failed checks or status) and when it could not
    run (``not_run``; ``{reason}``: why); ``head``: appended to the problem's name in the first answer's
    note when this rung's answer is used."""

    name: str
    outcome: str
    kind: str = ""
    after: tuple[str, ...] = ()
    accepted: str = ""
    failed: str = ""
    not_run: str = ""
    head: str = ""

    def kind_of(self, attempt: Attempt) -> str:
        """The provenance entry's kind for ``attempt`` of this rung."""
        return self.kind.format(formulation=attempt.option("formulation"))


@dataclass(frozen=True)
class Policy:
    """The rungs of one problem, in order (the first is the backend's first try); ``what`` names the
    problem in notes; ``no_answer``: the statuses that are no answer for numerical reasons;
    ``status_note``: the first answer's note when its status is not "optimal"."""

    problem: str
    what: str
    rungs: tuple[Rung, ...]
    no_answer: frozenset = frozenset()
    status_note: str = "{what}: backend status {status}"
    #: when no rung answered, the provenance entry's kind is the last fallback tried (else "")
    names_failed_fallback: bool = True

    def rung(self, name: str) -> Rung:
        """The rung called ``name``."""
        return next(r for r in self.rungs if r.name == name)


FIRST = Rung("first", "first")
REFINE = Rung("refine", "resolved", "iterative_refinement", after=("check",),
              accepted="re-solved with iterative refinement (checked)", head=", first try without iterative refinement")

#: The tube QP (20): statuses of :data:`amcp_drake.backends.clarabel_retry.RETRIED` ("inaccurate", a
#: solver error), reached after the backend's own retries, are no answer for numerical reasons and go to
#: the other formulation, as an "optimal" answer that fails its checks does (the plain form can stall
#: under every rung of the ladder where the vertex form solves the same QP: docs/decisions.md);
#: "infeasible" is an answer and is reported as such.
TUBE_QP = Policy(
    "tube_qp", "tube QP (20)",
    (FIRST, REFINE,
     Rung("other_formulation", "fallback", "{formulation}_form", after=("check", "no_answer"),
          accepted="fallback: {formulation} form of (20) (checked)",
          failed="fallback {formulation} form failed ({failed}): step not solved",
          not_run="{reason}: step not solved")),
    no_answer=frozenset(RETRIED), status_note="{what}: status {status}, no answer ({detail})")

#: A candidate of the PE procedure (docs/explanation/paper.md §8): the tube QP with a bound on u_0,
#: checked before it competes; re-solved with refinement, else dropped.
PE_CANDIDATE = Policy("pe_candidate", "tube QP (20) with PE bound", (FIRST, REFINE))

#: The set update (9): any status but "optimal" and any failed check go to HiGHS, then to Θ_{k−1}.
SET_UPDATE = Policy(
    "set_update", "set update (9)",
    (FIRST,
     Rung("highs_support_lps", "fallback", "highs_support_lps", after=REASONS,
          accepted="fallback: HiGHS support LPs (checked)"),
     Rung("kept_previous_set", "fallback", "kept_previous_set", after=REASONS,
          accepted="fallback: kept Θ_(k−1) (HiGHS answer failed too)")))


#: The projection (12): any status but "optimal" and any failed check go to the least-distance
#: projection (NNLS, another solver, checked the same way), then to θ̂_{k−1} if it is in S, then to the
#: Chebyshev centre of S if it is in S (a certified point of S keeps Theorem 14; Lemma 5 is not claimed
#: for such a step: the certificate's lms_update skips steps whose projection is not optimal).
PROJECTION = Policy(
    "projection", "projection (12) onto {target}",
    (FIRST,
     Rung("least_distance", "fallback", "least_distance", after=REASONS,
          accepted="fallback: least-distance projection (NNLS, checked)"),
     Rung("kept_previous_estimate", "fallback", "kept_previous_estimate", after=REASONS,
          accepted="fallback: kept θ̂_(k−1) (in {target})"),
     Rung("chebyshev_centre", "fallback", "chebyshev_centre", after=REASONS,
          accepted="fallback: Chebyshev centre of {target} (radius {radius})",
          failed="no certified point of {target}: step not solved")),
    names_failed_fallback=False)


def reason(policy: Policy, first: Attempt) -> str:
    """Why the rungs after the first may run (:data:`REASONS`), "" when the first answer was used."""
    if first.accepted:
        return ""
    if first.status is SolveStatus.OPTIMAL:
        return "check"
    return "no_answer" if first.status in policy.no_answer else "status"


def run(policy: Policy, attempt: Callable[[Rung], tuple[object, Attempt] | None]):
    """(answer, attempts): the rungs of ``policy`` in order, each that its reason lets run, until one's
    answer is accepted. ``attempt(rung)`` solves and checks one rung: (its answer, its
    :class:`Attempt`), or None when the rung does not apply here (nothing recorded). The answer is None
    when no rung's answer was accepted."""
    attempts: list[Attempt] = []
    why = ""
    for rung in policy.rungs:
        if attempts and why not in rung.after:
            continue
        got = attempt(rung)
        if got is None:
            continue
        answer, a = got
        attempts.append(a)
        if a.accepted:
            return answer, attempts
        if len(attempts) == 1:
            why = reason(policy, a)
    return None, attempts


def failed_check(first: Attempt) -> str:
    """The provenance entry's ``check`` of a problem whose first attempt is ``first``: its failed check, or
    ``"status <s>"`` when it is not "optimal"."""
    if first.check:
        return first.check
    return "" if first.status is SolveStatus.OPTIMAL else f"status {first.status.value}"


def answer_entry(policy: Policy, attempts: list[Attempt]) -> dict[str, str]:
    """The provenance entry (:mod:`amcp_drake.online.answers`) of a problem solved by :func:`run`."""
    first, last = attempts[0], attempts[-1]
    if first.accepted:
        return answers.entry(policy.problem, "first")
    why = failed_check(first)
    if last.accepted:
        rung = policy.rung(last.rung)
        return answers.entry(policy.problem, rung.outcome, rung.kind_of(last), why)
    if reason(policy, first) == "status" and len(attempts) == 1:
        # an answer that is no solution ("infeasible"): the backend's own, no fallback
        return answers.entry(policy.problem, "not_solved", first.status.value)
    tried = [a for a in attempts[1:] if a.status is not SolveStatus.NOT_RUN
             and policy.rung(a.rung).outcome == "fallback"] if policy.names_failed_fallback else []
    kind = policy.rung(tried[-1].rung).kind_of(tried[-1]) if tried else ""
    return answers.entry(policy.problem, "not_solved", kind, why)


def notes(policy: Policy, attempts: list[Attempt], what: str | None = None, **names: str) -> str:
    """The step's note on a problem solved by :func:`run` ("" when the first answer was used, or when it
    had no fallback): why the first answer was not used, then what the last rung gave. ``what``: the
    problem's name (default ``policy.what``); ``names`` and the last attempt's options fill the fields of
    the texts (``{target}``, ``{radius}``, ``{formulation}``)."""
    what = (policy.what if what is None else what).format(**names)
    first, last = attempts[0], attempts[-1]
    if first.accepted or len(attempts) == 1:
        return ""
    rung = policy.rung(last.rung)
    if first.check:
        head = answer_checks.describe_failures(what + (rung.head if last.accepted else ""), list(first.failures))
    else:
        head = policy.status_note.format(what=what, status=first.status.value, detail=first.detail)
    fields = {**names, "formulation": "", **dict(last.options)}
    if last.accepted:
        tail = rung.accepted.format(**fields)
    elif last.status is SolveStatus.NOT_RUN:
        tail = rung.not_run.format(reason=last.check, **fields)
    else:
        failed = (f"status {last.status.value}" if last.status is not SolveStatus.OPTIMAL
                  else answer_checks.describe_failures("checks", list(last.failures)))
        tail = rung.failed.format(failed=failed, **fields)
    return f"{head}; {tail}" if tail else head


def solver_details(attempts: list[Attempt]) -> str:
    """The solver details of the first answer and, when another was used, of the used one, "; "-joined."""
    first = attempts[0]
    used = next((a for a in attempts if a.accepted), None)
    if used is None or used is first:
        return first.detail
    return f"{first.detail}; {used.detail}"


__all__ = ["PE_CANDIDATE", "PROJECTION", "REASONS", "SET_UPDATE", "TUBE_QP", "Policy", "Rung", "answer_entry", "failed_check",
           "notes", "reason", "run", "solver_details"]
