"""Section 4.1 (time-varying parameters), Proposition 19 on Example 1, both backends.

Deterministic scenarios with θ*_k drifting at (or below) the rate bound d_θ of Assumption 17:
for every k, θ*_k ∈ Θ_k (the claim that replaces Lemma 3's fixed θ*), θ*_{k+l} ∈ Θ_{l|k} for the
predicted sets (26) used in (28b), (x_k, u_k) ∈ Z, and 𝔻_t(x_k, Θ_k) ≠ ∅ at every step (recursive
feasibility). A negative control shows the membership check can fail: the same drift under the
time-invariant update (d_θ = 0) loses θ*_k.
"""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.status import SolveStatus
from amcp_drake.model.tolerances import SET_TOL
from amcp_drake.offline.design import design
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import simulate

# θ*_k ∈ Θ_k on unit rows and (x_k, u_k) ∈ Z (max(F x + G u − 1)) are judged at SET_TOL (model.tolerances), the
# tolerance of the certificate's claims of the same ids: the LP (9) is solved to ~1e-9 and Δ_k carries a margin
# of 1e-6 (controller.DELTA_MARGIN) in the safe direction; the QP's feasibility tolerance is ~1e-8.
STEPS = 30


@pytest.fixture(scope="module")
def example():
    spec = lorenzen2019_spec()
    return spec, design(spec.problem, spec.design, backend="drake")


def _drift_line(theta0, direction, rate, steps):
    """θ*_k = θ*_0 + k·rate·direction/‖direction‖ (exactly the rate bound), clipped to stay in the unit box."""
    direction = np.asarray(direction, float) / np.linalg.norm(direction)
    seq = np.array([np.asarray(theta0, float) + k * rate * direction for k in range(steps + 1)])
    return np.clip(seq, -1.0, 1.0)


def _drift_sine(theta0, rate, steps):
    """θ*_k = θ*_0 + a·(sin(ω k), cos(ω k) − 1, 0): step length 2a sin(ω/2) <= rate."""
    omega = 0.3
    a = rate / (2.0 * np.sin(omega / 2.0))
    k = np.arange(steps + 1)
    return np.asarray(theta0, float) + a * np.stack([np.sin(omega * k), np.cos(omega * k) - 1.0, 0 * k], axis=1)


SCENARIOS = {
    # to the face θ1 = 1 at the full rate, then along it; vertex disturbances make Θ_k tight
    "line_to_face_vertices_fixed": dict(seq=lambda th: _drift_line(th, [1.0, -0.5, 0.5], 0.02, STEPS), d_theta=0.02,
                                        disturbance="vertices", update="fixed", seed=3),
    "sine_uniform_window": dict(seq=lambda th: _drift_sine(th, 0.03, STEPS), d_theta=0.03, disturbance="uniform",
                                update="window", seed=5),
    "slow_line_uniform_fixed": dict(seq=lambda th: _drift_line(th, [-1.0, 1.0, 0.0], 0.005, STEPS), d_theta=0.01,
                                    disturbance="uniform", update="fixed", seed=7),
}


def _membership_margin(H, h, theta):
    norms = np.linalg.norm(H, axis=1)
    return float(np.min((h - H @ theta) / norms))


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_proposition19(example, backend, name):
    spec, d = example
    pr, sc = spec.problem, spec.scenario
    cfg = SCENARIOS[name]
    seq = cfg["seq"](sc.theta_star)
    assert np.max(np.linalg.norm(np.diff(seq, axis=0), axis=1)) <= cfg["d_theta"] + 1e-12
    ctrl = AdaptiveMPC(pr, d, backend=backend, options=OnlineOptions(update=cfg["update"], window=5,
                                                                     d_theta=cfg["d_theta"]))
    traj = simulate(ctrl, sc.x0, seq, STEPS, cfg["disturbance"], seed=cfg["seed"])
    # recursive feasibility: every QP (28) solved, the run completed
    assert traj.stop_reason == "completed"
    assert all(r.status is SolveStatus.OPTIMAL for r in traj.records)
    # θ*_k ∈ Θ_k at every k (Proposition 19)
    margins = [_membership_margin(r.H_theta, r.h_theta, traj.theta_star_at(r.k)) for r in traj.records]
    assert min(margins) >= -SET_TOL, (name, int(np.argmin(margins)), min(margins))
    # θ*_{k+l} ∈ Θ_{l|k} for the predicted sets (26) the QP used, and their form min(h_k + l d_θ, h_0)
    for r in traj.records:
        stages = r.h_theta_stages
        assert stages is not None and stages.shape == (pr.N, len(r.h_theta))
        np.testing.assert_allclose(stages[0], r.h_theta, rtol=0, atol=0)
        for l in range(pr.N):
            np.testing.assert_allclose(stages[l], np.minimum(r.h_theta + l * cfg["d_theta"], d.h_theta0), atol=1e-15)
            if r.k + l < len(seq):
                assert _membership_margin(r.H_theta, stages[l], seq[r.k + l]) >= -SET_TOL
    # (x_k, u_k) ∈ Z
    assert max(pr.in_Z(x, u) for x, u in zip(traj.x, traj.u)) <= SET_TOL


def test_time_invariant_update_loses_drifting_parameter(example, backend):
    """Negative control: with d_θ = 0 the update (9) assumes θ* constant and, under the drift of the
    first scenario, excludes θ*_k at some step. (The loop is run by hand, because simulate()
    rejects a sequence faster than the controller's d_θ.)"""
    spec, d = example
    pr, sc = spec.problem, spec.scenario
    seq = SCENARIOS["line_to_face_vertices_fixed"]["seq"](sc.theta_star)
    ctrl = AdaptiveMPC(pr, d, backend=backend, options=OnlineOptions(update="fixed"))
    W = pr.w_vertices()[np.random.default_rng(3).integers(len(pr.w_vertices()), size=STEPS)]
    x, worst = np.asarray(sc.x0, float), np.inf
    for k in range(STEPS):
        try:
            u, r = ctrl.step(x)
        except Exception:  # noqa: BLE001 - an empty Θ_{k-1} ∩ Δ_k also shows the data are inconsistent
            worst = -np.inf
            break
        worst = min(worst, _membership_margin(r.H_theta, r.h_theta, seq[k]))
        if u is None:
            break
        x = pr.step(x, u, seq[k], W[k])
    assert worst < -1e-3


def test_simulate_rejects_sequence_faster_than_rate(example):
    spec, d = example
    sc = spec.scenario
    seq = _drift_line(sc.theta_star, [0.0, 1.0, 0.0], 0.05, 5)
    ctrl = AdaptiveMPC(spec.problem, d, options=OnlineOptions(d_theta=0.02))
    with pytest.raises(ProblemError, match="Assumption 17"):
        simulate(ctrl, sc.x0, seq, 5, "zero")


def test_unsupported_combinations_are_rejected(example):
    spec, d = example
    with pytest.raises(ProblemError, match="formulation='plain'"):
        AdaptiveMPC(spec.problem, d, options=OnlineOptions(d_theta=0.01), formulation="vertex")
    with pytest.raises(ProblemError, match="exact"):
        OnlineOptions(update="exact", d_theta=0.01)
