"""Where each solver answer of a step came from: the structured provenance ``StepRecord.answers``.

Every answer the online loop uses is checked (:mod:`amcp_drake.online.answer_checks`); when one fails,
the controller re-solves or falls back to another method (docs/decisions.md, "Verified solver
answers"). Each step records, per problem it solved, one entry

    {"problem": "set_update" | "exact_update" | "projection" | "tube_qp" | "pe_candidate",
     "outcome": "first" | "resolved" | "fallback" | "not_solved",
     "kind": short name of the re-solve or fallback ("" for a first answer),
     "check": the failed check (or "status <s>") that caused it ("" if none)}

* ``first``: the backend's first answer passed every check and was used;
* ``resolved``: it failed a check, the same backend and solver answered again (iterative
  refinement) and that answer passed: still the backend's own answer;
* ``fallback``: another method answered (HiGHS support LPs for (9), the other formulation of (20),
  a least-distance projection for (12), or a kept set/estimate): the backend's answer was rejected;
* ``not_solved``: nothing usable (``check`` empty when the backend's own answer was "infeasible",
  which is an answer, not a defect).

A trajectory written before this field existed has ``answers = None`` on every record: its provenance
is *unknown* and is reported as such, never as "all first answers".
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

PROBLEMS = ("set_update", "exact_update", "projection", "tube_qp", "pe_candidate")
OUTCOMES = ("first", "resolved", "fallback", "not_solved")
#: What each problem is, for messages ("Drake answered 51 of 51 tube QPs (20) itself").
PROBLEM_NAMES = {"set_update": "set updates (9)", "exact_update": "exact updates (7)",
                 "projection": "projections (12)", "tube_qp": "tube QPs (20)",
                 "pe_candidate": "PE-bounded QP candidates (docs/explanation/paper.md §8)"}
#: Kinds of fallback answers that are a solution of the problem itself (checked), so that the paper's
#: claims about that solution hold for them: the other formulation of (20), HiGHS' supports for (9),
#: the least-distance projection for (12). A kept Θ_(k−1) or θ̂_(k−1) is a valid but different answer.
SOLUTION_KINDS = ("vertex_form", "plain_form", "highs_support_lps", "least_distance")
KEYS = ("problem", "outcome", "kind", "check")


def entry(problem: str, outcome: str, kind: str = "", check: str = "") -> dict[str, str]:
    """One provenance entry (module docstring)."""
    return {"problem": problem, "outcome": outcome, "kind": kind, "check": check}


def validate(value: Any, where: str) -> list[dict[str, str]] | None:
    """``value`` as a list of entries, or None (unknown provenance); ValueError naming ``where`` and the
    offending entry when it is not of the documented layout."""
    if value is None:
        return None
    if not isinstance(value, list):
        raise ValueError(f"{where}: expected a list of answer entries or null; received {type(value).__name__}")
    out = []
    for i, item in enumerate(value):
        if not isinstance(item, dict) or set(item) != set(KEYS) or not all(isinstance(item[k], str) for k in KEYS):
            raise ValueError(f"{where}[{i}]: expected an object with string fields {list(KEYS)}; received {item!r}")
        if item["problem"] not in PROBLEMS or item["outcome"] not in OUTCOMES:
            raise ValueError(f"{where}[{i}]: expected problem in {list(PROBLEMS)} and outcome in {list(OUTCOMES)}; "
                             f"received {item['problem']!r}, {item['outcome']!r}")
        out.append(dict(item))
    return out


def rejected(e: dict[str, str]) -> bool:
    """True when the backend's own answer was rejected by a check and not replaced by its own re-solve:
    a fallback, or no answer because a check (or a no-answer status) failed."""
    return e["outcome"] == "fallback" or (e["outcome"] == "not_solved" and e["check"] != "")


def of(record, problem: str) -> dict[str, str] | None:
    """The record's entry for ``problem`` (the last one), None when absent or provenance unknown."""
    answers = getattr(record, "answers", None)
    if not answers:
        return None
    found = [e for e in answers if e["problem"] == problem]
    return found[-1] if found else None


def qp_applied(record) -> bool:
    """True when the step applied a checked answer of (20): its own (first or re-solved) or a checked
    fallback of the other formulation. Unknown provenance: the recorded status must be "optimal"."""
    from amcp_drake.model.status import SolveStatus

    if record.z is None:
        return False
    e = of(record, "tube_qp")
    if e is None:
        return record.status is SolveStatus.OPTIMAL
    return e["outcome"] in ("first", "resolved") or (e["outcome"] == "fallback" and e["kind"] in SOLUTION_KINDS)


def projection_is_projection(record) -> bool:
    """True when the recorded θ̂_k is a checked projection (12): the backend's (status optimal) or the
    least-distance fallback. A kept θ̂_(k−1) or Chebyshev centre is not (Lemma 5 is not claimed there)."""
    from amcp_drake.model.status import SolveStatus

    if record.projection_status is SolveStatus.OPTIMAL:
        return True
    e = of(record, "projection")
    return e is not None and e["outcome"] == "fallback" and e["kind"] == "least_distance"


