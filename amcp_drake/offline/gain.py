"""One solve of the gain LMI (16) under the design's time budget."""

from __future__ import annotations

import inspect

from amcp_drake.offline.budget import DesignBudget, unbounded


def gain_lmi(be, A_v, B_v, Q, R, margin: float, budget: DesignBudget | None = None):
    """``be.robust_gain`` (the LMI (16) at the vertices (A_v, B_v)) with the budget's ``tick`` checked
    before and after it and passed to a backend whose ``robust_gain`` takes it (the Drake backend calls
    it before every solve of its retry ladder and of its active-vertex loop): a candidate over its time
    budget stops with CandidateTimeout naming the gain LMI."""
    tick = (budget or unbounded()).tick
    tick("gain LMI (16)")
    if "tick" in inspect.signature(be.robust_gain).parameters:
        result = be.robust_gain(A_v, B_v, Q, R, margin, tick=tick)
    else:
        result = be.robust_gain(A_v, B_v, Q, R, margin)
    tick("gain LMI (16)")
    return result


__all__ = ["gain_lmi"]
