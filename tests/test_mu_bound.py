"""sup ‖D(x,u)‖₂² of (11) at any size: the exact vertex maximum, reproduced here by brute force over
the known corners of boxes and parallelotopes; the upper bound from support LPs, never below it; the
automatic choice between them by the vertex count of the (x, u) region estimated before anything is
enumerated; the budget; and the independent (11) check. Also the near-duplicate filter of vertex
enumeration (polytope._unique_rows) against the all-pairs definition, just inside and outside its
tolerance."""

from __future__ import annotations

import itertools
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from amcp_drake.model import polytope
from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.offline.budget import CandidateTimeout, DesignBudget, DesignSizeError
from amcp_drake.offline.checks import _mu
from amcp_drake.offline.result import MU_EXACT_MAX_VERTICES, OfflineDesign, regressor_sup, regressor_upper_bound
from amcp_drake.studies.chains import actuated_chain


# -- near-duplicate filter ----------------------------------------------------------------------------
def _unique_rows_all_pairs(points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """The definition, every point against every kept point before it."""
    kept: list[np.ndarray] = []
    for p in points:
        if any(np.max(np.abs(q - p)) <= tol * max(1.0, float(np.max(np.abs(q)))) for q in kept):
            continue
        kept.append(p)
    return np.array(kept)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_unique_rows_equals_the_all_pairs_definition(seed):
    rng = np.random.default_rng(seed)
    base = rng.normal(scale=[1.0, 30.0, 0.01, 5.0], size=(200, 4))
    scale = np.maximum(1.0, np.max(np.abs(base), axis=1))[:, None]
    copies = [base,
              base[:60] + 0.5e-9 * scale[:60] * rng.uniform(-1, 1, (60, 4)),  # within the tolerance
              base[60:120] + 2e-9 * scale[60:120] * np.sign(rng.uniform(-1, 1, (60, 4)))]  # just outside
    points = np.vstack(copies)[rng.permutation(320)]
    got = polytope._unique_rows(points)
    np.testing.assert_array_equal(got, _unique_rows_all_pairs(points))
    assert len(got) == 260  # the 60 copies within the tolerance merged, the 60 outside kept


def test_unique_rows_just_inside_and_just_outside_the_tolerance():
    q = np.array([3.0, -2.0, 0.5])  # scale max(1, 3) = 3: the tolerance is 3e-9
    inside = q + np.array([0.0, 1.5e-9, 0.0])  # half of it
    outside = q + np.array([0.0, 6e-9, 0.0])  # twice it
    assert len(polytope._unique_rows(np.array([q, inside]))) == 1
    assert len(polytope._unique_rows(np.array([q, outside]))) == 2
    # the earlier point's scale decides: a small point (scale 1) 2e-9 from a later large one is kept
    small = np.array([0.5, 0.0])
    np.testing.assert_array_equal(polytope._unique_rows(np.array([small, small + 2e-9])), [small, small + 2e-9])


def test_unique_rows_keeps_every_corner_of_a_16_dimensional_box_and_merges_their_repeats():
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=16))) * 5.0
    repeated = np.vstack([corners, corners[::7] * (1 + 1e-10)])
    got = polytope._unique_rows(repeated)
    assert len(got) == 2**16
    np.testing.assert_array_equal(got, corners)


# -- sup ‖D‖² of (11): exact, bound, choice ---------------------------------------------------------
def _brute_force_sup(mats: np.ndarray, corners: np.ndarray) -> float:
    """max over the given corners of the largest singular value of D(z) = [M_1 z, ..., M_p z], squared
    (numpy's SVD, one corner at a time)."""
    return max(float(np.linalg.svd(np.column_stack([M @ z for M in mats]), compute_uv=False)[0] ** 2)
               for z in corners)


def _problem_with(mats_A, mats_B, F, G):
    """A problem whose regressor is [A_i x + B_i u] and whose Z is {F x + G u <= 1}."""
    n, m, p = mats_A.shape[1], mats_B.shape[2], mats_A.shape[0]
    return SimpleNamespace(n=n, m=m, p=p, A=mats_A, B=mats_B, F=F, G=G)


