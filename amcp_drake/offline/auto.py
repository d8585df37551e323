"""Automatic design (``design.x0_template = "auto"``, the default): try cross-section templates and
gains in a documented order and keep the first design that passes EVERY check of
:func:`~amcp_drake.offline.checks.verify_design` (docs/decisions.md, "X0 templates and the automatic
design").

Order (:func:`candidate_options`):

1. ``given`` with ``design.x0_H``, when the file gives one.
2. ``mrpi`` with ``design.x0_facets`` (default 8) and the LMI gain: the design of the paper and of
   every earlier version of this project, so problems that designed before (Example 1) keep
   exactly the same design.
3. ``contractive`` with the LMI gain, λ in :data:`AUTO_LAMBDAS`.
4. ``contractive`` with a lower-gain K (R scaled by each of :data:`AUTO_R_SCALES` in the LMI),
   λ in :data:`AUTO_LAMBDAS`.
5. ``mrpi`` with more facets, :data:`AUTO_FACETS` (those the dimension allows).

A user-given K, P (``design.K``/``design.P``) skips step 4; a user-given ``x0_lambda`` replaces the
λ list; ``gain_R_scale`` other than 1 is used in steps 2-3 (and step 4 uses larger scales only).
Each attempt is recorded as (label, outcome, reason, seconds); the returned design carries them in
``info["attempts"]``; when none passes, :class:`AutoDesignError` lists them all.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

from amcp_drake.offline import templates as x0_templates
from amcp_drake.backends import get_backend
from amcp_drake.model.errors import DesignError
from amcp_drake.model.problem import DesignOptions, Problem

#: λ of the contractive template, tried in this order: 0.9 leaves the tube room to shrink
#: (α⁺ <= 0.9 α + w̄) with a set close to the maximal robust control-invariant set; larger λ give
#: larger sets but a slower tube.
AUTO_LAMBDAS = (0.9, 0.95, 0.98)
#: R multipliers of the lower-gain K (step 4): each decade lowers the gain visibly on the 2-D
#: benchmarks without making A_cl(θ) nearly unstable.
AUTO_R_SCALES = (10.0, 100.0)
#: Facet counts of the last resort (step 5); the issue-14 measurements needed up to 96 in 2-D.
AUTO_FACETS = (12, 16, 20, 24, 32, 48, 64, 96)


@dataclass(frozen=True)
class Attempt:
    """One try of the automatic design: ``outcome`` is "pass", "design failed" or "check failed"."""

    label: str
    outcome: str
    reason: str
    seconds: float

    def to_dict(self) -> dict:
        return {"label": self.label, "outcome": self.outcome, "reason": self.reason, "seconds": round(self.seconds, 3)}

    def line(self) -> str:
        return f"{self.label}: {self.outcome}" + (f" ({self.reason})" if self.reason else "") + f" [{self.seconds:.1f} s]"


class AutoDesignError(DesignError):
    """No candidate of the automatic design passed every design check; ``attempts`` lists them."""

    def __init__(self, attempts: list[Attempt]) -> None:
        self.attempts = attempts
        lines = "\n".join(f"  {i + 1}. {a.line()}" for i, a in enumerate(attempts))
        super().__init__(
            f"automatic design: none of the {len(attempts)} candidates passed every design check:\n{lines}\n"
            "Next: give a cross-section yourself (design.x0_template = 'given', design.x0_H), a gain "
            "(design.K, design.P), or relax Z / shrink W or Theta; no design passing every check exists "
            "among the templates tried.")


def candidate_options(problem: Problem, options: DesignOptions) -> list[DesignOptions]:
    """The documented order of the automatic mode (module docstring) as DesignOptions."""
    out: list[DesignOptions] = []
    base = replace(options, x0_template="mrpi")
    if options.x0_H is not None:
        out.append(replace(options, x0_template="given"))
    out.append(replace(base, x0_H=None))
    lambdas = (options.x0_lambda,) if options.x0_lambda is not None else AUTO_LAMBDAS
    gains = [options.gain_R_scale]
    if options.K is None:
        gains += [s for s in AUTO_R_SCALES if s > options.gain_R_scale]
    for scale in gains:
        for lam in lambdas:
            out.append(replace(options, x0_template="contractive", x0_lambda=lam, gain_R_scale=scale, x0_H=None))
    limit = x0_templates.max_template_facets(problem.n)
    for facets in AUTO_FACETS:
        if options.x0_facets < facets <= limit:
            out.append(replace(base, x0_facets=facets, x0_H=None))
    return out


def design_auto(problem: Problem, options: DesignOptions, backend="drake", log=None):
    """The first candidate of :func:`candidate_options` whose design passes every check of
    :func:`~amcp_drake.offline.checks.verify_design`; ``log(line)`` is called after each attempt."""
    from amcp_drake.offline.design import design_fixed, robust_gain, template_label
    from amcp_drake.offline.checks import verify_design

    be = get_backend(backend)
    gains: dict = {}
    attempts: list[Attempt] = []
    for candidate in candidate_options(problem, options):
        label = template_label(candidate)
        start = time.perf_counter()
        try:
            key = candidate.gain_R_scale
            if key not in gains:
                gains[key] = robust_gain(problem, candidate, be)
            d = design_fixed(problem, candidate, backend=be, gain=gains[key])
        except DesignError as exc:  # includes TemplateError and TerminalSetError
            attempts.append(Attempt(label, "design failed", _short(exc), time.perf_counter() - start))
            _emit(log, attempts[-1])
            continue
        checks = verify_design(problem, d, candidate.mu_state_bound)
        failed = [c for c in checks if not c.passed]
        if failed:
            reason = "; ".join(f"{c.name}: {c.status}" + (f" (margin {c.margin:.3g})" if c.margin is not None else "")
                               for c in failed)
            attempts.append(Attempt(label, "check failed", reason, time.perf_counter() - start))
            _emit(log, attempts[-1])
            continue
        attempts.append(Attempt(label, "pass", "", time.perf_counter() - start))
        _emit(log, attempts[-1])
        info = dict(d.info)
        info["x0_template"] = template_label(candidate, len(d.H_x))
        info["options"] = {"x0_template": candidate.x0_template, "x0_facets": candidate.x0_facets,
                           "x0_lambda": candidate.x0_lambda, "gain_R_scale": candidate.gain_R_scale}
        info["attempts"] = [a.to_dict() for a in attempts]
        return replace(d, info=info)
    raise AutoDesignError(attempts)


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
