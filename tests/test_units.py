"""The offline design is covariant under diagonal changes of state units (offline/units.py).

The same system written in x̃ = T x, T = diag(t_i) > 0 (``model/state_units.scale_states``) must get
the same design, mapped: K̃ = K T⁻¹, P̃ = T⁻ᵀ P T⁻¹, H̃_x = H_x T⁻¹ (rows in any order), X̃0 = T X0,
Ã_z = T A_z T⁻¹, H̃_T = H_T T⁻¹ with the same h_T, and the same unit-free w̄, f̄, h̄, λ̄, template and
terminal iterations; μ is that of (11) in the user's units (recomputed here from the vertices of the
region, not by the design code). A design that is not unit-free fails them: Example 1 in
diag(100, 0.01) gets K̃T = [−0.051, −0.478] instead of [0.018, −0.415], and massera2017 in
diag(0.01, 100, 100) a K 2.6e-4 away (relative).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.model import polytope
from amcp_drake.model.examples import get_example
from amcp_drake.model.problem import DesignOptions
from amcp_drake.model.state_units import scale_states
from amcp_drake.offline import units
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design, design_fixed

#: Agreement required between the design of the scaled problem and the mapped original, relative
#: to the size of each quantity, for everything the design computes from K and P (K and P themselves:
#: :data:`GAIN_RTOL`). Both designs are made on normalised problems that differ only by a common factor
#: c (S̃T = cS, offline/units.py) and by round-off (~1e-16); the support LPs stop at ~1e-8. Measured
#: (Drake and cvxpy, with K equal to 9e-9): w̄ within 1e-8, λ̄ within 1e-11; 1e-6 leaves a
#: factor 100 above the solvers' accuracy. These are compared on the design made with
#: the original's K and P given, so the flatness of the gain LMI does not enter them.
COVARIANCE_RTOL = 1e-6
#: Agreement required of K and P from the gain LMI (16), relative. Its optimum trace(S) is flat in K:
#: an interior-point answer at relative gap δ fixes K only to about √δ (measured: ±3.3e-5 at 1e-10,
#: ±3.5e-4 at 1e-8 on sls eps0.05). Twins are solved to 1e-9 of each other while their solves follow
#: the same path, but round-off can send one of them to a stall and the backend's defaults (1e-8):
#: on an AMD EPYC, massera2017 stalled at 1e-10 and its twins did not, and their K were
#: 7.3e-5 apart, where another machine had measured 9e-9. So K and P are required to
#: agree to √1e-8 = 1e-4 (which still catches the 2.6e-4 of the design before normalisation), and
#: everything the design computes from them is required to 1e-6 on the design with the original's
#: gain given in the new units (:func:`assert_same_downstream_design`).
GAIN_RTOL = 1e-4

EXAMPLE_1_UNITS = [np.array([100.0, 0.01]), np.array([0.01, 100.0])]
MASSERA_UNITS = [np.array([100.0, 0.01, 0.01]), np.array([0.01, 100.0, 100.0])]


def _rel(actual: np.ndarray, expected: np.ndarray) -> float:
    """max |actual − expected| relative to max |expected|."""
    return float(np.max(np.abs(actual - expected)) / max(np.max(np.abs(expected)), 1e-300))


def _match_rows(actual: np.ndarray, expected: np.ndarray, what: str) -> np.ndarray:
    """perm with actual[perm[i]] ≈ expected[i] for every row (a bijection), within COVARIANCE_RTOL of
    the row's norm; rows of H_x, H_T carry right-hand side 1, so there is no positive scaling left."""
    assert actual.shape == expected.shape, f"{what}: {actual.shape} rows in the scaled units, {expected.shape} expected"
    dist = np.linalg.norm(actual[None, :, :] - expected[:, None, :], axis=2) / np.linalg.norm(expected, axis=1)[:, None]
    perm = np.argmin(dist, axis=1)
    assert sorted(perm.tolist()) == list(range(len(actual))), f"{what}: rows do not correspond one to one"
    worst = float(np.max(dist[np.arange(len(perm)), perm]))
    assert worst <= COVARIANCE_RTOL, f"{what}: a row differs by {worst:.3e} of its norm"
    return perm


