"""The cvxpy backend's exact update (9) by dual bases (amcp_reference.set_update_dual).

Every answer is compared with an LP built anew for each row by scipy (HiGHS, independent of the code
under test) on random data, h_θ within 1e-9, and its multipliers and maximisers are re-checked as a
certificate of (9) with numpy (helpers shared with tests/test_set_update_fast.py). Where the method
does not apply the backend's cvxpy LP answers.
"""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.model.status import SolveStatus
from amcp_reference import CvxpyBackend
from amcp_reference.set_update_dual import MAX_BASES, solve_by_dual_bases
from tests.test_set_update_fast import H_TOL, assert_certificate, random_case, rebuilt_lp


@pytest.fixture(scope="module")
def backend():
    return CvxpyBackend(formulation="vertex")


def test_dual_bases_equal_the_rebuilt_lp_on_random_data(backend):
    """Boxes and random polytopes in ℝ^1..ℝ^4, random cuts through a point inside, a fifth of them
    pinning a coordinate (flat intersection: degenerate vertices)."""
    rng = np.random.default_rng(1616)
    for _ in range(120):
        H, h, Hd, hd = random_case(rng, flat=rng.random() < 0.3)
        res = backend.set_update(H, h, Hd, hd)
        assert res.status is SolveStatus.OPTIMAL and res.method.startswith("dual bases")
        np.testing.assert_allclose(res.h, rebuilt_lp(H, h, Hd, hd), rtol=0, atol=H_TOL)
        assert_certificate(H, h, Hd, hd, res.h, res.Lambda, res.points)


#: The backend's LP runs at Clarabel's default tolerances (1e-8 relative): it is off by ~1e-9 (seen)
LP_TOL = 1e-7


def test_dual_bases_equal_the_cvxpy_lp(backend):
    """The same answers as the backend's own LP (set_update_method="lp", within its accuracy) on
    Example 1's shape along a chain of updates; the exact answer is the rebuilt LP's to 1e-9."""
    lp = CvxpyBackend(set_update_method="lp")
    rng = np.random.default_rng(16)
    H, h = np.vstack([np.eye(3), -np.eye(3)]), np.ones(6)
    theta = rng.uniform(-0.5, 0.5, 3)  # in every Δ_k, as θ* (the intersection is never empty)
    methods = set()
    for _ in range(40):
        Hd = rng.normal(size=(4, 3))
        Hd /= np.linalg.norm(Hd, axis=1)[:, None]
        hd = Hd @ theta + rng.uniform(0.0, 0.3, 4)
        fast, slow = backend.set_update(H, h, Hd, hd), lp.set_update(H, h, Hd, hd)
        assert fast.method.startswith("dual bases") and slow.method == "lp"
        methods.add(fast.method)
        assert_certificate(H, h, Hd, hd, fast.h, fast.Lambda, fast.points)
        np.testing.assert_allclose(fast.h, slow.h, rtol=0, atol=LP_TOL)
        np.testing.assert_allclose(fast.h, rebuilt_lp(H, h, Hd, hd), rtol=0, atol=H_TOL)
        h = fast.h
    assert methods == {"dual bases", "dual bases, reused"}  # both paths ran


def test_reused_maximisers_only_while_they_certify_the_answer():
    """Θ_{k−1} = [-1, 1]³: far data reuse the last maximisers (h unchanged); a cut of the face θ_1 = 1
    by 1e-7 must lower h_1 by 1e-7 (not reused); a corner cut is enumerated anew."""
    from amcp_reference.set_update_dual import DualBasesSetUpdate

    update = DualBasesSetUpdate()
    H, h = np.vstack([np.eye(3), -np.eye(3)]), np.ones(6)
    far = (np.array([[1.0, 0.0, 0.0]]), np.array([5.0]))
    assert update.solve(H, h, *far)[3] is False
    out = update.solve(H, h, *far)
    assert out[3] is True
    np.testing.assert_array_equal(out[0], h)
    assert_certificate(H, h, *far, *out[:3])
    corner = (np.ones((1, 3)) / np.sqrt(3.0), np.array([np.sqrt(3.0) - 0.5]))
    face = (np.array([[1.0, 0.0, 0.0]]), np.array([1.0 - 1e-7]))
    for cut in (face, corner):
        out = update.solve(H, h, *cut)
        assert out[3] is False
        np.testing.assert_allclose(out[0], rebuilt_lp(H, h, *cut), rtol=0, atol=H_TOL)
        assert_certificate(H, h, *cut, *out[:3])
    assert update.solve(H, h, *face)[0][0] == pytest.approx(1.0 - 1e-7, abs=1e-12)


def test_empty_intersection_and_too_many_bases_are_left_to_the_lp(backend):
    assert solve_by_dual_bases([[1.0], [-1.0]], [1.0, 1.0], [[1.0]], [-2.0]) is None
    res = backend.set_update([[1.0], [-1.0]], [1.0, 1.0], [[1.0]], [-2.0])
    assert res.method == "lp" and res.status is not SolveStatus.OPTIMAL and res.h is None
    rng = np.random.default_rng(3)
    p, rows = 4, 30  # C(34, 4) = 46 376 > MAX_BASES
    H = rng.normal(size=(rows, p))
    H /= np.linalg.norm(H, axis=1)[:, None]
    h, Hd, hd = np.ones(rows), np.eye(p)[:4], np.full(4, 0.5)
    assert solve_by_dual_bases(H, h, Hd, hd) is None and MAX_BASES < 46_376
    res = backend.set_update(H, h, Hd, hd)
    assert res.method == "lp" and res.status is SolveStatus.OPTIMAL
    np.testing.assert_allclose(res.h, rebuilt_lp(H, h, Hd, hd), rtol=0, atol=1e-7)


def test_unknown_method_is_refused():
    with pytest.raises(ValueError, match="set_update_method"):
        CvxpyBackend(set_update_method="simplex")