@pytest.mark.parametrize("seed", range(6))
def test_exact_sup_equals_brute_force_and_the_bound_is_never_below_it(seed):
    """Z a parallelotope T·[−c, c] in (x, u) with random T, c; its 2^d corners are known without any
    enumeration, so the brute-force maximum is independent of the code under test."""
    rng = np.random.default_rng(seed)
    n, m, p = int(rng.integers(2, 4)), int(rng.integers(1, 3)), int(rng.integers(1, 4))
    d = n + m
    T = np.eye(d) + 0.4 * rng.normal(size=(d, d))
    c = rng.uniform(0.5, 3.0, d)
    corners = (np.array(list(itertools.product([-1.0, 1.0], repeat=d))) * c) @ T.T
    H = np.vstack([np.linalg.inv(T) / c[:, None], -np.linalg.inv(T) / c[:, None]])  # |[T⁻¹z]_j| <= c_j
    A, B = rng.normal(size=(p, n, n)), rng.normal(size=(p, n, m))
    if seed % 2:
        A[:, 1:, :] = 0.0  # sparse regressors, where the bound's terms can be tight
        B[:, 1:, :] = 0.0
    pr = _problem_with(A, B, H[:, :n], H[:, n:])
    brute = _brute_force_sup(np.concatenate([A, B], axis=2), corners)
    exact = regressor_sup(pr, None, method="exact")
    bound = regressor_sup(pr, None, method="bound")
    assert exact.method == "exact" and bound.method == "bound"
    assert exact.value == pytest.approx(brute, rel=1e-10)
    assert bound.value >= brute
    assert regressor_sup(pr, None).method == "exact"  # 2^d <= 32 corners: auto enumerates


def test_the_bound_is_the_supremum_when_each_column_of_d_has_one_nonzero_row_in_distinct_rows():
    """Actuated chain: D = [0.2 x_2 e_1, 0.5 u_n e_n], ‖D‖₂² = max(0.04 x_2², 0.25 u_n²) = max(1, 0.25) = 1
    over |x_i| <= 5, |u_i| <= 1 (by hand); the Frobenius bound would be 1.25, Gershgorin's is 1 (up to
    the LP safety margins)."""
    spec = spec_from_dict(actuated_chain(3))
    bound = regressor_sup(spec.problem, None, method="bound")
    assert bound.value >= 1.0
    assert bound.value == pytest.approx(1.0, rel=1e-6)
    assert regressor_sup(spec.problem, None, method="exact").value == pytest.approx(1.0, rel=1e-12)


def test_regressor_upper_bound_with_coupled_columns_against_brute_force():
    """Columns of D sharing rows (M_1ᵀM_2 ≠ 0), on the unit box in 3 dimensions."""
    rng = np.random.default_rng(7)
    mats = rng.normal(size=(3, 4, 3))
    H, h = polytope.box(-np.ones(3), np.ones(3))
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=3)))
    value, _ = regressor_upper_bound(mats, H, h)
    brute = _brute_force_sup(mats, corners)
    assert value >= brute
    assert value <= 3.0 * brute  # ‖D‖_F² <= rank · ‖D‖₂² pointwise; the LPs add little at a box's corners


def test_auto_chooses_the_bound_above_the_vertex_cap_and_says_why():
    """Actuated chain n = 8: Z is a box in 16 dimensions, 2^16 > 2^14 vertices."""
    assert MU_EXACT_MAX_VERTICES < 2**16
    spec = spec_from_dict(actuated_chain(8))
    found = regressor_sup(spec.problem, None)
    assert found.method == "bound"
    assert "2^16 vertices of a box in 16 dimensions" in found.detail
    assert 1.0 <= found.value <= 1.0 + 1e-6  # the supremum is 1 (by hand, as in the test above)


def test_auto_chooses_the_bound_when_the_enumeration_would_exceed_the_memory_limit():
    """Actuated chain n = 5: 2^10 vertices in 10 dimensions need ~5 MiB by the budget's estimate."""
    spec = spec_from_dict(actuated_chain(5))
    small = DesignBudget(max_memory_mb=1.0)
    found = regressor_sup(spec.problem, None, small)
    assert found.method == "bound" and "memory limit" in found.detail
    assert regressor_sup(spec.problem, None, DesignBudget(max_memory_mb=16.0)).method == "exact"
    with pytest.raises(DesignSizeError) as err:
        regressor_sup(spec.problem, None, small, method="exact")
    assert err.value.stage.startswith("mu (11)") and "10 dimensions" in str(err.value)


def test_mu_stage_ticks_the_candidate_budget(monkeypatch):
    """The budget's CPU counter faked: 1 s counted against a budget of 1 ms before μ's stage starts; each
    method's first tick raises and names the stage."""
    import amcp_drake.offline.budget as budget_module

    cpu = [7.0]
    monkeypatch.setattr(budget_module.time, "process_time", lambda: cpu[0])
    spec = spec_from_dict(actuated_chain(4))
    budget = DesignBudget(candidate_seconds=1e-3)
    cpu[0] = 8.0
    for method in ("exact", "bound"):
        with pytest.raises(CandidateTimeout) as err:
            regressor_sup(spec.problem, None, budget, method=method)
        assert err.value.stage.startswith("mu (11)")


