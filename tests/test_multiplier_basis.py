"""(15d) solved for p of the q multipliers (amcp_drake.backends.multiplier_basis), against scipy's LPs."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from amcp_drake.backends.multiplier_basis import MultiplierBasis


def random_theta_shape(rng: np.random.Generator, p: int, extra: int) -> tuple[np.ndarray, np.ndarray]:
    """A bounded Θ = {H θ <= h}: the box |θ_i| <= 1 (rows interleaved +e_i, −e_i) and ``extra`` random
    unit cuts through a neighbourhood of a point inside it."""
    box = np.zeros((2 * p, p))
    box[0::2], box[1::2] = np.eye(p), -np.eye(p)
    cuts = rng.normal(size=(extra, p))
    cuts /= np.linalg.norm(cuts, axis=1, keepdims=True)
    centre = rng.uniform(-0.3, 0.3, p)
    H = np.vstack([box, cuts])
    h = np.concatenate([np.ones(2 * p), cuts @ centre + rng.uniform(0.05, 0.5, extra)])
    return H, h


def test_a_box_keeps_one_row_of_each_pair():
    p = 3
    H, _ = random_theta_shape(np.random.default_rng(0), p, 0)
    basis = MultiplierBasis.of(H)
    assert len(basis.basic) == p and len(basis.nonbasic) == p
    assert sorted(np.abs(H[basis.basic]).argmax(axis=1)) == [0, 1, 2]  # one row per coordinate
    np.testing.assert_array_equal(np.abs(basis.M), np.eye(p))


@pytest.mark.parametrize("seed", range(6))
def test_the_full_multipliers_satisfy_15d_and_split_the_cost(seed):
    """Λ = full(c, Λ_N) has Λ H_θ = c and its N entries are Λ_N; Λ·h = c·κ + Λ_N·s."""
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 5))
    H, h = random_theta_shape(rng, p, int(rng.integers(0, 4)))
    basis = MultiplierBasis.of(H)
    c = rng.normal(size=(7, p))
    lam_n = rng.uniform(0.0, 2.0, size=(7, len(basis.nonbasic)))
    lam = basis.full(c, lam_n)
    np.testing.assert_allclose(lam @ H, c, atol=1e-12)
    np.testing.assert_array_equal(lam[:, basis.nonbasic], lam_n)
    kappa, s = basis.offsets(h)
    np.testing.assert_allclose(lam @ h, c @ kappa + lam_n @ s, atol=1e-12)
    # per-stage offsets (N, q): row by row the same as one offset vector at a time
    hs = h + rng.uniform(0.0, 0.2, size=(4, len(h)))
    kappas, slacks = basis.offsets(hs)
    for row in range(4):
        k1, s1 = basis.offsets(hs[row])
        np.testing.assert_allclose(kappas[row], k1, atol=1e-15)
        np.testing.assert_allclose(slacks[row], s1, atol=1e-15)


@pytest.mark.parametrize("seed", range(6))
def test_the_reduced_lp_has_the_optimum_of_15c_15d_and_of_the_support(seed):
    """min {Λ h : Λ >= 0, Λ H_θ = c} (the multipliers of one row of (15c)-(15d), scipy), the same LP over
    Λ_N >= 0 with Λ_B = c M − Λ_N H_N M >= 0 (this module's reduction, scipy) and the support
    max {c θ : H_θ θ <= h} (LP duality) agree."""
    rng = np.random.default_rng(100 + seed)
    p = int(rng.integers(2, 5))
    H, h = random_theta_shape(rng, p, int(rng.integers(0, 4)))
    basis = MultiplierBasis.of(H)
    c = rng.normal(size=p)
    support = -linprog(-c, A_ub=H, b_ub=h, bounds=[(None, None)] * p, method="highs").fun
    full = linprog(h, A_eq=H.T, b_eq=c, bounds=[(0, None)] * len(h), method="highs").fun
    kappa, s = basis.offsets(h)
    reduced = linprog(s, A_ub=basis.HNM.T, b_ub=c @ basis.M, bounds=[(0, None)] * len(s), method="highs")
    assert reduced.status == 0
    np.testing.assert_allclose([full, c @ kappa + reduced.fun], support, rtol=1e-9, atol=1e-9)
    lam = basis.full(c, reduced.x)
    assert lam.min() >= -1e-9 and abs(lam @ h - support) <= 1e-9


def test_a_shape_without_p_independent_rows_is_refused():
    """Too few rows, or rank < p (Θ unbounded along a direction; the problem validation refuses
    such a Θ earlier, this is the backend's own guard)."""
    with pytest.raises(ValueError, match="unbounded"):
        MultiplierBasis.of(np.array([[1.0, 0.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="unbounded"):
        MultiplierBasis.of(np.array([[1.0, 0.0], [-1.0, 0.0], [2.0, 0.0], [-3.0, 0.0]]))  # rank 1


@pytest.mark.parametrize("seed", range(8))
def test_optimal_multipliers_are_the_lp_duals_of_the_support(seed):
    """Λ >= 0, Λ H = c and Λ·h = max {c θ : H θ <= h} (scipy) for random c, on random polytopes and,
    for odd seeds, a flat one (one coordinate pinned to within 1e-6, as θ* pins Θ_k)."""
    from amcp_drake.backends.multiplier_basis import optimal_multipliers

    rng = np.random.default_rng(200 + seed)
    p = int(rng.integers(2, 5))
    H, h = random_theta_shape(rng, p, int(rng.integers(0, 4)))
    if seed % 2:  # pin θ_1 at the Chebyshev centre's first coordinate (scipy)
        norms = np.linalg.norm(H, axis=1)
        centre = linprog(np.r_[np.zeros(p), -1.0], A_ub=np.c_[H, norms], b_ub=h,
                         bounds=[(None, None)] * p + [(0, None)], method="highs").x[:p]
        h[0], h[1] = centre[0], -centre[0] + 1e-6  # θ_1 ∈ [c_1 − 1e-6, c_1]
    c = rng.normal(size=(20, p))
    lam = optimal_multipliers(H, h, c)
    assert lam is not None and lam.shape == (20, len(h))
    assert lam.min() >= -1e-9
    np.testing.assert_allclose(lam @ H, c, atol=1e-9)
    for row in range(20):
        support = -linprog(-c[row], A_ub=H, b_ub=h, bounds=[(None, None)] * p, method="highs").fun
        assert abs(lam[row] @ h - support) <= 1e-8 * max(1.0, abs(support))


def test_optimal_multipliers_refuse_an_empty_set():
    from amcp_drake.backends.multiplier_basis import optimal_multipliers

    H = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    assert optimal_multipliers(H, np.array([1.0, -2.0, 1.0, 1.0]), np.ones((3, 2))) is None  # θ1 <= 1, θ1 >= 2
