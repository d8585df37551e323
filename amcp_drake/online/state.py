"""The controller's state: everything of the online loop (docs/explanation/paper.md §6) that changes from
step to step, as one immutable value.

:class:`ControllerState` is what :meth:`AdaptiveMPC.step_from <amcp_drake.online.controller.AdaptiveMPC.step_from>`
reads and returns: Θ_k's rows and offsets (H_θ, h_θ of (7)/(9)), θ̂_k of (12), the previous measured state
and applied input (x_{k−1}, u_{k−1}) that Δ_k (6) needs, the data sets of the moving window (Remark 4), the
inputs the PE constraint of Section 4.2 reads, k, and the caches whose content can change an answer.
Its arrays are read-only copies, so a state can be kept, shared and stepped again: two states stepped by
one controller are two independent runs. A Drake ``Context`` holds one as an abstract state
(:mod:`amcp_drake.systems`).

:class:`StepState` is the working copy of one step (mutable, private to the step): the step's methods
update it, and :meth:`StepState.freeze` makes the next state.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

#: Fields of ControllerState that hold one array each.
_ARRAY_FIELDS = ("H_theta", "h_theta", "theta_hat")


def frozen_array(a) -> np.ndarray:
    """``a`` as a read-only float array that nothing else writes to: itself when it is already one made
    here (read-only and owning its data), else a read-only copy."""
    if type(a) is np.ndarray and a.dtype == np.float64 and not a.flags.writeable and a.flags.owndata:
        return a
    out = np.array(a, dtype=float)
    out.setflags(write=False)
    return out


def _frozen_pair(pair) -> tuple[np.ndarray, np.ndarray] | None:
    return None if pair is None else (frozen_array(pair[0]), frozen_array(pair[1]))


@dataclass(frozen=True)
class ControllerState:
    """Everything of :class:`~amcp_drake.online.controller.AdaptiveMPC` that changes from step to step.

    ``k``: the index of the next step; ``H_theta`` (q_k, p), ``h_theta`` (q_k,): Θ_k of (7)/(9) (``H_theta``
    changes only under the exact update (7)); ``theta_hat`` (p,): θ̂_k of (12); ``prev``: (x_{k−1}, u_{k−1})
    of the last step whose QP (20) was solved (None before the first), the data of Δ_k (6);
    ``window``: the data sets Δ of the moving window (Remark 4), newest first; ``u_hist``: the last inputs
    the PE constraint of Section 4.2 reads (m = 1; at most pe_window + n of them);
    ``exact_rows_irredundant``: Θ_k is the result of (7), every row irredundant (a row of Δ_k that does
    not cut Θ_{k−1} is then dropped without a redundancy LP of its own); ``checked_vertices``:
    (H_θ, h_θ, vertices) of the last Θ_k whose vertices the answer check of (20) enumerated (Qhull from
    θ̂ as interior point: the vertices' round-off depends on the run, so the cache is part of the run's state).

    Immutable: the arrays are read-only copies (:func:`frozen_array`); :meth:`replace` returns a new state.
    """

    k: int
    H_theta: np.ndarray
    h_theta: np.ndarray
    theta_hat: np.ndarray
    prev: tuple[np.ndarray, np.ndarray] | None = None
    window: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    u_hist: tuple[float, ...] = ()
    exact_rows_irredundant: bool = False
    checked_vertices: tuple[np.ndarray, np.ndarray, np.ndarray | None] | None = None

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        set_(self, "k", int(self.k))
        for name in _ARRAY_FIELDS:
            set_(self, name, frozen_array(getattr(self, name)))
        set_(self, "prev", _frozen_pair(self.prev))
        set_(self, "window", tuple(_frozen_pair(w) for w in self.window))
        set_(self, "u_hist", tuple(float(u) for u in self.u_hist))
        set_(self, "exact_rows_irredundant", bool(self.exact_rows_irredundant))
        cv = self.checked_vertices
        if cv is not None:
            set_(self, "checked_vertices", (frozen_array(cv[0]), frozen_array(cv[1]),
                                            None if cv[2] is None else frozen_array(cv[2])))

    def replace(self, **changes) -> ControllerState:
        """A new state with ``changes`` (field names as above; arrays are copied read-only)."""
        return replace(self, **changes)

    def working(self) -> StepState:
        """The mutable working copy of one step, starting from this state."""
        return StepState(k=self.k, H_theta=self.H_theta, h_theta=self.h_theta, theta_hat=self.theta_hat,
                         prev=self.prev, window=list(self.window), u_hist=list(self.u_hist),
                         exact_rows_irredundant=self.exact_rows_irredundant, checked_vertices=self.checked_vertices,
                         origin=self)

    def same_as(self, other: ControllerState) -> bool:
        """Equal field by field, arrays to the bit (shape and every float)."""
        def same(a, b) -> bool:
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape
                        and a.tobytes() == b.tobytes())
            if isinstance(a, tuple) and isinstance(b, tuple):
                return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
            return a == b
        return all(same(getattr(self, f.name), getattr(other, f.name)) for f in fields(self))


@dataclass
class StepState:
    """The working copy of one step (see the module docstring): the fields of :class:`ControllerState`,
    writable, plus the step's scratch (the regression (D_{k−1}, d_k) of (6), computed once per step)."""

    k: int
    H_theta: np.ndarray
    h_theta: np.ndarray
    theta_hat: np.ndarray
    prev: tuple[np.ndarray, np.ndarray] | None
    window: list
    u_hist: list
    exact_rows_irredundant: bool
    checked_vertices: tuple | None
    #: (x_prev, u_prev, x, D, d) of this step (the arguments compared by identity), or None
    regression: tuple | None = None
    #: the state this working copy started from (its values are frozen already)
    origin: ControllerState | None = None

    def freeze(self) -> ControllerState:
        """The state after the step: the values the step did not replace are the origin's (shared, not
        copied), the others are frozen as by the constructor (the same result, without re-checking the
        origin's values at every step)."""
        o = self.origin
        if o is None:
            return ControllerState(k=self.k, H_theta=self.H_theta, h_theta=self.h_theta, theta_hat=self.theta_hat,
                                   prev=self.prev, window=tuple(self.window), u_hist=tuple(self.u_hist),
                                   exact_rows_irredundant=self.exact_rows_irredundant,
                                   checked_vertices=self.checked_vertices)
        window = self.window
        same_window = len(window) == len(o.window) and all(a is b for a, b in zip(window, o.window))
        cv = self.checked_vertices
        new = object.__new__(ControllerState)
        new.__dict__.update(
            k=int(self.k),
            H_theta=o.H_theta if self.H_theta is o.H_theta else frozen_array(self.H_theta),
            h_theta=o.h_theta if self.h_theta is o.h_theta else frozen_array(self.h_theta),
            theta_hat=o.theta_hat if self.theta_hat is o.theta_hat else frozen_array(self.theta_hat),
            prev=o.prev if self.prev is o.prev else _frozen_pair(self.prev),
            window=o.window if same_window else tuple(_frozen_pair(w) for w in window),
            u_hist=tuple(float(u) for u in self.u_hist) if self.u_hist else (),
            exact_rows_irredundant=bool(self.exact_rows_irredundant),
            checked_vertices=(cv if cv is o.checked_vertices or cv is None else
                              (frozen_array(cv[0]), frozen_array(cv[1]), None if cv[2] is None else frozen_array(cv[2]))))
        return new


__all__ = ["ControllerState", "StepState", "frozen_array"]
