"""The preimage template (offline/preimage.py) and the single-input integrator chains of the size study:
a file without a ``design`` section designs at n = 4 and passes every independent check; the template's
fit condition α_∞ max f̄ < 1 is judged just inside and just outside; its direction cap at its edge."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.backends import get_backend
from amcp_drake.model import polytope
from amcp_drake.model.problem_io import load_spec
from amcp_drake.offline.auto import Attempt, AutoDesignError
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design, design_fixed, robust_gain
from amcp_drake.offline.preimage import PREIMAGE_STOP_REACH, nominal_directions, preimage_max_rows
from amcp_drake.offline.templates import TemplateError
from amcp_drake.studies.chains import integrator_chain

THETA_VERTICES = np.array([[s1, s2] for s1 in (-0.1, 0.1) for s2 in (-0.1, 0.1)])


def _load(tmp_path, data: dict):
    path = tmp_path / f"{data['name']}.json"
    path.write_text(json.dumps(data))
    return load_spec(path)


def _fit_ratio_by_numpy(problem, d) -> float:
    """α_∞ · max f̄ of the design's X0, from its vertices (numpy only, not offline/preimage.py)."""
    verts = polytope.vertices(d.H_x, np.ones(len(d.H_x)))
    A_cl = [problem.A_of(t) + problem.B_of(t) @ d.K for t in THETA_VERTICES]
    h_bar = np.array([np.max(d.H_x @ Ak @ verts.T, axis=1) for Ak in A_cl])
    w_bar = np.max(d.H_x @ problem.w_vertices().T, axis=1)
    alpha_inf = float(np.max(w_bar[None, :] / (1.0 - h_bar)))
    return alpha_inf * float(np.max((problem.F + problem.G @ d.K) @ verts.T))


def test_integrator_chain4_without_design_section_designs_and_passes_every_check(tmp_path):
    spec = _load(tmp_path, integrator_chain(4))
    assert "design" not in json.loads((tmp_path / "integrator_chain4.json").read_text())
    d = design(spec.problem, spec.design)
    checks = verify_design(spec.problem, d, spec.design.mu_state_bound)  # numpy/scipy only
    assert [c.name for c in checks if not c.passed] == []
    assert len(d.H_x) <= preimage_max_rows(4) and len(d.H_T) == len(d.H_x)
    # contractivity and invariance recomputed here from the vertices, without offline/checks.py
    A_cl = [spec.problem.A_of(t) + spec.problem.B_of(t) @ d.K for t in THETA_VERTICES]
    h_bar = np.array([np.max(d.H_x @ Ak @ d.X0_vertices.T, axis=1) for Ak in A_cl])
    w_bar = np.max(d.H_x @ spec.problem.w_vertices().T, axis=1)
    assert np.max(h_bar) < 1.0 and np.max(h_bar + w_bar) <= 1.0 + 1e-9
    assert _fit_ratio_by_numpy(spec.problem, d) < 1.0


def _preimage_options(spec):
    return replace(spec.design, x0_template="preimage", x0_lambda=0.95, gain_R_scale=100.0)


