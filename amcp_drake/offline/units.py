"""The offline design in state units normalised by W.

Every claim of the paper is invariant under a change of state units x̃ = T x, T = diag(t_i) > 0, but
the design as written is not: the X0 template directions are fixed unit vectors in x
(:func:`~amcp_drake.offline.templates.template_directions`) and the objective trace(P⁻¹) of the gain
LMI (16) is another objective after a non-uniform T. Measured with a design in the file's units: Example 1 in units
diag(100, 0.01) designed at its first candidate with K·T⁻¹ = [−0.051, −0.478] instead of
[0.018, −0.415]; ``massera2017`` in diag(100, 0.01, 0.01) failed all 15 candidates.

So every design (automatic and fixed template, :func:`~amcp_drake.offline.design.design` and
:func:`~amcp_drake.offline.design.design_fixed`) is computed in the units

    ξ = S x,  S = diag(s_i),  s_i = max_j e_j / e_i,  e_i = max_{w ∈ W} |w_i| (W's extent in state i),

and mapped back to x:

    K = K_ξ S,  P = S P_ξ S,  H_x = H_ξ S,  x^j = S⁻¹ ξ^j,  A_z = S⁻¹ A_z,ξ S,  H_T = H_T,ξ S,

while w̄, f̄, h̄, λ̄, h_T, Θ0 and the terminal iterations are unit-free (each is a support of a set in
rows that are mapped with it). μ of (11) is recomputed in x, since the LMS step (12) runs in the
user's units. A user-given K, P are returned as given (not K S⁻¹ S, which differs in the last bit).

Why this S:

* W transforms with the units (T W) and is bounded with 0 inside (Assumption 1), so e_i > 0 always
  and, for the same system in units T, S̃ T = c S with c = max_j(t_j e_j) / max_j e_j: the normalised
  problems of all diagonal units differ by the common factor c only, for which the design is
  unit-free (the gain LMI, ``backends/gain_scaling.py``; the templates, X_f and every
  check work on rows with right-hand side 1). Z is not used: it may leave states unbounded.
* s_i = max e / e_i (not 1 / e_i): S = I exactly when W's extents are equal, and then the design is
  the one as written, bit for bit (every file in ``examples/`` has equal extents). Extents equal up
  to :data:`EXTENT_RTOL` count as equal (vertex enumeration's round-off must not move a design).
* The common factor: the design is unit-free under a common factor only while the sets
  are of moderate size (absolute tolerances on vertices and row entries), so a W whose largest
  extent lies outside :data:`EXTENT_BAND` is brought to [0.01, 0.1) by a power of ten,
  c = :func:`common_factor`; inside the band c = 1 and the design is as before, bit for bit.
  Example 1 in x̃ = 1e-4 x, 1e6 x, 1e8 x designs a 12-facet, a 20-facet X0 and nothing without the
  common factor; with it, the mapped 8-facet design (tests/test_units.py).

Acceptance in the user's units. The automatic mode judges every candidate by
:func:`~amcp_drake.offline.checks.verify_design` on the design *mapped back to x*, so the design it
returns passes every check in the user's units by construction; when none does,
:class:`~amcp_drake.offline.auto.AutoDesignError` lists every attempt as before. A fixed template
is not checked by the design (as in the user's units, the certificate judges it), except for what
the change of units could break: a check that passes in ξ and fails on the mapped design in x raises
:class:`UnitsMappingError` naming it; a check failing in both is the template's own result and is
returned as a design with a balanced W would be.

Measured (tests/test_units.py, benchmarks/units_twins.py, docs/decisions.md): every file in
``examples/`` designs bit for bit as before on both backends; Example 1 in diag(100, 0.01) gets
K̃T = K to 1e-11 (relative), massera2017 in diag(0.01, 100, 100) to 2e-9; of 400 generated draws (Drake) in units
10^e a design in the file's units rejected 17 where their unscaled twins rejected 3, this design 3 and 3, every draw with its
twin's outcome and K̃T = K to 3.5e-7; of 150 on cvxpy 9 where the twins rejected 2, this design 2 and 2, every
draw with its twin's outcome (K̃T = K to 3.5e-4: the cvxpy gain LMI is less accurate under a common
factor than Drake's). The Drake figure 3.5e-7 holds for a gain LMI solved at its default tolerances;
with the tight first try twins differ by up to 4.2e-4 on Drake and 6.3e-4 on cvxpy
(``benchmarks/gain_twins.py``), because round-off (3e-16) decides whether the 1e-10 first try ends
Solved or stalls and is settled at 1e-8, where the flat optimum of trace(S) fixes K only to ~√1e-8
(docs/decisions.md, "The cvxpy gain LMI in Drake's form"); outcomes still agree draw by draw.

Opting out: ``design.state_units = "as written"`` designs in the units of the file. The recorded
regression problems of tests/data that pin an online defect on the design they were found with carry
it; a user may want it to reproduce a design made in given units.

There is deliberately no partial rule such as redoing the automatic design in ξ = diag(1/e) x only
when every candidate failed in x and W's extents differed by 1.5× or more: that would leave the
design of a problem that passes in x depending on its units. There is no fallback to the units as written: a design
found in x but not in ξ would make the outcome depend on the units again.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from amcp_drake.model.errors import DesignError
from amcp_drake.model.problem import DesignOptions, Problem
from amcp_drake.model.state_units import scale_states
from amcp_drake.offline.result import OfflineDesign, regressor_sup

#: W's extents whose ratio to the largest is within this of 1 count as equal (s_i = 1 exactly): the
#: extents come from Qhull's vertices of W, accurate to ~1e-12 relative; rescaling by less than 1e-9
#: would only move the design in its last digits, breaking the bit-for-bit promise for balanced W.
EXTENT_RTOL = 1e-9
#: W's largest extent (in the units of the file) for which the design keeps the file's common scale
#: (c = 1, :func:`common_factor`). The design works with absolute tolerances on vertex coordinates and
#: row entries (rounding of duplicate rows at 1e-10, the LPs' feasibility tolerances), so it is
#: unit-free only for sets of moderate size: Example 1 (largest extent 0.1) written in x̃ = t x
#: designs to the mapped design for t = 1e-3 … 1e5 (largest extent 1e-4 … 1e4) and not for t = 1e-4 (a
#: 12-facet X0 instead of 8) or t >= 1e6 (20 facets; no candidate passes from 1e7 on;
#: measured). The band [1e-4, 1e3] is that range (a decade inside it at the top) and contains every
#: file of examples/ (1e-3 … 0.1) and every unscaled generated draw (0.005 … 0.06), whose designs are
#: therefore unchanged.
EXTENT_BAND = (1e-4, 1e3)
#: A largest extent outside :data:`EXTENT_BAND` is brought into [0.01, 0.1) by a power of ten (c = 10^j,
#: exact enough: the design is mapped back by the same s, and the checks run in the user's units).
EXTENT_TARGET = (0.01, 0.1)


class UnitsMappingError(DesignError):
    """A fixed-template design made in normalised units failed, mapped back to the user's units, a
    design check it passed in the normalised units (``checks`` names them)."""

    def __init__(self, checks: list[str]) -> None:
        self.checks = checks
        super().__init__(
            "design in state units normalised by W (offline/units.py): mapped back to the user's units the "
            f"design fails {', '.join(checks)}, which it passes in the normalised units (a check at the edge "
            "of its round-off allowance). Next: give the problem in units where W's extents are equal, or "
            "another template (design.x0_template, design.x0_facets).")


def w_extents(problem: Problem) -> np.ndarray:
    """e_i = max_{w ∈ W} |w_i| from the vertices of W (W is bounded with 0 inside, so e_i > 0)."""
    return np.max(np.abs(problem.w_vertices()), axis=0)


def normalising_scales(problem: Problem, options: DesignOptions | None = None) -> np.ndarray:
    """s with ξ = diag(s) x: s_i = c · max_j e_j / e_i, the ratio exactly 1 where it is within
    :data:`EXTENT_RTOL` of 1, and c = :func:`common_factor` (max_j e_j), 1 inside the band of
    magnitudes the design is measured to be unit-free on (so s = 1 exactly for a W with equal
    extents of a usual size); all ones when ``options.state_units`` is "as written"."""
    if options is not None and options.state_units == "as written":
        return np.ones(problem.n)
    e = w_extents(problem)
    s = np.max(e) / e
    s[np.abs(s - 1.0) <= EXTENT_RTOL] = 1.0
    return s * common_factor(float(np.max(e)))


def common_factor(extent: float) -> float:
    """1 when W's largest extent lies in [:data:`EXTENT_BAND`], else the power of ten 10^j that puts
    it into [:data:`EXTENT_TARGET`] (the magnitude of W in every file of examples/ and of the
    generator's draws before their change of units)."""
    lo, hi = EXTENT_BAND
    if lo <= extent <= hi:
        return 1.0
    return 10.0 ** (np.log10(EXTENT_TARGET[0]) - np.floor(np.log10(extent)))  # extent·c = 10^frac · EXTENT_TARGET[0]


def is_identity(s: np.ndarray) -> bool:
    """True when ξ = x (every s_i == 1): the design is then made as written."""
    return bool(np.all(s == 1.0))


def to_normalised(problem: Problem, options: DesignOptions, s: np.ndarray) -> tuple[Problem, DesignOptions]:
    """(the problem in ξ = diag(s) x, the options with a given K, P, X0 mapped into ξ).

    ``mu_state_bound`` is left as it is: it only enters μ, which :func:`from_normalised` recomputes in x."""
    changes = {}
    if options.K is not None:
        changes["K"] = _rows_into(options.K, s)
    if options.P is not None:
        changes["P"] = _form_into(options.P, s)
    if options.x0_H is not None:
        changes["x0_H"] = _rows_into(options.x0_H, s)
    return scale_states(problem, s), replace(options, **changes)


def gain_to_normalised(gain: tuple | None, s: np.ndarray) -> tuple | None:
    """A (K, P, source) of ``robust_gain`` in x mapped into ξ = diag(s) x (None stays None)."""
    if gain is None:
        return None
    K, P, source = gain
    return _rows_into(K, s), _form_into(P, s), source


def _rows_into(M, s: np.ndarray) -> np.ndarray:
    """Rows of linear functions of x (K, H_x) written in ξ = diag(s) x: M x = (M diag(s)⁻¹) ξ."""
    return np.asarray(M, float) / s[None, :]


def _form_into(P, s: np.ndarray) -> np.ndarray:
    """A quadratic form of x written in ξ = diag(s) x: xᵀPx = ξᵀ(diag(s)⁻¹ P diag(s)⁻¹)ξ."""
    return np.asarray(P, float) / np.outer(s, s)


def from_normalised(design: OfflineDesign, s: np.ndarray, problem: Problem, options: DesignOptions,
                    gain: tuple | None = None) -> OfflineDesign:
    """The design of the problem in ξ = diag(s) x mapped back to x (module docstring); μ recomputed
    on ``problem`` (the user's units); a user-given K, P (``options`` or ``gain`` with source
    "given") returned exactly as given."""
    S, S_inv = np.diag(s), np.diag(1.0 / s)
    K, P = design.K @ S, S @ design.P @ S
    if options.K is not None and options.P is not None:
        K, P = np.asarray(options.K, float), np.asarray(options.P, float)
    elif gain is not None and gain[2] == "given":
        K, P = np.asarray(gain[0], float), np.asarray(gain[1], float)
    mu_found = regressor_sup(problem, options.mu_state_bound)
    mu_sup, region = mu_found.value, mu_found.region
    info = dict(design.info, state_units={"normalised_by": "W extents", "xi_equals_diag_times_x": s.tolist()})
    return replace(design, K=K, P=P, H_x=design.H_x @ S, X0_vertices=design.X0_vertices @ S_inv,
                   A_z=S_inv @ design.A_z @ S, H_T=design.H_T @ S,
                   mu=float(options.mu_fraction / mu_sup), mu_sup=float(mu_sup), mu_region=region, info=info,
                   mu_state_bound=options.mu_state_bound, mu_method=mu_found.detail)


__all__ = ["EXTENT_RTOL", "UnitsMappingError", "from_normalised", "gain_to_normalised", "is_identity",
           "normalising_scales", "to_normalised", "w_extents"]
