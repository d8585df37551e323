"""Vertices and support values of a polytope {H y <= h} with the design backend's LPs.

Shared by the two row recursions of the offline design: the terminal set X_f of Appendix A.1
(:func:`amcp_drake.offline.design.terminal_set`, on (z, α) with α >= 0) and the contractive X0
template (:mod:`amcp_drake.offline.templates`). Each works on a set that may be unbounded while the
recursion runs; when it is bounded, the support of many directions is read off its vertices (one
vertex enumeration instead of one LP per direction).
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model import polytope


def bounded_vertices(H: np.ndarray, h: np.ndarray, be) -> np.ndarray | None:
    """Vertices of {H y <= h} when it is bounded (checked by the backend's support LPs along ±e_i),
    else None (also when the vertex enumeration fails)."""
    dim = H.shape[1]
    extent = be.support(H, h, np.vstack([np.eye(dim), -np.eye(dim)]))
    if not np.all(np.isfinite(extent)):
        return None
    try:
        return polytope.vertices(H, h)
    except (ValueError, RuntimeError):
        return None


def row_maxima(H: np.ndarray, h: np.ndarray, directions: np.ndarray, be) -> np.ndarray:
    """max over {H y <= h} of each row of ``directions``: by the vertices when the set is bounded,
    else by the backend's support LPs (NaN where an LP fails)."""
    verts = bounded_vertices(H, h, be)
    if verts is not None:
        return np.max(directions @ verts.T, axis=1)
    return be.support(H, h, directions)
