"""The automatic design on generated systems of 4 to 6 states (the campaign's generator, seeded): every
design check of offline/checks.py passes, and the template's contractivity λ̄, the disturbance support w̄
and X_f ⊆ Z under u = Kx are recomputed here from vertices with numpy alone."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.model import polytope
from amcp_drake.offline.checks import verify_design
from amcp_drake.studies.random_problems import random_case

CASES = [(4, 0), (4, 1), (5, 0), (5, 1), (6, 0), (6, 1)]


@pytest.fixture(scope="module")
def designs():
    return {(n, seed): random_case(np.random.default_rng(seed), steps=2, state_dims=(n, n)) for n, seed in CASES}


@pytest.mark.parametrize("n, seed", CASES)
def test_a_generated_design_passes_every_check_and_its_template_is_contractive_by_hand(designs, n, seed):
    case = designs[(n, seed)]
    pr, d = case.problem, case.design
    assert pr.n == n
    failed = [(c.name, c.detail) for c in verify_design(pr, d, case.spec.design.mu_state_bound) if not c.passed]
    assert failed == []
    theta_v = polytope.vertices(pr.H_theta, pr.h_theta)
    lam = max(float(np.max(d.H_x @ (pr.A_of(t) + pr.B_of(t) @ d.K) @ d.X0_vertices.T)) for t in theta_v)
    assert lam < 1.0
    assert lam == pytest.approx(d.lambda_bar, abs=1e-7)
    w_bar = np.max(d.H_x @ pr.w_vertices().T, axis=1)
    np.testing.assert_allclose(d.w_bar, w_bar, rtol=0, atol=1e-9)


@pytest.mark.parametrize("n, seed", CASES)
def test_a_generated_terminal_set_lies_in_z_under_the_terminal_gain(designs, n, seed):
    """(x, Kx) ∈ Z for x = z + α x0 with (z, α) at the vertices of X_f (a polytope in n + 1 dimensions)
    and x0 a vertex of X0: Z is convex, so its vertices decide."""
    case = designs[(n, seed)]
    pr, d = case.problem, case.design
    H = np.vstack([np.hstack([d.H_T, d.h_T[:, None]]), np.r_[np.zeros(n), -1.0][None, :]])
    verts = polytope.vertices(H, np.r_[np.ones(len(d.H_T)), 0.0])
    worst = -np.inf
    for v in verts:
        z, alpha = v[:n], v[n]
        xs = z[None, :] + alpha * d.X0_vertices
        worst = max(worst, float(np.max(pr.F @ xs.T + pr.G @ (d.K @ xs.T))))
    assert worst <= 1.0 + 1e-9
