"""The size check of a closed-loop run, in the form of the tube QP (20) the run will really use.

Every command that builds the tube QP (``amcp run``, ``certify``, ``compare``, ``coverage``,
``baseline``, ``pe-figure`` and the campaign's runs) calls :func:`check_run_size` twice: before the
design and once the design is known, before the controller is built. The formulation is resolved
first (:func:`run_formulation`):

* ``"plain"`` and ``"vertex"`` are the forms the run builds;
* ``"auto"`` with a design is the choice of :func:`~amcp_drake.online.formulation_choice.choose_formulation`,
  exactly the form the controller will build;
* ``"auto"`` before the design is the plain form when an online option needs it (min-max cost (19),
  d_θ > 0, PE), else the smaller of the two estimates (the design decides between them; the second
  check, with the design, holds the run to the form chosen).

The estimate and the refusal themselves are :func:`amcp_drake.model.limits.check_run_size`'s. The
offline design is not a run: ``amcp design`` never calls this check (each stage of the design is sized
against the same memory limit by :class:`~amcp_drake.offline.budget.DesignBudget`).
"""

from __future__ import annotations

from amcp_drake.model.limits import DEFAULT_MAX_MEMORY_MB, SizeEstimate
from amcp_drake.model.limits import check_run_size as _check_estimate
from amcp_drake.online.formulation_choice import choose_formulation, plain_only_reason


def run_formulation(formulation: str, problem, design=None, options=None) -> str:
    """The form of (20) whose size is checked for a run with ``formulation`` ("plain", "vertex" or
    "auto") and the online ``options``: module docstring ("auto" stays "auto" only before the design,
    when no option forces the plain form)."""
    if formulation != "auto":
        return formulation
    if design is not None:
        return choose_formulation(problem, design, options).formulation
    return "plain" if plain_only_reason(options) else "auto"


def check_run_size(problem, design_options=None, steps: int = 1, options=None,
                   max_memory_mb: float = DEFAULT_MAX_MEMORY_MB, *, design=None, formulation: str = "plain",
                   option: str = "--max-memory") -> SizeEstimate:
    """Refuse a run of ``steps`` steps whose estimated memory exceeds ``max_memory_mb`` in the form of
    (20) it will use (:func:`run_formulation`); ProblemError naming the sizes, the estimate and
    ``option``. ``design``: the OfflineDesign found (None: the estimate before the design). Returns the
    estimate."""
    form = run_formulation(formulation, problem, design, options)
    return _check_estimate(problem, design_options, steps, options, max_memory_mb, option=option, design=design,
                           formulation=form)


__all__ = ["check_run_size", "run_formulation"]
