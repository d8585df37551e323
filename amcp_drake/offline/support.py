"""Vertices and support values of a polytope {H y <= h} with the design backend's LPs.

Shared by the two row recursions of the offline design: the terminal set X_f of Appendix A.1
(:func:`amcp_drake.offline.design.terminal_set`, on (z, α) with α >= 0) and the contractive X0
template (:mod:`amcp_drake.offline.templates`). Each works on a set that may be unbounded while the
recursion runs; when it is bounded, the support of many directions is read off its vertices (one
vertex enumeration instead of one LP per direction). Both the vertex enumeration and the products
directions × vertices are sized against the design's memory limit first and computed in bounded
chunks (:mod:`amcp_drake.offline.budget`).
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.offline.budget import DesignBudget, chunked_row_maxima, unbounded


def bounded_vertices(H: np.ndarray, h: np.ndarray, be, budget: DesignBudget | None = None,
                     stage: str = "vertex enumeration") -> np.ndarray | None:
    """Vertices of {H y <= h} when it is bounded (checked by the backend's support LPs along ±e_i),
    else None (also when the vertex enumeration fails). Raises DesignSizeError, before Qhull runs,
    when the upper-bound-theorem estimate of the vertex enumeration exceeds the memory limit."""
    budget = budget or unbounded()
    dim = H.shape[1]
    extent = be.support(H, h, np.vstack([np.eye(dim), -np.eye(dim)]))
    if not np.all(np.isfinite(extent)):
        return None
    budget.require_vertices(stage, len(H), dim)
    budget.tick(stage)
    try:
        verts = polytope.vertices(H, h)
    except (ValueError, RuntimeError):
        return None
    budget.note_vertices(len(H), dim, len(verts))
    return verts


def row_maxima(H: np.ndarray, h: np.ndarray, directions: np.ndarray, be, budget: DesignBudget | None = None,
               stage: str = "support values", failures: list[str] | None = None) -> np.ndarray:
    """max over {H y <= h} of each row of ``directions``: by the vertices when the set is bounded
    (in chunks of rows), else by the backend's support LPs (NaN where an LP fails; the solver status
    of each failed LP, where the backend reports it, is appended to ``failures``)."""
    budget = budget or unbounded()
    verts = bounded_vertices(H, h, be, budget, stage)
    if verts is not None:
        return chunked_row_maxima(directions, verts, budget, stage)
    out = np.empty(len(directions))
    step = 64
    for start in range(0, len(directions), step):
        budget.tick(stage)
        out[start:start + step] = be.support(H, h, directions[start:start + step])
        if failures is not None:
            failures.extend(getattr(be, "last_support_failures", None) or [])
    return out
