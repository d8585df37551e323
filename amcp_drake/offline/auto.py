"""Automatic design (``design.x0_template = "auto"``, the default): try cross-section templates and
gains in a documented order and keep the first design that passes EVERY check of
:func:`~amcp_drake.offline.checks.verify_design` (docs/decisions.md, "X0 templates and the automatic
design").

Order (:func:`candidate_options`):

1. ``given`` with ``design.x0_H``, when the file gives one.
2. ``mrpi`` with ``design.x0_facets`` (default 8 up to n = 4, 2n above) and the LMI gain: the
   design of the paper and of every earlier version of this project, so problems that designed
   before (Example 1) keep exactly the same design.
3. ``contractive`` with a lower-gain K first (the LMI solved with R scaled by each of
   :data:`AUTO_R_SCALES`, largest first), then the LMI gain, each with λ in :data:`AUTO_LAMBDAS`:
   a lower gain makes the input constraint bite less and gave the larger region on the SLS-MPC
   family (benchmarks/x0_template_regions.py: 0.26 instead of 0.16 at ε_A = 0.25).
4. ``mrpi`` with more facets, :data:`AUTO_FACETS` (those the dimension allows).

A user-given K, P (``design.K``/``design.P``) skips the lower-gain K's; a user-given ``x0_lambda``
replaces the λ list; a ``gain_R_scale`` other than 1 is used in step 2 and replaces the LMI gain in
step 3 (only larger scales are added).

From n = 4 on (:data:`BOUNDED_FIRST_N`) the bounded-complexity constructions come first: the
``parallelotope`` template (offline/parallelotope.py: 2n facets, 2^n vertices, K from a linear
program started at the LMI gain), then step 3
(the contractive template, whose rows are capped by
:func:`~amcp_drake.offline.templates.contractive_max_rows`, with the scaled-copy terminal set of
offline/terminal.py, as many rows as X0) before step 2, whose fixed template directions rarely fit
the closed loop in more than three dimensions (every mrpi candidate diverged on the 4- to 6-state
chains measured), and the many-facet mrpi candidates of step 4 are left out above
:data:`MRPI_FACETS_MAX_N` (each costs a long template iteration and, when it converges, a tube QP
with thousands of X0 vertices). Last come the ``preimage`` candidates (offline/preimage.py: facet
normals from the nominal closed loop, the least robustly invariant template over Θ's vertices), with
the gains of step 3 (lowest first) and each λ₀ of
:data:`~amcp_drake.offline.preimage.PREIMAGE_LAMBDAS`; they come after every earlier candidate, so a
system that designed before keeps its design. A preimage candidate whose tube does not fit Z records
how far it reaches (``fit_ratio``), and :class:`AutoDesignError` names the closest one.

Two rounds from n = 4 on (:func:`compact_facets`): the simplest X0 that passes is preferred, with the
facet count as the cost (the tube QP has N·u rows per vertex of Θ and its cross-section's vertices, the
other cost, grow with the facets: 58 facets have 298 vertices on the cart-pole, 152 have 554). The
first round runs the order above with every open-ended template capped at :func:`compact_facets`
(16 n) rows (``design.x0_max_facets``; the contractive and preimage iterations stop as "too complex"
once they pass it, which costs little) and leaves out the mrpi candidates with more facets; the first
design passing every check is kept. Only when none passes does the second round run, in the same
order, the candidates the cap stopped or left out, with their own caps: every candidate that designed
before still runs, so no system loses its design, and a system whose first passing candidate was
complex gets a simpler one when any candidate of the order gives one. Below n = 4 there is one round
(X0 has as many vertices as facets in 2-D, and a larger contractive set gives the larger region).

Each attempt is recorded as (label, outcome, reason, seconds); the returned design carries them in
``info["attempts"]``; when none passes, :class:`AutoDesignError` lists them all. Every candidate
runs under a :class:`~amcp_drake.offline.budget.DesignBudget`: a stage whose size estimate exceeds
the memory limit ends the candidate as "too large", a candidate over its time budget as "time
budget"; both are recorded attempts like any other failure. The budget's ``progress`` callback is
told when each candidate starts and ends (outcome, reason, seconds) and, every few seconds, which
stage a long candidate is in.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from amcp_drake.backends import get_backend
from amcp_drake.model.errors import DesignError
from amcp_drake.model.problem import DEFAULT_X0_LAMBDA, DesignOptions, Problem
from amcp_drake.offline import templates as x0_templates
from amcp_drake.offline.budget import CandidateTimeout, DesignBudget, DesignSizeError, unbounded
from amcp_drake.offline.preimage import PREIMAGE_LAMBDAS

#: λ of the contractive template, tried in this order: 0.9 leaves the tube room to shrink
#: (α⁺ <= 0.9 α + w̄); larger λ admit a set where a smaller one is empty (the disturbance uses up
#: λ − σ_W(a) in some row). 0.99 designs the SLS family at ε_A = 0.45 in 0.6 s with a feasible
#: region at least as large along 16 rays as the 96-facet mrpi design that took ~100 s.
AUTO_LAMBDAS = (0.9, 0.95, 0.98, 0.99)
#: R multipliers of the lower-gain K (step 3): each decade lowers the gain visibly on the 2-D
#: benchmarks without making A_cl(θ) nearly unstable.
AUTO_R_SCALES = (10.0, 100.0)
#: Facet counts of the last resort (step 4); the issue-14 measurements needed up to 96 in 2-D.
AUTO_FACETS = (12, 16, 20, 24, 32, 48, 64, 96)
#: From this dimension on the contractive candidates come before the mrpi template (module docstring).
BOUNDED_FIRST_N = 4
#: Above this dimension the many-facet mrpi candidates of step 4 are not tried.
MRPI_FACETS_MAX_N = 3
#: Rows of X0 per state allowed in the first round of the automatic design (:func:`compact_facets`).
COMPACT_FACETS_PER_STATE = 16


def compact_facets(n: int) -> int | None:
    """The facet cap of the first round of the automatic design at n states: 16 n from n = 4
    (:data:`BOUNDED_FIRST_N`) on (64 at n = 4), None (a single round) below (module docstring)."""
    return COMPACT_FACETS_PER_STATE * int(n) if int(n) >= BOUNDED_FIRST_N else None


@dataclass(frozen=True)
class Attempt:
    """One try of the automatic design: ``outcome`` is "pass", "design failed", "check failed",
    "too large" (a stage's size estimate exceeded the memory limit) or "time budget". ``fit_ratio``:
    α_∞ max f̄ of the least robustly invariant template of a candidate that failed because its tube
    does not fit Z (offline/preimage.py), else None; ``fit_bound``: True when it is a lower bound."""

    label: str
    outcome: str
    reason: str
    seconds: float
    fit_ratio: float | None = None
    fit_bound: bool = False
    brief: str = ""
    facets: int | None = None
    vertices: int | None = None

    def to_dict(self) -> dict:
        out = {"label": self.label, "outcome": self.outcome, "reason": self.reason, "seconds": round(self.seconds, 3)}
        if self.fit_ratio is not None:
            out["fit_ratio"] = self.fit_ratio
            out["fit_bound"] = self.fit_bound
        if self.facets is not None:
            out["facets"] = self.facets
            out["vertices"] = self.vertices
        return out

    def line(self) -> str:
        return f"{self.label}: {self.outcome}" + (f" ({self.reason})" if self.reason else "") + f" [{self.seconds:.1f} s]"

    def short_line(self) -> str:
        """One line of what was tried and how it ended: the short reason (``brief``), the size of a
        designed X0, the time; the full reason is in :meth:`line`."""
        size = f", X0 {self.facets} facets / {self.vertices} vertices" if self.facets is not None else ""
        why = self.brief or self.reason
        return f"{self.label}: {self.outcome}" + (f" ({why})" if why else "") + f"{size} [{self.seconds:.1f} s]"


class AutoDesignError(DesignError):
    """No candidate of the automatic design passed every design check; ``attempts`` lists them. When a
    candidate measured how far its least robustly invariant tube reaches beyond Z (``fit_ratio``), the
    message names the closest one: the measured reason why no design was found."""

    def __init__(self, attempts: list[Attempt]) -> None:
        self.attempts = attempts
        lines = "\n".join(f"  {i + 1}. {a.line()}" for i, a in enumerate(attempts))
        measured = [(a.fit_ratio, i, a) for i, a in enumerate(attempts) if a.fit_ratio is not None]
        closest = ""
        if measured:
            ratio, i, a = min(measured, key=lambda t: (t[0], t[1]))
            closest = (f"Closest: candidate {i + 1} ({a.label}): its least robustly invariant tube reaches "
                       f"{'at least ' if a.fit_bound else ''}{ratio:.3g} x the constraints (alpha_inf * max f_bar; "
                       "a design needs < 1).\n")
        super().__init__(
            f"automatic design: none of the {len(attempts)} candidates passed every design check:\n{lines}\n{closest}"
            "Next: give a cross-section yourself (design.x0_template = 'given', design.x0_H), a gain "
            "(design.K, design.P), or relax Z / shrink W or Theta; no design passing every check exists "
            "among the templates tried.")


def candidate_options(problem: Problem, options: DesignOptions) -> list[DesignOptions]:
    """The documented order of the automatic mode (module docstring) as DesignOptions."""
    out: list[DesignOptions] = []
    base = replace(options, x0_template="mrpi")
    if options.x0_H is not None:
        out.append(replace(options, x0_template="given"))
    first_mrpi = replace(base, x0_H=None, x0_facets=options.facets_for(problem.n))
    bounded_first = problem.n >= BOUNDED_FIRST_N
    if bounded_first:  # fixed complexity first: 2n facets, 2^n vertices
        out.append(replace(options, x0_template="parallelotope", x0_H=None))
    else:
        out.append(first_mrpi)
    lambdas = (options.x0_lambda,) if options.x0_lambda is not None else AUTO_LAMBDAS
    gains = [options.gain_R_scale]
    if options.K is None:  # the lowest gain first: the input constraint bites least (docs/decisions.md)
        gains = sorted({options.gain_R_scale, *(s for s in AUTO_R_SCALES if s > options.gain_R_scale)}, reverse=True)
    for scale in gains:
        for lam in lambdas:
            out.append(replace(options, x0_template="contractive", x0_lambda=lam, gain_R_scale=scale, x0_H=None))
    if bounded_first:
        out.append(first_mrpi)
        pre_lambdas = (options.x0_lambda,) if options.x0_lambda is not None else PREIMAGE_LAMBDAS
        for scale in gains:
            for lam in pre_lambdas:
                out.append(replace(options, x0_template="preimage", x0_lambda=lam, gain_R_scale=scale, x0_H=None))
        if problem.n > MRPI_FACETS_MAX_N:
            return out
    limit = x0_templates.max_template_facets(problem.n)
    for facets in AUTO_FACETS:
        if options.facets_for(problem.n) < facets <= limit:
            out.append(replace(base, x0_facets=facets, x0_H=None))
    return out


#: Templates whose row count is open-ended: capped by ``design.x0_max_facets`` in a round of the automatic design.
CAPPED_KINDS = ("contractive", "preimage")


def round_caps(problem: Problem, options: DesignOptions) -> list[int | None]:
    """The facet caps of the rounds of the automatic design, in order (module docstring): the
    compact cap (:func:`compact_facets`) and then the user's ``design.x0_max_facets`` (None: each
    template's own cap), or a single round when there is no compact cap or the user's is no larger."""
    compact = compact_facets(problem.n)
    user = options.x0_max_facets
    if compact is None or (user is not None and user <= compact):
        return [user]
    return [compact, user]


def _in_round(candidate: DesignOptions, cap: int | None, n: int) -> DesignOptions | None:
    """``candidate`` as it runs in a round with facet cap ``cap``: the open-ended templates capped, an
    mrpi template with more facets than the cap left out (None); the others as they are."""
    if cap is None:
        return candidate
    if candidate.x0_template in CAPPED_KINDS:
        return replace(candidate, x0_max_facets=cap)
    if candidate.x0_template == "mrpi" and candidate.facets_for(n) > cap:
        return None
    return candidate


def _stopped_by_cap(candidate: DesignOptions, exc: Exception) -> bool:
    """True when a capped candidate ended because its X0 passed the round's facet cap."""
    return (candidate.x0_template in CAPPED_KINDS and candidate.x0_max_facets is not None
            and isinstance(exc, x0_templates.TemplateError) and exc.reason == "too complex")


def design_auto(problem: Problem, options: DesignOptions, backend, design_fixed, robust_gain, verify, log=None,
                budget: DesignBudget | None = None):
    """The first candidate of :func:`candidate_options` whose design passes every check of ``verify``
    (:func:`~amcp_drake.offline.checks.verify_design`), round by round (:func:`round_caps`: from n = 4
    on the candidates first run capped at :func:`compact_facets` facets); ``log(line)`` is called
    after each attempt.

    ``design_fixed`` and ``robust_gain`` are those of offline/design.py, passed in by
    :func:`~amcp_drake.offline.design.design` (this module sits below design.py: no import cycle).
    ``budget``: memory limit, per-candidate time budget and progress callback (module docstring).
    """
    be = get_backend(backend)
    budget = budget or unbounded()
    gains: dict = {}
    attempts: list[Attempt] = []
    pending = candidate_options(problem, options)
    caps = round_caps(problem, options)
    for round_number, cap in enumerate(caps, start=1):
        runs = [(c, _in_round(c, cap, problem.n)) for c in pending]
        later: list[DesignOptions] = [c for c, run in runs if run is None]  # left out of this round
        runs = [(c, run) for c, run in runs if run is not None]
        if round_number > 1 and budget.progress is not None:
            budget.progress(f"design: no candidate with at most {caps[round_number - 2]} facets passed; "
                            f"{len(runs)} candidate(s) again with " + (f"at most {cap} facets" if cap is not None
                                                                        else "their own caps"))
        for original, candidate in runs:
            label = template_label(candidate, dimension=problem.n)
            number = len(attempts) + 1
            cand_budget = budget.for_candidate(f"candidate {number} ({label})")
            start = time.perf_counter()
            try:
                key = candidate.gain_R_scale
                if key not in gains:
                    gains[key] = robust_gain(problem, candidate, be)
                d = design_fixed(problem, candidate, backend=be, gain=gains[key], budget=cand_budget)
            except DesignSizeError as exc:
                _record(attempts, Attempt(label, "too large", _short(exc), time.perf_counter() - start,
                                          brief=_brief(exc)), log, budget)
                continue
            except CandidateTimeout as exc:
                _record(attempts, Attempt(label, "time budget", _short(exc), time.perf_counter() - start,
                                          brief=_brief(exc)), log, budget)
                continue
            except DesignError as exc:  # includes TemplateError and TerminalSetError
                if _stopped_by_cap(candidate, exc):
                    later.append(original)
                _record(attempts, Attempt(label, "design failed", _short(exc), time.perf_counter() - start,
                                          getattr(exc, "fit_ratio", None), getattr(exc, "fit_bound", False),
                                          brief=_brief(exc)), log, budget)
                continue
            checks = verify(problem, d, candidate.mu_state_bound)
            failed = [c for c in checks if not c.passed]
            if failed:
                reason = "; ".join(f"{c.name}: {c.status}" + (f" (margin {c.margin:.3g})" if c.margin is not None else "")
                                   for c in failed)
                brief = ", ".join(c.name for c in failed) + " failed"
                _record(attempts, Attempt(label, "check failed", reason, time.perf_counter() - start, brief=brief),
                        log, budget, d)
                continue
            _record(attempts, Attempt(label, "pass", "", time.perf_counter() - start), log, budget, d)
            info = dict(d.info)
            info["x0_template"] = template_label(candidate, len(d.H_x), dimension=problem.n)
            info["options"] = {"x0_template": candidate.x0_template, "x0_facets": candidate.facets_for(problem.n),
                               "x0_lambda": candidate.x0_lambda, "gain_R_scale": candidate.gain_R_scale}
            info["attempts"] = [a.to_dict() for a in attempts]
            return replace(d, info=info)
        order = {id(c): i for i, c in enumerate(pending)}
        pending = sorted(later, key=lambda c: order[id(c)])  # the documented order, in the next round
        if not pending:
            break
    raise AutoDesignError(attempts)


def template_label(options: DesignOptions, facets: int | None = None, dimension: int | None = None) -> str:
    """A short human name of the template of ``options`` ("mrpi, 8 facets", "contractive, lambda 0.9",
    "..., K from R x 10"); ``dimension`` resolves a default facet count (``design.x0_facets`` not given)."""
    kind = options.x0_template
    if kind == "mrpi":
        count = options.x0_facets if options.x0_facets is not None or dimension is None else options.facets_for(dimension)
        text = f"mrpi, {count if count is not None else 'default'} facets"
    elif kind == "parallelotope":
        text = "parallelotope" + (f", {facets} facets" if facets is not None else "")
    elif kind == "preimage":
        text = f"preimage, lambda {options.x0_lambda if options.x0_lambda is not None else PREIMAGE_LAMBDAS[0]:g}"
        if facets is not None:
            text += f", {facets} facets"
    elif kind == "contractive":
        text = f"contractive, lambda {options.x0_lambda if options.x0_lambda is not None else DEFAULT_X0_LAMBDA:g}"
        if facets is not None:
            text += f", {facets} facets"
    else:
        text = f"{kind}" + (f", {facets} facets" if facets is not None else "")
    if options.gain_R_scale != 1.0 and options.K is None:
        text += f", K from R x {options.gain_R_scale:g}"
    if facets is None and kind in CAPPED_KINDS and options.x0_max_facets is not None:
        text += f", at most {options.x0_max_facets} facets"
    return text


def chosen_options(options: DesignOptions, design) -> DesignOptions:
    """The DesignOptions that reproduce ``design`` with a fixed template: ``options`` with the
    template, facets, λ and gain scale the automatic mode chose (``design.info["options"]``);
    ``options`` unchanged for a design made with a fixed template. Used to design with a second
    backend on the same template (amcp compare)."""
    chosen = (getattr(design, "info", None) or {}).get("options")
    if not chosen:
        return options
    return replace(options, **chosen, x0_H=options.x0_H if chosen["x0_template"] == "given" else None)


def _short(exc: Exception) -> str:
    text = str(exc).replace("\n", " ")
    return text if len(text) <= 300 else text[:297] + "..."


def _emit(log, attempt: Attempt) -> None:
    if log is not None:
        log(attempt.line())


def _record(attempts: list[Attempt], attempt: Attempt, log, budget: DesignBudget, designed=None) -> None:
    """Append ``attempt`` (with the size of ``designed``'s X0 when a design was made), hand it to
    ``log`` and report its end in one line through the budget's progress callback."""
    if designed is not None:
        attempt = replace(attempt, facets=len(designed.H_x), vertices=len(designed.X0_vertices))
    attempts.append(attempt)
    _emit(log, attempt)
    if budget.progress is not None:
        budget.progress(f"design candidate {len(attempts)}: {attempt.short_line()}")


#: Longest short reason of a candidate's line (:meth:`Attempt.short_line`).
BRIEF_CHARS = 90


def _brief(exc: Exception) -> str:
    """The short reason of a failed candidate: a template's reason and detail, else the message's first
    sentence, at most :data:`BRIEF_CHARS` characters (the full message is the attempt's ``reason``)."""
    if isinstance(exc, x0_templates.TemplateError):
        text = f"{exc.reason}: {exc.detail}"
    else:
        text = str(exc).replace("\n", " ").split("; ")[0].split(". ")[0]
    return text if len(text) <= BRIEF_CHARS else text[:BRIEF_CHARS - 3] + "..."
