"""Online options of the adaptive MPC (docs/explanation/paper.md §6 and Section 4): the update of Θ_k, the projection of
(12), and the Section 4 extensions (time-varying θ, persistent excitation, min–max cost).

Part of the model layer so that problem files (``problem_io``) can hold them without importing the
online loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from amcp_drake.model.errors import ProblemError

UPDATE_MODES = ("fixed", "exact", "window", "none")
PROJECTION_TARGETS = ("Theta", "Theta_k")
COSTS = ("certainty_equivalence", "minmax")


@dataclass(frozen=True)
class OnlineOptions:
    """Online choices. ``update``: ``"fixed"`` = fixed-complexity LP (9) (default), ``"exact"`` =
    intersection (7) with redundant rows removed, ``"window"`` = (9) over the last ``window``
    data sets Δ (Remark 4), ``"none"`` = the robust (non-adaptive) baseline: Θ_k ≡ Θ0 and θ̂_k ≡ θ̂0.
    ``projection``: project θ̃ onto Θ (eq. (12)) or onto Θ_k (Remark 7).

    ``d_theta`` (Section 4.1, Assumption 17): rate bound ‖θ*_{k+1} − θ*_k‖ <= d_θ of a time-varying
    parameter. With d_θ > 0 the update is (25) in fixed-complexity form, h_θk ← min(h_(9) + d_θ n,
    h_θ0) with n_i = ‖[H_θ]_i‖, and the QP (20) uses the predicted sets (26) per stage,
    Θ_{l|k} = {H_θ θ <= min(h_θk + l d_θ n, h_θ0)} in (28b). Supported for update "fixed", "window"
    and "none" with the plain formulation (docs/decisions.md, "Section 4 extensions").

    ``pe_window``, ``pe_level`` (Section 4.2 of the paper): when ``pe_window`` = P is set (m = 1 only), the
    input is kept persistently exciting by Σ_{j=k−P+1}^{k} ū_j ū_jᵀ ⪰ ρ I (ρ = ``pe_level``) on the
    stacked input ū_k = [u_k; …; u_{k−n}]: (20) is solved with K x_k + v_{0|k} <= u₋ and with
    >= u₊ and the cheaper solution is applied; with no feasible one, (20) without the PE constraint
    (recorded as ``pe_status = "fallback"``).

    ``cost``: ``"certainty_equivalence"`` (17)-(18) with θ̂_k, or ``"minmax"``: the worst case over the
    tube vertices (19), Σ_l max_j (‖x^j_l‖²_Q + ‖u^j_l‖²_R) + max_j ‖x^j_N‖²_P, in epigraph form
    (Remark 13; plain formulation only)."""

    update: str = "fixed"
    window: int = 10
    projection: str = "Theta"
    d_theta: float = 0.0
    pe_window: int | None = None
    pe_level: float = 0.1
    cost: str = "certainty_equivalence"

    def __post_init__(self) -> None:
        if self.update not in UPDATE_MODES:
            raise ProblemError("online.update", f"one of {UPDATE_MODES}", repr(self.update))
        if isinstance(self.window, bool) or not isinstance(self.window, int) or self.window < 1:
            raise ProblemError("online.window", "an integer >= 1", repr(self.window))
        if self.projection not in PROJECTION_TARGETS:
            raise ProblemError("online.projection", f"one of {PROJECTION_TARGETS}", repr(self.projection))
        if isinstance(self.d_theta, bool) or not isinstance(self.d_theta, (int, float)) \
                or not np.isfinite(self.d_theta) or self.d_theta < 0:
            raise ProblemError("online.d_theta", "a finite number >= 0 (Assumption 17)", repr(self.d_theta))
        object.__setattr__(self, "d_theta", float(self.d_theta))
        if self.pe_window is not None and (isinstance(self.pe_window, bool) or not isinstance(self.pe_window, int)
                                           or self.pe_window < 1):
            raise ProblemError("online.pe_window", "None or an integer >= 1", repr(self.pe_window))
        if isinstance(self.pe_level, bool) or not isinstance(self.pe_level, (int, float)) \
                or not np.isfinite(self.pe_level) or self.pe_level <= 0:
            raise ProblemError("online.pe_level", "a finite number > 0 (ρ of the PE constraint)", repr(self.pe_level))
        object.__setattr__(self, "pe_level", float(self.pe_level))
        if self.cost not in COSTS:
            raise ProblemError("online.cost", f"one of {COSTS}", repr(self.cost))
        if self.d_theta > 0 and self.update == "exact":
            raise ProblemError("online.d_theta", "0 with update 'exact' (time-varying parameters need the "
                               "fixed-shape update 'fixed' or 'window', Section 4.1)", repr(self.d_theta))