# -- the independent (11) check --------------------------------------------------------------------
def test_mu_check_accepts_a_mu_below_one_over_the_bound_and_refuses_one_above_the_supremum():
    """n = 8: the check's own S (the bound) is >= sup = 1; μ = 0.999 passes (margin 1e-3), μ = 1.002
    (twice as far outside) fails, as it must: μ ‖D‖² = 1.002 at x_2 = 5."""
    spec = spec_from_dict(actuated_chain(8))
    inside = _mu(spec.problem, SimpleNamespace(mu=0.999), None)
    outside = _mu(spec.problem, SimpleNamespace(mu=1.002), None)
    assert inside.status == "pass" and "bound:" in inside.detail
    assert outside.status == "fail"


def test_design_records_how_mu_was_obtained_and_keeps_it_through_json():
    spec = spec_from_dict(actuated_chain(2))
    from amcp_drake.offline.design import design

    d = design(spec.problem, spec.design)
    assert d.mu_method.startswith("exact: maximum over the 16 vertices")
    assert d.mu == pytest.approx(spec.design.mu_fraction / 1.0, rel=1e-12)  # sup = 1 by hand
    again = OfflineDesign.from_dict(d.to_dict())
    assert again.mu_method == d.mu_method
    legacy = d.to_dict()
    del legacy["mu_method"]
    assert OfflineDesign.from_dict(legacy).mu_method == "exact"
    bounded = replace(d, mu_method="bound: test")
    assert OfflineDesign.from_dict(bounded.to_dict()).mu_method == "bound: test"


# -- support LPs that answer "unbounded" on a bounded X0 ----------------------------------------------
def test_a_support_lp_reported_unbounded_on_the_bounded_x0_falls_back_to_the_vertex_maximum():
    """The design's w̄, f̄, h̄ with a backend whose LPs over X0 report one direction unbounded: X0's
    vertices were enumerated (it is bounded), so the design uses the exact vertex maxima, counts the
    failures and equals the design of the untampered backend; the independent checks pass."""
    from amcp_drake.backends.drake_ import DrakeBackend
    from amcp_drake.offline.checks import verify_design
    from amcp_drake.offline.design import design_fixed
    from tests.tampered_backends import UnboundedSupportDrake

    spec = spec_from_dict(actuated_chain(4))  # W and the parallelotope X0: 8 rows each
    options = replace(spec.design, x0_template="parallelotope")
    reference = design_fixed(spec.problem, options, backend=DrakeBackend())
    tampered = design_fixed(spec.problem, options, backend=UnboundedSupportDrake())
    assert len(reference.H_x) >= 8 and "support_lp_failures" not in reference.info
    assert tampered.info["support_lp_failures"] == 2 + len(tampered.theta_vertices)  # w̄, f̄ and each h̄^k
    for name in ("w_bar", "f_bar", "h_bar", "H_T", "h_T"):
        np.testing.assert_allclose(getattr(tampered, name), getattr(reference, name), rtol=1e-7, atol=1e-9)
    assert all(c.status == "pass" for c in verify_design(spec.problem, tampered, None))


def test_amcp_design_prints_how_mu_was_obtained():
    """massera2017: Z is a box in (x, u) of 2^5 corners; the exact value is that of a brute force over them."""
    from click.testing import CliRunner

    from amcp_drake.cli import main
    from amcp_drake.model.examples import get_example

    pr = get_example("massera2017").problem
    H = np.hstack([pr.F, pr.G])
    lo, hi = [], []
    for j in range(H.shape[1]):  # a box: each row has one nonzero entry; the bound of z_j is 1 / H_rj
        col = H[:, j]
        hi.append(1.0 / col[col > 0].min())
        lo.append(1.0 / col[col < 0].max())
    assert np.all(np.count_nonzero(H, axis=1) == 1)
    corners = np.array([[hi[j] if s > 0 else lo[j] for j, s in enumerate(signs)]
                        for signs in itertools.product([-1, 1], repeat=H.shape[1])])
    brute = _brute_force_sup(np.concatenate([pr.A, pr.B], axis=2), corners)
    result = CliRunner().invoke(main, ["design", "--example", "massera2017"], catch_exceptions=False)
    assert result.exit_code == 0
    line = next(text for text in result.output.splitlines() if text.startswith("mu = "))
    assert "exact: maximum over the 32 vertices" in line
    assert f"sup ||D||^2 = {brute:.6g} over Z" in line
