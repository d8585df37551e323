"""Drake backends with a seeded defect, each a subclass of the real one (no patch of the library).

Registered under the name "drake" for one test with :func:`use_as_drake`, so that every path that
builds a backend by name (the controller's other formulation, ``amcp compare``, ``amcp certify``)
gets the defective one. Each defect is in the backend's *answer*; the answer checks must reject it,
the controller must fall back, and the certificate and ``amcp compare`` must say so.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from amcp_drake.backends import REGISTRY
from amcp_drake.backends.drake_ import DrakeBackend
from amcp_drake.backends.drake_tube import DrakeTubeMPC
from amcp_drake.backends.set_update_vertices import VertexSetUpdate
from amcp_drake.model.arrays import same_bits


class _ShiftedPlainQP:
    """The plain form's QP (20) whose every answer has v shifted by ``shift`` (the program is right,
    the answer returned is not). Everything else is the wrapped solver's."""

    def __init__(self, inner, shift: float) -> None:
        self._inner = inner
        self._shift = shift

    def __getattr__(self, name):
        return getattr(self._inner, name)

    def solve(self, *args, **kwargs):
        sol = self._inner.solve(*args, **kwargs)
        if sol.v is None:
            return sol
        return replace(sol, v=np.asarray(sol.v, float) + self._shift)


class WrongTubeDrake(DrakeBackend):
    """Every answer of the plain form of (20) has v shifted by 0.5; the vertex form is untouched."""

    def tube_mpc(self, data):
        inner = super().tube_mpc(data)
        return _ShiftedPlainQP(inner, 0.5) if self.formulation == "plain" else inner


class WrongSetUpdateDrake(DrakeBackend):
    """Every answer of the set update (9) has its offsets h raised by 0.3 (multipliers unchanged)."""

    def set_update(self, H_theta, h_prev, H_data, h_data):
        result = super().set_update(H_theta, h_prev, H_data, h_data)
        if result.h is None:
            return result
        return replace(result, h=np.asarray(result.h, float) + 0.3)


