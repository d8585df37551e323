"""The set update (9) as the Drake backend solves it: the LP written in place into a
preallocated program, and the exact per-facet maximum over the vertices of Θ_{k−1} ∩ Δ_k with its
dual certificate (reusing the vertices of Θ_{k−1} when Δ_k cuts none of them).

Every answer is compared with an LP built anew for each row by scipy (HiGHS), independent of the
code under test, on random data: h_θ within 1e-9, and Λ re-checked as a certificate
of (9) (Λ >= 0, Λ H̃ = H_θ, Λ h̃ <= h) with numpy.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

pytest.importorskip("pydrake")

from amcp_drake.backends.drake_ import DrakeBackend
from amcp_drake.backends.set_update_vertices import (
    MAX_BASES,
    VertexSetUpdate,
    solve_by_vertices,
)
from amcp_drake.model.status import SolveStatus

#: the in-place and vertex updates give the same h_θ as the rebuilt LP to 1e-9
H_TOL = 1e-9
#: Λ >= 0, Λ H̃ = H_θ and Λ h̃ <= h hold to round-off of the solvers (Clarabel at 1e-10, see CLARABEL_LP_OPTIONS)
CERT_TOL = 1e-8
#: HiGHS's default feasibility tolerance (1e-7) would accept θ_1 = 1 against θ_1 <= 1 − 1e-7 (seen
#: in the face-cut test below); the reference LP must be exact to well below H_TOL
HIGHS_TIGHT = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


def rebuilt_lp(H_theta, h_prev, H_data, h_data):
    """[h]_i = max [H_θ]_i θ s.t. H̃ θ <= h̃, one scipy LP built from scratch per row."""
    A = np.vstack([H_theta, H_data])
    b = np.concatenate([h_prev, h_data])
    out = []
    for row in H_theta:
        res = linprog(-row, A_ub=A, b_ub=b, bounds=[(None, None)] * A.shape[1], method="highs-ds",
                      options=HIGHS_TIGHT)
        assert res.status == 0, res.message
        out.append(-res.fun)
    return np.array(out)


def random_case(rng, flat=False):
    """Θ_{k−1} = a box or a random polytope around 0 in ℝ^p, Δ_k = r unit rows through a point
    θ* inside (offsets >= 0: the intersection holds θ*); ``flat``: Δ_k pins one coordinate."""
    p = int(rng.integers(1, 5))
    if rng.random() < 0.5:
        H = np.vstack([np.eye(p), -np.eye(p)])
    else:
        H = rng.normal(size=(2 * p + 2, p))
        H /= np.linalg.norm(H, axis=1)[:, None]
    h = rng.uniform(0.3, 1.0, len(H))
    theta = rng.uniform(-0.1, 0.1, p)
    r = int(rng.integers(1, 5))
    Hd = rng.normal(size=(r, p))
    Hd /= np.linalg.norm(Hd, axis=1)[:, None]
    hd = Hd @ theta + rng.uniform(0.0, 0.6, r)
    if flat:
        e = np.eye(p)[:1]
        Hd, hd = np.vstack([Hd, e, -e]), np.concatenate([hd, e @ theta, -e @ theta])
    return H, h, Hd, hd


def assert_certificate(H_theta, h_prev, H_data, h_data, h, Lam, points=None):
    H_tilde = np.vstack([H_theta, H_data])
    h_tilde = np.concatenate([h_prev, h_data])
    assert Lam.shape == (len(H_theta), len(H_tilde))
    assert np.all(Lam >= -CERT_TOL)  # interior-point multipliers may be -1e-11; the vertex ones are clipped to 0
    assert np.max(np.abs(Lam @ H_tilde - H_theta)) <= CERT_TOL
    assert np.all(Lam @ h_tilde <= h + CERT_TOL)
    if points is not None:  # maximisers: in Θ_{k−1} ∩ Δ_k and attaining h row by row
        assert points.shape == H_theta.shape
        assert np.all(points @ H_tilde.T <= h_tilde + CERT_TOL)
        np.testing.assert_allclose(np.einsum("ij,ij->i", H_theta, points), h, rtol=0, atol=CERT_TOL)


@pytest.fixture(scope="module")
def lp_backend():
    return DrakeBackend(set_update_method="lp")


@pytest.fixture(scope="module")
def auto_backend():
    return DrakeBackend()


def test_in_place_lp_equals_the_rebuilt_lp_on_random_data(lp_backend):
    """One backend, one preallocated program per shape, 60 calls with other data written in place;
    the LP's maximisers (the duals of Λ H̃ = H_θ) are in the set and attain h row by row."""
    rng = np.random.default_rng(16)
    for _ in range(60):
        H, h, Hd, hd = random_case(rng, flat=rng.random() < 0.2)
        res = lp_backend.set_update(H, h, Hd, hd)
        assert res.status is SolveStatus.OPTIMAL and res.method == "lp"
        np.testing.assert_allclose(res.h, rebuilt_lp(H, h, Hd, hd), rtol=0, atol=H_TOL)
        assert res.points is not None
        assert_certificate(H, h, Hd, hd, res.h, res.Lambda, res.points)


