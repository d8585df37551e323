"""The projection QP of (12) in the form both backends hand to their solver.

Π_S(θ̃) = argmin{‖θ − θ̃‖² | H θ <= h} is solved in the coordinates y = (θ − θ̃)/s on unit rows,

    min ‖y‖²  s.t.  Ĥ_in y <= b_in,  Ĥ_eq y = b_eq,   θ = θ̃ + s y,

for two reasons, both found on sets Θ_k that the update (9) collapses to (nearly) a point or a
lower-dimensional set (θ* pinned by vertex disturbances; campaign problem 0-19):

* **Scale.** s is the largest violation of a row by θ̃ (at least :data:`SCALE_FLOOR` times the
  largest distance to a facet plane), so the data the solver sees are of order 1 (offsets <= 1e3). In θ itself the cvxpy backend (which had no such scaling) ended Clarabel "AlmostSolved"
  on 0-19 (Θ_1 of width ~3e-6, θ̃ 0.55 away, tolerances 1e-11), and the controller then silently
  projected onto Θ instead of Θ_1: a point 0.55 outside Θ_1 recorded as optimal. The Drake backend
  used this scaling already (θ̃ 1e-5 outside a Θ_k of width 2e-6 was off by 1.7e-6 without it).
* **Flat slabs.** A pair of opposite rows a·θ <= h_i, −a·θ <= h_j whose slab width h_i + h_j is at
  most :data:`FLAT_SLAB_WIDTH` (θ units, unit rows) gives a set with no interior, on which an
  interior-point solver stalls ("inaccurate" in both backends at widths ~1e-9, and a false
  "infeasible" when round-off makes the width −1e-12). Such a pair is passed as the equality
  a·θ = (h_i − h_j)/2, the mid-plane of the slab: every point it allows lies in the slab when the
  width is >= 0, the optimum moves by at most width/2 <= 5e-9, and a slab emptied by round-off
  (width in [−FLAT_SLAB_WIDTH, 0)) is answered by the point nearest to both rows instead of
  "infeasible". Only exactly opposite rows (cosine −1 up to :data:`OPPOSITE_COS_TOL`) are paired,
  so the mid-plane is a subset of the slab; other lower-dimensional shapes are left to the solver
  and to the controller's answer checks (:mod:`amcp_drake.online.answer_checks`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: (Named tolerances with their reasons, as in model/problem.py: `duplicates` pairs the two blocks by
#: shape only; the values and reasons differ.)
#: Opposite unit rows closer than this (θ units) form an equality at their mid-plane. 1e-8 keeps the
#: error of the projection (<= width/2 = 5e-9) an order below the certificate's PROJECTION_TOL
#: (1e-7) and above the widths (~1e-9) at which Clarabel stalled in both backends.
FLAT_SLAB_WIDTH = 1e-8
#: The scale s is the largest violation of a row by θ̃ (so ‖y*‖ >= 1: the optimum is not lost in the
#: solver's absolute tolerances when θ̃ is just outside a thin set; 3e-7 error at s = max |slack|), but
#: at least this fraction of the largest |slack|: with θ̃ outside by round-off only (1e-12, campaign
#: problem 13) s = violation made the other offsets 1e12 and Clarabel ended "inaccurate" in both
#: backends. With the floor every offset is <= 1e3 in y.
SCALE_FLOOR = 1e-3
#: Two unit rows are "opposite" when their inner product is <= −1 + this (round-off of the
#: normalisation only: 1e-12 means the mid-plane differs from the slab by < 1e-12 per unit length).
OPPOSITE_COS_TOL = 1e-12


@dataclass(frozen=True, eq=False)
class ProjectionForm:
    """The scaled QP: ``G_in`` (r, p) y <= ``b_in``, ``G_eq`` (e, p) y = ``b_eq``, θ = point + scale y."""

    point: np.ndarray
    scale: float
    G_in: np.ndarray
    b_in: np.ndarray
    G_eq: np.ndarray
    b_eq: np.ndarray

    def theta(self, y: np.ndarray) -> np.ndarray:
        """θ of a solution y of the scaled QP."""
        return self.point + self.scale * np.asarray(y, float)


def projection_form(point: np.ndarray, H: np.ndarray, h: np.ndarray) -> ProjectionForm:
    """The scaled form of argmin{‖θ − point‖² | H θ <= h} (module docstring). Rows of zero norm
    are kept as they are (0 <= h_i: the solver decides feasibility)."""
    point = np.asarray(point, float)
    H = np.asarray(H, float)
    h = np.asarray(h, float)
    norms = np.linalg.norm(H, axis=1)
    unit = norms > 0
    safe = np.where(unit, norms, 1.0)
    Hn, hn = H / safe[:, None], h / safe
    slack = hn - Hn @ point
    violation = float(np.max(-slack[unit])) if np.any(unit) else 0.0
    reach = float(np.max(np.abs(slack[unit]))) if np.any(unit) else 1.0
    scale = max(violation, SCALE_FLOOR * reach)
    scale = scale if np.isfinite(scale) and scale > 0.0 else 1.0
    paired = np.zeros(len(h), dtype=bool)
    eq_rows, eq_rhs = [], []
    if np.any(unit):
        cos = Hn @ Hn.T
        for i in range(len(h)):
            if paired[i] or not unit[i]:
                continue
            for j in range(i + 1, len(h)):
                if paired[j] or not unit[j] or cos[i, j] > -1.0 + OPPOSITE_COS_TOL:
                    continue
                if abs(hn[i] + hn[j]) <= FLAT_SLAB_WIDTH:
                    paired[i] = paired[j] = True
                    eq_rows.append(Hn[i])
                    eq_rhs.append(0.5 * (slack[i] - slack[j]) / scale)
                    break
    keep = ~paired
    p = H.shape[1]
    return ProjectionForm(point=point, scale=scale, G_in=Hn[keep], b_in=slack[keep] / scale,
                          G_eq=np.array(eq_rows, float).reshape(-1, p), b_eq=np.array(eq_rhs, float))