class StaleSetUpdateDrake(DrakeBackend):
    """The set update (9) is given Θ_0's offsets instead of Θ_(k−1)'s (a stale argument)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._h0 = None

    def set_update(self, H_theta, h_prev, H_data, h_data):
        if self._h0 is None:
            self._h0 = np.array(h_prev, float)
        return super().set_update(H_theta, self._h0, H_data, h_data)


class WrongProjectionDrake(DrakeBackend):
    """Every projection (12) is off by 0.05 in its first coordinate."""

    def project(self, point, H, h):
        result = super().project(point, H, h)
        if result.theta is None:
            return result
        theta = np.array(result.theta, float)
        theta[0] += 0.05
        return replace(result, theta=theta)


class IgnoresLastDataRowDrake(DrakeBackend):
    """The set update (9) leaves out the last row of the data Δ_k (its multipliers padded with a zero
    column): where that row cuts Θ_(k−1), the offsets and maximisers are those of a larger set."""

    def set_update(self, H_theta, h_prev, H_data, h_data):
        H_data, h_data = np.asarray(H_data, float), np.asarray(h_data, float)
        if len(h_data) < 2:
            return super().set_update(H_theta, h_prev, H_data, h_data)
        result = super().set_update(H_theta, h_prev, H_data[:-1], h_data[:-1])
        if result.Lambda is None:
            return result
        return replace(result, Lambda=np.hstack([result.Lambda, np.zeros((len(result.Lambda), 1))]))


class LowSupportDrake(DrakeBackend):
    """The support LPs answer 0.1 too low, so the redundancy test of the exact update (7) removes rows
    that cut Θ_(k−1)."""

    def support(self, H, h, directions):
        return super().support(H, h, directions) - 0.1


class _DroppedConstraintTube(DrakeTubeMPC):
    """The plain form's program (20) built without the constraints named by ``DROP`` (a description of
    drake_tube.py) and, if ``BOUNDS_ONLY``, only its bounding-box binding (Λ_N >= 0, not the rows Λ_B >= 0)."""

    DROP = ""
    BOUNDS_ONLY = False

    def _build(self, H_theta, capacity=None):
        super()._build(H_theta, capacity)
        bindings = self.prog.bounding_box_constraints() if self.BOUNDS_ONLY else self.prog.GetAllConstraints()
        dropped = [b for b in bindings if b.evaluator().get_description() == self.DROP]
        assert dropped, f"no constraint {self.DROP!r} in the program"
        for b in dropped:
            self.prog.RemoveConstraint(b)


class _NoLambdaNBoundTube(_DroppedConstraintTube):
    DROP, BOUNDS_ONLY = "Lambda >= 0", True


class _NoTerminalSetTube(_DroppedConstraintTube):
    DROP = "terminal set (z_N, alpha_N) in Xf"


class _WrongVertexTube(DrakeTubeMPC):
    """The pruning of dominated rows of (15c) (dominated_rows.kept_vertices) judges each facet [H_x]_i by the
    next vertex of X0 instead of its own: the mask (u, v) of kept rows shifted by one vertex."""

    def _kept_vertices(self, Acl0, Acl_i):
        keep, h0 = super()._kept_vertices(Acl0, Acl_i)
        return np.roll(keep, 1, axis=1), h0


class _PlainTubeDrake(DrakeBackend):
    TUBE: type = DrakeTubeMPC

    def tube_mpc(self, data):
        if self.formulation == "plain":
            return self.TUBE(data, self._solver)
        return super().tube_mpc(data)


class NoLambdaNBoundDrake(_PlainTubeDrake):
    """The plain form of (20) without Λ_N >= 0 (the free multipliers of (15c)-(15d), multiplier_basis)."""

    TUBE = _NoLambdaNBoundTube


class NoTerminalSetDrake(_PlainTubeDrake):
    """The plain form of (20) without the terminal constraint H_T z_N + h_T α_N <= 1."""

    TUBE = _NoTerminalSetTube


class WrongVertexDrake(_PlainTubeDrake):
    """The plain form of (20) with the rows of (15c) pruned by the wrong vertex (:class:`_WrongVertexTube`)."""

    TUBE = _WrongVertexTube


class _ReuseIgnoresLastRow(VertexSetUpdate):
    """The exact update by vertices whose reuse test (does Δ_k cut a vertex of Θ_(k−1)?) ignores the last row
    of Δ_k: when only that row cuts, the vertices of Θ_(k−1) alone are reused and h_k is too large."""

    def solve(self, H_theta, h_prev, H_data, h_data):
        H_data, h_data = np.atleast_2d(np.asarray(H_data, float)), np.asarray(h_data, float)
        if len(h_data) < 2:
            return super().solve(H_theta, h_prev, H_data, h_data)
        last = self._last
        if last is None or not (same_bits(last[1], np.asarray(h_prev, float)) and same_bits(last[0], np.asarray(H_theta, float))):
            super().solve(H_theta, h_prev, H_data[:0], h_data[:0])   # enumerates Θ_(k−1) alone into self._last
            last = self._last
        if last is not None and np.all(last[2] @ H_data[:-1].T <= h_data[:-1]):
            Lam = np.zeros((len(h_prev), len(h_prev) + len(h_data)))
            Lam[:, :len(h_prev)] = last[4]
            return last[3].copy(), Lam, last[5].copy()
        return super().solve(H_theta, h_prev, H_data, h_data)


class ReuseIgnoresLastRowDrake(DrakeBackend):
    """The exact update (9) by vertices with the reuse test that ignores the last data row."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._vertex_update = _ReuseIgnoresLastRow()


class UnboundedSupportDrake(DrakeBackend):
    """Support LPs over a set of at least 8 rows (W and X0 of a 4-state chain, not its Θ) report the
    first direction "unbounded" (+inf), as a solver does on badly scaled rows; the set is bounded."""

    def support(self, H, h, directions):
        values = np.array(super().support(H, h, directions), float)
        if len(np.asarray(H)) >= 8 and len(values):
            values[0] = np.inf
        return values


def use_as_drake(monkeypatch, cls: type) -> None:
    """Register ``cls`` (a class of this module) as the backend named "drake" for one test."""
    monkeypatch.setitem(REGISTRY, "drake", (__name__, cls.__name__, ("pydrake",)))