def _mu_sup(problem, state_bound) -> float:
    """sup ‖D(x,u)‖₂² (spectral norm) over Z (∩ the box |x_i| <= state_bound when Z is unbounded), from the
    vertices of that polytope: ‖D‖² is convex, so the supremum is at a vertex."""
    H, h = np.hstack([problem.F, problem.G]), np.ones(len(problem.F))
    if not polytope.is_bounded(H, h):  # Z leaves x unbounded: the box of design.mu_state_bound
        n, m = problem.n, problem.m
        box = np.vstack([np.eye(n), -np.eye(n)])
        H = np.vstack([H, np.hstack([box, np.zeros((2 * n, m))])])
        h = np.concatenate([h, np.full(2 * n, state_bound)])
    verts = polytope.vertices(H, h)
    return max(float(np.linalg.norm(problem.regressor(v[:problem.n], v[problem.n:]), 2)) ** 2 for v in verts)


def assert_same_design_in_units(scaled_problem, scaled, original, T: np.ndarray, options: DesignOptions,
                                backend: str = "drake") -> None:
    """``scaled`` (the design of the problem in x̃ = diag(T) x) is ``original`` mapped to x̃: the same
    choices, K and P to :data:`GAIN_RTOL`, every quantity computed from them to :data:`COVARIANCE_RTOL`
    on the design of the problem in x̃ with the original's K, P given (mapped to x̃)."""
    assert scaled.info.get("x0_template") == original.info.get("x0_template")
    assert scaled.gain_source == original.gain_source
    assert scaled.terminal_iterations == original.terminal_iterations
    # K̃ T ≈ K and T P̃ T ≈ P, compared in x (in x̃ the entries differ by the units, 1e4 here)
    assert _rel(scaled.K * T[None, :], original.K) <= GAIN_RTOL
    assert _rel(scaled.P * np.outer(T, T), original.P) <= GAIN_RTOL
    failed = [c.name for c in verify_design(scaled_problem, scaled, options.mu_state_bound) if not c.passed]
    assert failed == []
    given = replace(options, K=original.K / T[None, :], P=original.P / np.outer(T, T))
    assert_same_downstream_design(scaled_problem, design(scaled_problem, given, backend=backend), original, T, options)


def assert_same_downstream_design(scaled_problem, scaled, original, T: np.ndarray, options: DesignOptions) -> None:
    """Everything the design computes from K and P (``scaled`` designed with the original's gain
    given in x̃) is ``original``'s mapped to x̃, to :data:`COVARIANCE_RTOL`."""
    assert scaled.info.get("x0_template") == original.info.get("x0_template")
    assert scaled.terminal_iterations == original.terminal_iterations
    perm = _match_rows(scaled.H_x * T[None, :], original.H_x, "H_x")
    np.testing.assert_allclose(scaled.w_bar[perm], original.w_bar, rtol=0, atol=COVARIANCE_RTOL)
    np.testing.assert_allclose(scaled.h_bar[:, perm], original.h_bar, rtol=0, atol=COVARIANCE_RTOL)
    np.testing.assert_allclose(scaled.f_bar, original.f_bar, rtol=0, atol=COVARIANCE_RTOL)  # rows of Z: same order
    assert scaled.lambda_bar == pytest.approx(original.lambda_bar, abs=COVARIANCE_RTOL)
    _match_rows(scaled.X0_vertices / T[None, :], original.X0_vertices, "X0 vertices")
    A_z_in_x = scaled.A_z * np.outer(1.0 / T, T)  # T⁻¹ Ã_z T
    assert np.max(np.abs(A_z_in_x - original.A_z)) <= COVARIANCE_RTOL * max(1.0, float(np.max(np.abs(original.A_z))))
    _match_rows(np.column_stack([scaled.H_T * T[None, :], scaled.h_T]),
                np.column_stack([original.H_T, original.h_T]), "[H_T, h_T]")
    np.testing.assert_array_equal(scaled.H_theta, original.H_theta)  # θ has no state units
    sup = _mu_sup(scaled_problem, options.mu_state_bound)
    assert scaled.mu_sup == pytest.approx(sup, rel=1e-12)
    assert scaled.mu == pytest.approx(options.mu_fraction / sup, rel=1e-12)
    failed = [c.name for c in verify_design(scaled_problem, scaled, options.mu_state_bound) if not c.passed]
    assert failed == []


