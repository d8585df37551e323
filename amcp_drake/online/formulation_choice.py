"""The automatic formulation of the tube QP (20): ``formulation="auto"`` picks the plain form (15) with
the multipliers Λ or the vertex form of (5b) by a size rule measured on this machine.

Both forms have the same optimum (:mod:`amcp_drake.backends.vertex_form`); their costs differ:

* the vertex form has u·S rows of (5b) per prediction step (u facets of X0, S vertices of Θ_k) and
  no extra variables;
* the plain form has, per prediction step, one row (15c) per kept pair (vertex x^j of X0, facet i)
  (:mod:`amcp_drake.backends.dominated_rows`: K_p pairs of u·q) with q_θ − p free multipliers
  each after the exact elimination of (15d) (:mod:`amcp_drake.backends.multiplier_basis`), and the
  p eliminated ones as rows Λ_B >= 0.

The rule compares the two per-stage sizes

    vertex_size = u · S,        plain_size = K_p · (q_θ − p + 1)

and chooses the vertex form when ``vertex_size <= VERTEX_SIZE_RATIO · plain_size``. The ratio is
read from the step CPU times of the scaling benchmark (Drake, Clarabel; benchmarks/README.md,
"Formulation rule"): Example 1's p sweep has vertex/plain size ratios 1.33 (p = 2), 2.0 (p = 3),
3.2 (p = 4, 16 vertices of Θ) and 6.1 (p = 6, 64 vertices) and vertex/plain CPU ratios 0.69, 0.79,
1.22 and 2.3; the 4- and 16-facet X0 (ratios 2.0, 1.14) 0.75 and 0.58; every n = 2 … 8 point of
the scaling table has a ratio below 1.4 and a faster vertex form. The crossing lies between 2.0 and
3.2: 2.5.

Options that only the plain form implements (the min-max cost (19), time-varying parameters (26),
the PE constraint of docs/explanation/paper.md §8) choose it whatever the sizes. S is counted on Θ0 = {H_θ θ <= h_θ0}
(Θ_k ⊆ Θ0 keeps the shape of (9) and at most as many vertices in the generic case).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amcp_drake.backends.dominated_rows import kept_vertices
from amcp_drake.model import polytope

#: The vertex form is chosen when its per-stage size is at most this multiple of the plain form's
#: (the crossing of the measured CPU times, module docstring).
VERTEX_SIZE_RATIO = 2.5
#: The formulation names ``AdaptiveMPC(formulation=...)`` and the CLI accept.
FORMULATION_CHOICES = ("auto", "plain", "vertex")


@dataclass(frozen=True)
class FormulationChoice:
    """The formulation chosen, why, and the two per-stage sizes of the rule (None when an option
    decided without them)."""

    formulation: str
    reason: str
    vertex_size: int | None = None
    plain_size: int | None = None


def plain_only_reason(options) -> str:
    """'' when both forms implement ``options`` (an OnlineOptions), else the option that needs the plain form."""
    if options is None:
        return ""
    if options.cost != "certainty_equivalence":
        return "the min-max cost (19) needs the plain form"
    if options.d_theta > 0:
        return "time-varying parameters (26) need the plain form"
    if options.pe_window is not None:
        return "the PE constraint needs the plain form"
    return ""


def formulation_sizes(problem, design) -> tuple[int, int]:
    """(vertex_size, plain_size) per prediction step, module docstring."""
    H_theta = np.asarray(design.H_theta, float)
    h_theta0 = np.asarray(design.h_theta0, float)
    theta0_vertices = polytope.vertices(H_theta, h_theta0)
    K = np.asarray(design.K, float)
    Acl0 = problem.A0 + problem.B0 @ K
    Acl_i = np.array([problem.A[i] + problem.B[i] @ K for i in range(problem.p)])
    keep = kept_vertices(design.H_x, Acl0, Acl_i, design.X0_vertices, theta0_vertices)
    u = int(len(design.H_x))
    vertex_size = u * int(len(theta0_vertices))
    plain_size = int(keep.sum()) * (int(len(H_theta)) - problem.p + 1)
    return vertex_size, plain_size


def choose_formulation(problem, design, options=None) -> FormulationChoice:
    """The formulation of the rule (module docstring) for ``problem``, its ``design`` and the online ``options``."""
    reason = plain_only_reason(options)
    if reason:
        return FormulationChoice("plain", reason)
    try:
        vertex_size, plain_size = formulation_sizes(problem, design)
    except ValueError as exc:  # Θ0 vertices not enumerable: the plain form needs none
        return FormulationChoice("plain", f"vertices of Theta0 not enumerable ({exc})")
    if vertex_size <= VERTEX_SIZE_RATIO * plain_size:
        return FormulationChoice("vertex", f"vertex form size {vertex_size} <= {VERTEX_SIZE_RATIO:g} x plain "
                                 f"size {plain_size} per stage", vertex_size, plain_size)
    return FormulationChoice("plain", f"vertex form size {vertex_size} > {VERTEX_SIZE_RATIO:g} x plain size "
                             f"{plain_size} per stage", vertex_size, plain_size)


def resolve_formulation(backend_options: dict, problem, design, options=None) -> tuple[dict, FormulationChoice | None]:
    """``backend_options`` with ``formulation="auto"`` replaced by the chosen one (and the choice);
    other values are returned unchanged (choice None)."""
    if backend_options.get("formulation") != "auto":
        return backend_options, None
    choice = choose_formulation(problem, design, options)
    resolved = {**backend_options, "formulation": choice.formulation}
    if choice.formulation != "vertex" and resolved.get("qp_solver") == "daqp":
        resolved.pop("qp_solver")  # the fast path is the vertex form's only
    return resolved, choice


__all__ = ["FORMULATION_CHOICES", "VERTEX_SIZE_RATIO", "FormulationChoice", "choose_formulation",
           "formulation_sizes", "plain_only_reason", "resolve_formulation"]
