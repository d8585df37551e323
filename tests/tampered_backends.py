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


def use_as_drake(monkeypatch, cls: type) -> None:
    """Register ``cls`` (a class of this module) as the backend named "drake" for one test."""
    monkeypatch.setitem(REGISTRY, "drake", (__name__, cls.__name__, ("pydrake",)))