_ORIGINALS: dict = {}


def _original(name: str, options: DesignOptions, backend: str, label: str):
    """The design of the example in its own units, once per (example, options, backend)."""
    key = (name, label, backend)
    if key not in _ORIGINALS:
        _ORIGINALS[key] = design(get_example(name).problem, options, backend=backend)
    return _ORIGINALS[key]


CASES = [("lorenzen2019", T, "drake") for T in EXAMPLE_1_UNITS] + [("massera2017", T, "drake") for T in MASSERA_UNITS] \
    + [("lorenzen2019", EXAMPLE_1_UNITS[0], "cvxpy"), ("massera2017", MASSERA_UNITS[1], "cvxpy")]


@pytest.mark.parametrize("name, T, backend", CASES, ids=lambda v: str(v.tolist()) if isinstance(v, np.ndarray) else v)
def test_the_automatic_design_in_other_state_units_is_the_mapped_design(name, T, backend):
    spec = get_example(name)
    scaled_problem = scale_states(spec.problem, T)
    scaled = design(scaled_problem, spec.design, backend=backend)
    assert_same_design_in_units(scaled_problem, scaled, _original(name, spec.design, backend, "auto"), T, spec.design,
                                backend)


#: Example 1 written in x̃ = t x with a common factor far from 1 (states in micro- or mega-units).
#: A design that is not unit-free gives here: a 12-facet X0 instead of 8 (t = 1e-4, and a
#: raw ValueError from the design check's Chebyshev LP, HiGHS status 4), a 20-facet X0 (t = 1e6), no
#: candidate passing (t = 1e8). t = 3e-5 and below are refused by the input limits (Q̃ > 1e9).
COMMON_FACTORS = [1e-4, 1e6, 1e8]


@pytest.mark.parametrize("t", COMMON_FACTORS)
def test_the_design_is_the_mapped_design_under_a_large_common_factor(t):
    spec = get_example("lorenzen2019")
    T = np.full(spec.problem.n, t)
    scaled_problem = scale_states(spec.problem, T)
    scaled = design(scaled_problem, spec.design, backend="drake")
    assert_same_design_in_units(scaled_problem, scaled, _original("lorenzen2019", spec.design, "drake", "auto"), T,
                                spec.design)


@pytest.mark.parametrize(("extent", "factor"), [
    (0.1, 1.0), (1e-4, 1.0), (1e3, 1.0),        # inside the band: the file's own scale
    (5e4, 1e-6), (1e-5, 1e3), (2e3, 1e-5), (9.9e-5, 1e3),  # outside: 0.05, 0.01, 0.02, 0.099
])
def test_the_common_factor_brings_the_largest_extent_of_w_into_the_band(extent, factor):
    assert units.common_factor(extent) == pytest.approx(factor, rel=1e-12)
    if factor != 1.0:
        assert 0.01 <= extent * factor < 0.1


@pytest.mark.parametrize("name, T, changes", [
    ("lorenzen2019", EXAMPLE_1_UNITS[0], {"x0_template": "mrpi", "x0_facets": 12}),
    ("massera2017", MASSERA_UNITS[1], {"x0_template": "contractive", "x0_lambda": 0.95}),
], ids=["lorenzen2019-mrpi12", "massera2017-contractive"])
def test_a_fixed_template_in_other_state_units_is_the_mapped_design(name, T, changes):
    """The generator's path (a fixed template through design() and design_fixed)."""
    spec = get_example(name)
    options = replace(spec.design, **changes)
    scaled_problem = scale_states(spec.problem, T)
    original = _original(name, options, "drake", str(changes))
    assert_same_design_in_units(scaled_problem, design(scaled_problem, options, backend="drake"), original, T, options)
    assert_same_design_in_units(scaled_problem, design_fixed(scaled_problem, options, backend="drake"), original, T,
                                options)