def summarize(records: Iterable, backend: str) -> dict[str, Any]:
    """The ``solver_answers`` section of certificate.json: per problem the count of answers per outcome
    and the steps of each (outcome, kind, check); ``conformance``: "pass" (every answer was the
    backend's own: first or re-solved), "fail" (some answer was rejected: :func:`rejected`) or "unknown"
    (a record without provenance); ``summary``: one line per problem for the terminal and the report."""
    records = list(records)
    unknown = [r.k for r in records if getattr(r, "answers", None) is None]
    problems: dict[str, dict[str, Any]] = {}
    for r in records:
        for e in r.answers or ():
            p = problems.setdefault(e["problem"], {"answers": 0, **{o: 0 for o in OUTCOMES}, "kinds": []})
            p["answers"] += 1
            p[e["outcome"]] += 1
            if e["outcome"] != "first":
                key = {"outcome": e["outcome"], "kind": e["kind"], "check": e["check"]}
                for group in p["kinds"]:
                    if all(group[k] == key[k] for k in key):
                        group["steps"].append(r.k)
                        break
                else:
                    p["kinds"].append({**key, "steps": [r.k]})
    rejected_steps = sorted({r.k for r in records for e in (r.answers or ()) if rejected(e)})
    conformance = "unknown" if unknown else ("fail" if rejected_steps else "pass")
    return {"backend": backend, "provenance": "unknown" if unknown else "recorded",
            "steps_without_provenance": unknown, "problems": problems, "conformance": conformance,
            "rejected_steps": rejected_steps, "summary": summary_lines(backend, problems, unknown)}


def summary_lines(backend: str, problems: dict[str, dict[str, Any]], unknown: list[int]) -> list[str]:
    """"drake answered 51 of 51 tube QPs (20) itself", then each re-solve and fallback with its steps."""
    if unknown:
        return [f"provenance of the solver answers unknown at {len(unknown)} step(s) (a trajectory recorded "
                f"without it): whether {backend} answered them itself is not known"]
    lines = []
    for name in PROBLEMS:
        p = problems.get(name)
        if p is None:
            continue
        own = p["first"] + p["resolved"]
        line = f"{backend} answered {own} of {p['answers']} {PROBLEM_NAMES[name]} itself"
        if p["resolved"]:
            line += f" ({p['resolved']} after a re-solve)"
        lines.append(line)
        for g in p["kinds"]:
            steps = g["steps"]
            listed = ", ".join(map(str, steps[:8])) + (", ..." if len(steps) > 8 else "")
            what = {"resolved": "re-solved", "fallback": "fallback", "not_solved": "not solved"}[g["outcome"]]
            kind = f" by {g['kind']}" if g["kind"] else ""
            because = f" (failed: {g['check']})" if g["check"] else ""
            lines.append(f"  {what}{kind} at {len(steps)} step(s) [{listed}]{because}")
    return lines or [f"no solver answers recorded for {backend}"]


def mismatches(k: int, a: list | None, b: list | None, names: tuple[str, str]) -> list[dict[str, Any]]:
    """Per problem at step k: where one backend needed a re-solve or fallback (or did not solve) and the
    other answered first, one dict naming the step, the backend that needed help, its outcome, kind
    and failed check. Unknown provenance on either side gives nothing to compare."""
    if a is None or b is None:
        return []
    out = []
    for problem in PROBLEMS:
        ea = [e for e in a if e["problem"] == problem]
        eb = [e for e in b if e["problem"] == problem]
        worst_a = next((e for e in ea if e["outcome"] != "first"), None)
        worst_b = next((e for e in eb if e["outcome"] != "first"), None)
        for e, other, name in ((worst_a, worst_b, names[0]), (worst_b, worst_a, names[1])):
            if e is not None and other is None and (e["outcome"] != "not_solved" or e["check"]):
                out.append({"step": k, "backend": name, "problem": problem, "outcome": e["outcome"],
                            "kind": e["kind"], "check": e["check"]})
    return out


def counts(records: Iterable) -> dict[str, dict[str, int]]:
    """Per problem: the number of answers, of each outcome, and of each re-solve/fallback kind
    (``"fallback vertex_form"``); records without provenance are left out (see :func:`unknown_steps`)."""
    out: dict[str, dict[str, int]] = {}
    for r in records:
        for e in getattr(r, "answers", None) or ():
            c = out.setdefault(e["problem"], {"answers": 0, **{o: 0 for o in OUTCOMES}})
            c["answers"] += 1
            c[e["outcome"]] += 1
            if e["outcome"] != "first":
                key = f"{e['outcome']} {e['kind']}".strip()
                c[key] = c.get(key, 0) + 1
    return out


def unknown_steps(records: Iterable) -> list[int]:
    """Steps whose record has no provenance (a trajectory written before it was recorded)."""
    return [r.k for r in records if getattr(r, "answers", None) is None]