def test_vertex_update_equals_the_rebuilt_lp_on_random_data(auto_backend):
    rng = np.random.default_rng(1516)
    methods = set()
    for _ in range(80):
        H, h, Hd, hd = random_case(rng, flat=rng.random() < 0.2)
        res = auto_backend.set_update(H, h, Hd, hd)
        assert res.status is SolveStatus.OPTIMAL
        methods.add(res.method)
        np.testing.assert_allclose(res.h, rebuilt_lp(H, h, Hd, hd), rtol=0, atol=H_TOL)
        assert_certificate(H, h, Hd, hd, res.h, res.Lambda, res.points)
    assert "vertices" in methods  # the fast path was exercised, not only its fallback


def test_reused_vertices_when_the_data_cut_nothing_and_when_they_cut_a_little():
    """Θ_{k−1} = [-1, 1]³; a first Δ_k far away reuses nothing yet, a second (same Θ_{k−1}) reuses the
    vertices; a third cuts off a corner, a fourth the face θ_1 = 1 by 1e-7, which must lower h_1 by 1e-7."""
    update = VertexSetUpdate()
    H = np.vstack([np.eye(3), -np.eye(3)])
    h = np.ones(6)
    far = (np.array([[1.0, 0.0, 0.0]]), np.array([5.0]))
    for _ in range(2):
        out = update.solve(H, h, *far)
        np.testing.assert_array_equal(out[0], h)
        assert_certificate(H, h, *far, *out)
    corner = (np.ones((1, 3)) / np.sqrt(3.0), np.array([np.sqrt(3.0) - 0.5]))
    face = (np.array([[1.0, 0.0, 0.0]]), np.array([1.0 - 1e-7]))
    for cut in (corner, face):
        out = update.solve(H, h, *cut)
        np.testing.assert_allclose(out[0], rebuilt_lp(H, h, *cut), rtol=0, atol=H_TOL)
        assert_certificate(H, h, *cut, *out)
    assert out[0][0] == pytest.approx(1.0 - 1e-7, abs=1e-12)


def test_reused_multipliers_are_fresh_for_each_theta_and_number_of_data_rows():
    """The reuse case's Λ (a copy of one template per Θ_(k−1) and number of data rows) equals
    that of a fresh VertexSetUpdate while Θ_(k−1) (two sets whose redundant seventh row has different
    multipliers) and the number of data rows change, and an answer overwritten by the caller does not
    change the next one."""
    H1 = np.vstack([np.eye(3), -np.eye(3), np.ones((1, 3)) / np.sqrt(3.0)])
    H2 = np.vstack([np.eye(3), -np.eye(3), np.array([[1.0, -1.0, 1.0]]) / np.sqrt(3.0)])
    h = np.r_[np.ones(6), 10.0]
    one = (np.array([[1.0, 0.0, 0.0]]), np.array([5.0]))
    two = (np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([5.0, 6.0]))
    update = VertexSetUpdate()
    for H, data in [(H1, one), (H1, one), (H1, two), (H2, two), (H2, one), (H1, one)]:
        out = update.solve(H, h, *data)
        for got, want in zip(out, VertexSetUpdate().solve(H, h, *data)):
            np.testing.assert_array_equal(got, want)
        assert_certificate(H, h, *data, *out)
        for array in out:
            array[...] = 7.0  # the caller's arrays


def test_empty_intersection_is_left_to_the_lp(auto_backend):
    assert solve_by_vertices([[1.0], [-1.0]], [1.0, 1.0], [[1.0]], [-2.0]) is None
    res = auto_backend.set_update([[1.0], [-1.0]], [1.0, 1.0], [[1.0]], [-2.0])
    assert res.method == "lp" and res.status is not SolveStatus.OPTIMAL and res.h is None


def test_too_many_bases_are_left_to_the_lp(auto_backend):
    rng = np.random.default_rng(3)
    p, rows = 4, 30  # C(34, 4) = 46 376 > MAX_BASES
    H = rng.normal(size=(rows, p))
    H /= np.linalg.norm(H, axis=1)[:, None]
    h = np.ones(rows)
    Hd, hd = np.eye(p)[:4], np.full(4, 0.5)
    assert solve_by_vertices(H, h, Hd, hd) is None and MAX_BASES < 46_376
    res = auto_backend.set_update(H, h, Hd, hd)
    assert res.method == "lp" and res.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(res.h, rebuilt_lp(H, h, Hd, hd), rtol=0, atol=H_TOL)