def test_the_fit_condition_is_judged_just_inside_and_just_outside(tmp_path):
    """The least invariant template scales exactly with W (its directions depend on K and Z only, the
    template iteration is homogeneous in σ_W), so the fit ratio r measured at ‖w‖∞ <= 0.01 predicts it at
    any w: at w = 0.01·0.98/r the design passes every check; at w = 0.01·1.02/r it is refused as
    "does not fit Z" with the ratio 1.02 (1 % accuracy of the iteration's stopping rule); likewise at 1.5;
    at 2.2, above PREIMAGE_STOP_REACH, with a lower bound between the stop and 2.2."""
    spec = _load(tmp_path, integrator_chain(4))
    d = design_fixed(spec.problem, _preimage_options(spec))
    r = _fit_ratio_by_numpy(spec.problem, d)
    assert 0.1 < r < 1.0
    inside = _load(tmp_path, integrator_chain(4, w=0.01 * 0.98 / r))
    d_in = design_fixed(inside.problem, _preimage_options(inside))
    assert [c.name for c in verify_design(inside.problem, d_in) if not c.passed] == []
    for factor in (1.02, 1.5, 2.2):
        outside = _load(tmp_path, integrator_chain(4, w=0.01 * factor / r))
        with pytest.raises(TemplateError, match="does not fit Z") as err:
            design_fixed(outside.problem, _preimage_options(outside))
        if factor < PREIMAGE_STOP_REACH:  # the iteration ran to its fixed point: the exact ratio
            assert not err.value.fit_bound and err.value.fit_ratio == pytest.approx(factor, rel=1e-2)
        else:  # stopped at the first iterate reaching PREIMAGE_STOP_REACH: a lower bound
            assert err.value.fit_bound and PREIMAGE_STOP_REACH <= err.value.fit_ratio <= factor * 1.01
        assert f"alpha_inf * max f_bar = {'at least ' if err.value.fit_bound else ''}{err.value.fit_ratio:.3g}" \
            in str(err.value)


def test_the_direction_cap_at_its_edge(tmp_path):
    """The nominal directions of the 4-chain (λ₀ = 0.95, K from R x 100) number m: a cap of m accepts
    them, a cap of m - 1 refuses them as "too complex" naming the cap."""
    spec = _load(tmp_path, integrator_chain(4))
    pr = spec.problem
    be = get_backend("drake")
    K, _, _ = robust_gain(pr, replace(spec.design, gain_R_scale=100.0), be)
    A_nom = pr.A_of(pr.theta_hat0) + pr.B_of(pr.theta_hat0) @ K
    FGK = pr.F + pr.G @ K
    D = nominal_directions(FGK, A_nom, 0.95, be, max_rows=10_000)
    m = len(D)
    assert m <= preimage_max_rows(4)
    np.testing.assert_allclose(np.linalg.norm(D, axis=1), 1.0, atol=1e-12)
    assert len(nominal_directions(FGK, A_nom, 0.95, be, max_rows=m)) == m
    with pytest.raises(TemplateError, match=f"too complex: .*cap {m - 1}"):
        nominal_directions(FGK, A_nom, 0.95, be, max_rows=m - 1)


def test_auto_design_error_names_the_closest_fit():
    attempts = [Attempt("a", "design failed", "x", 0.1), Attempt("b", "design failed", "y", 0.2, fit_ratio=1.7),
                Attempt("c", "design failed", "z", 0.3, fit_ratio=1.3)]
    text = str(AutoDesignError(attempts))
    assert "Closest: candidate 3 (c): its least robustly invariant tube reaches 1.3 x the constraints" in text
    bound = [Attempt("d", "design failed", "w", 0.1, fit_ratio=2.4, fit_bound=True)]
    assert "Closest: candidate 1 (d): its least robustly invariant tube reaches at least 2.4 x" in str(
        AutoDesignError(bound))
    assert "Closest" not in str(AutoDesignError(attempts[:1]))
    assert attempts[2].to_dict()["fit_ratio"] == 1.3 and attempts[2].to_dict()["fit_bound"] is False
    assert "fit_ratio" not in attempts[0].to_dict()


def test_a_lambda_at_or_below_the_nominal_spectral_radius_is_refused_at_once(tmp_path):
    spec = _load(tmp_path, integrator_chain(4))
    pr = spec.problem
    be = get_backend("drake")
    K, _, _ = robust_gain(pr, replace(spec.design, gain_R_scale=100.0), be)
    A_nom = pr.A_of(pr.theta_hat0) + pr.B_of(pr.theta_hat0) @ K
    radius = float(np.max(np.abs(np.linalg.eigvals(A_nom))))
    with pytest.raises(TemplateError, match="below the spectral radius"):
        nominal_directions(pr.F + pr.G @ K, A_nom, radius, be, max_rows=10_000)
