"""The parallelotope template's gain (offline/parallelotope.py): the linear programs that bound the
constraint rows (F + GK)T⁻¹ at a given contraction λ, and the rating r = γ̄ σ̄_W / (1 − λ̄) that picks
among them, recomputed here with numpy from T and K; the designs they give re-checked independently
(offline/checks.py, vertices only) on the 3-mass chain and generated chains n = 4 … 6."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.backends import get_backend
from amcp_drake.model.examples import get_example
from amcp_drake.offline import parallelotope as par
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design_fixed, robust_gain
from tests.test_scale_design import _load, actuated_chain


def _vertex_data(pr):
    theta_v = pr.theta_vertices()
    return (np.array([pr.A_of(t) for t in theta_v]), np.array([pr.B_of(t) for t in theta_v]))


def _basis(pr, K):
    A_v, B_v = _vertex_data(pr)
    A0, B0 = pr.A_of(pr.theta_hat0), pr.B_of(pr.theta_hat0)
    return par.perron_scaled(np.linalg.inv(par.real_eigenbasis(A0 + B0 @ K)), A_v + B_v @ K)


def _ratio(pr, T, K):
    """r = max_j ‖(F+GK)_j T⁻¹‖₁ · max_i max_w |T_i w| / (1 − max_k ‖T A_cl T⁻¹‖∞), written out."""
    A_v, B_v = _vertex_data(pr)
    Ti = np.linalg.inv(T)
    lam = max(np.abs(T @ (A + B @ K) @ Ti).sum(axis=1).max() for A, B in zip(A_v, B_v))
    gamma = np.abs((pr.F + pr.G @ K) @ Ti).sum(axis=1).max()
    sigma = np.abs(pr.w_vertices() @ T.T).max()
    return gamma * sigma / (1 - lam) if lam < 1 else np.inf, lam


def test_constraint_rows_lp_meets_its_bounds_and_rating_is_recomputed():
    pr = get_example("mass_chain3").problem
    A_v, B_v = _vertex_data(pr)
    K_place = par.placed_gain(pr.A_of(pr.theta_hat0), pr.B_of(pr.theta_hat0))
    assert K_place is not None
    T = _basis(pr, K_place)
    answered = 0
    for lam in par.LAMBDA_GRID:
        found = par.lp_gain(T, A_v, B_v, pr.F, pr.G, lam)
        if found is None:
            continue
        answered += 1
        K, gamma = found
        r, lam_bar = _ratio(pr, T, K)
        assert lam_bar <= lam + 1e-7  # ‖T A_cl(θ^k) T⁻¹‖∞ <= λ at every vertex
        assert np.abs((pr.F + pr.G @ K) @ np.linalg.inv(T)).sum(axis=1).max() <= gamma + 1e-7
        assert par.rating(T, K, A_v, B_v, pr.F, pr.G, pr.w_vertices()) == pytest.approx((r, lam_bar), rel=1e-9)
    assert answered >= 1


def test_minimal_lambda_gain_leaves_no_room_where_the_constraint_rows_do():
    """On the 3-mass chain the gain of least λ̄ alone gives r >= 1 (no scaled terminal set: α_∞ max f̄ >= 1),
    while the chosen gain gives r < 1 and a design passing every independent check."""
    spec = get_example("mass_chain3")
    pr = spec.problem
    A_v, B_v = _vertex_data(pr)
    K0, _, _ = robust_gain(pr, spec.design, get_backend("drake"))
    T0 = _basis(pr, K0)
    K_min, _ = par.lp_gain(T0, A_v, B_v)
    assert _ratio(pr, T0, K_min)[0] >= 1.0
    K, T, lam_bar = par.parallelotope_gain(pr, K0)
    r, lam = _ratio(pr, T, K)
    assert r < 1.0 and lam == pytest.approx(lam_bar, abs=1e-12)
    d = design_fixed(pr, replace(spec.design, x0_template="parallelotope"))
    assert [c.name for c in verify_design(pr, d, spec.design.mu_state_bound) if not c.passed] == []
    assert len(d.H_x) == 12 and len(d.H_T) == 12


@pytest.mark.parametrize("n", [4, 5, 6, 7, 8])
def test_parallelotope_designs_of_generated_chains_pass_every_independent_check(tmp_path, n):
    """n = 8: Z is a box in 16 dimensions (2^16 vertices, above the exact enumeration's cap), so μ of (11)
    comes from the upper bound, and the independent (11) check passes with its own bound."""
    spec = _load(tmp_path, actuated_chain(n))
    d = design_fixed(spec.problem, replace(spec.design, x0_template="parallelotope"))
    checks = verify_design(spec.problem, d, spec.design.mu_state_bound)
    failed = [c.name for c in checks if not c.passed]
    assert failed == [] and len(d.H_x) == 2 * n and len(d.X0_vertices) == 2 ** n
    assert d.mu_method.split(":")[0] == ("bound" if n == 8 else "exact")
    assert "mu condition (11)" in {c.name for c in checks}
    # Assumption 11's condition of the scaled copy, recomputed from the vertices: α_∞ max f̄ < 1
    W_v, X_v = spec.problem.w_vertices(), d.X0_vertices
    w_bar = np.max(d.H_x @ W_v.T, axis=1)
    theta_v = spec.problem.theta_vertices()
    h_bar = np.array([np.max(d.H_x @ (spec.problem.A_of(t) + spec.problem.B_of(t) @ d.K) @ X_v.T, axis=1)
                      for t in theta_v])
    f_bar = np.max((spec.problem.F + spec.problem.G @ d.K) @ X_v.T, axis=1)
    alpha_inf = float(np.max(w_bar[None, :] / (1 - h_bar)))
    assert alpha_inf * float(np.max(f_bar)) < 1.0


def test_scipys_unconverged_pole_placement_gives_a_gain_without_a_warning():
    """A random 6-state, 2-input pair (seed 0, the 14th draw) on which scipy's place_poles warns that its
    iteration stopped above its tolerance: the placed gain is returned (a starting point, rated later by
    its λ̄) and nothing is printed; the same call to scipy directly does warn."""
    import warnings

    from scipy.signal import place_poles

    rng = np.random.default_rng(0)
    for _ in range(14):
        n, m = int(rng.integers(4, 7)), int(rng.integers(2, 4))
        A, B = rng.normal(size=(n, n)), rng.normal(size=(n, m))
    assert (n, m) == (6, 2)
    with pytest.warns(UserWarning, match="Convergence was not reached"):
        place_poles(A, B, np.linspace(*par.PLACED_POLES, n))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        K = par.placed_gain(A, B)
    assert K is not None and K.shape == (2, 6)
    assert np.all(np.isfinite(np.linalg.eigvals(A + B @ K)))