def test_a_given_gain_is_returned_exactly_as_given_in_other_units():
    """A user-given K, P (in the user's units) is not K S⁻¹ S (which differs in the last bit)."""
    spec = get_example("lorenzen2019")
    original = _original("lorenzen2019", spec.design, "drake", "auto")
    T = EXAMPLE_1_UNITS[0]
    K, P = original.K / T[None, :], original.P / np.outer(T, T)
    options = replace(spec.design, K=K, P=P)
    d = design(scale_states(spec.problem, T), options, backend="drake")
    assert d.gain_source == "given"
    np.testing.assert_array_equal(d.K, K)
    np.testing.assert_array_equal(d.P, P)


def test_normalising_scales_are_the_ratio_of_the_largest_extent_of_w():
    """s_i = max e / e_i, e_i = max |w_i| over W: by hand for W = {|w_1| <= 0.1, |w_2| <= 0.01}; exactly 1
    for Example 1 (|w_i| <= 0.1) and for extents equal up to round-off (so its design is the one as written)."""
    problem = get_example("lorenzen2019").problem
    np.testing.assert_array_equal(units.normalising_scales(problem), [1.0, 1.0])
    np.testing.assert_allclose(units.normalising_scales(replace(problem, H_w=problem.H_w @ np.diag([1.0, 10.0]))),
                               [1.0, 10.0], rtol=1e-12)
    np.testing.assert_allclose(units.normalising_scales(scale_states(problem, [100.0, 0.01])), [1.0, 1e4], rtol=1e-12)
    nearly = replace(problem, H_w=problem.H_w @ np.diag([1.0, 1.0 + 1e-12]))
    np.testing.assert_array_equal(units.normalising_scales(nearly), [1.0, 1.0])
    assert units.is_identity(units.normalising_scales(nearly))


def test_a_check_lost_by_the_mapping_is_an_error_not_a_silent_design(monkeypatch):
    """A fixed-template design that passes (16) in the normalised units but not once mapped back (here:
    a mapping that loses 1e-3 of P, as a wrong mapping would) raises UnitsMappingError naming the check."""
    spec = get_example("lorenzen2019")
    options = replace(spec.design, x0_template="mrpi")
    mapped = units.from_normalised

    def losing_P(found, s, problem, opts, gain=None):
        d = mapped(found, s, problem, opts, gain)
        return replace(d, P=d.P * (1.0 - 1e-3))

    monkeypatch.setattr(units, "from_normalised", losing_P)
    with pytest.raises(units.UnitsMappingError, match="terminal cost"):
        design(scale_states(spec.problem, EXAMPLE_1_UNITS[0]), options, backend="drake")


def test_as_written_designs_in_the_files_units_and_a_bad_value_names_the_field():
    """design.state_units = "as written" is the design in the units of the file (no "state_units" record;
    Example 1 in diag(100, 0.01) then gets the other K: K̃T = [−0.051, −0.478], not [0.018, −0.415])."""
    from amcp_drake.model.errors import ProblemError

    spec = get_example("lorenzen2019")
    problem = scale_states(spec.problem, EXAMPLE_1_UNITS[0])
    d = design(problem, replace(spec.design, state_units="as written"), backend="drake")
    assert "state_units" not in d.info
    assert np.max(np.abs(d.K * EXAMPLE_1_UNITS[0][None, :] - [[0.018, -0.415]])) > 0.05
    with pytest.raises(ProblemError, match="design.state_units"):
        design(problem, replace(spec.design, state_units="metres"))
