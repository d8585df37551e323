"""Certificate claims of the Section 4 options and of the recorded cost:
``cost_value`` ((17) or (19) re-evaluated), ``pe_level`` and ``pe_bounds`` (docs/explanation/paper.md §8).

Known answers are worked by hand in the docstrings; honest runs pass; each tampering fails exactly
the claims that use the tampered quantity.
"""

from __future__ import annotations

import json
from types import SimpleNamespace

import jsonschema
import numpy as np
import pytest

from amcp_drake.certificate.certify import certify, schema
from amcp_drake.certificate.section4 import certainty_equivalence_cost, minmax_cost, window_gram
from amcp_drake.model.options import OnlineOptions
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate

PE_OPTIONS = OnlineOptions(update="exact", pe_window=3, pe_level=0.2)


@pytest.fixture(scope="module")
def spec(example_spec):
    return example_spec


@pytest.fixture(scope="module")
def designed(example_design):
    return example_design


def _run(spec, designed, options, steps, backend="drake") -> dict:
    ctrl = AdaptiveMPC(spec.problem, designed, backend=backend, options=options)
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, steps, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)
    assert traj.stop_reason == "completed"
    return json.loads(json.dumps(traj.to_dict()))


def fresh(recorded: dict) -> Trajectory:
    return Trajectory.from_dict(json.loads(json.dumps(recorded)))


@pytest.fixture(scope="module")
def pe_run(spec, designed) -> dict:
    return _run(spec, designed, PE_OPTIONS, 15)


@pytest.fixture(scope="module")
def minmax_run(spec, designed) -> dict:
    return _run(spec, designed, OnlineOptions(cost="minmax"), 10)


def failed_and_not_run(cert) -> tuple[set[str], list[str]]:
    return set(cert.ids("fail")), cert.ids("not_run")


# -- known answers ------------------------------------------------------------------------------
def test_window_gram_known_answer():
    """u = [1, 2, 3, 4]: at k = 3, d = 2, P = 2 the stacked inputs are [4, 3] and [3, 2], so the Gram
    is [[16+9, 12+6], [12+6, 9+4]]; at k = 1 the history is too short (u_{−1} would be needed)."""
    u = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(window_gram(u, 3, 2, 2), [[25.0, 18.0], [18.0, 13.0]])
    np.testing.assert_array_equal(window_gram(u, 2, 1, 3), [[1.0 + 4.0 + 9.0]])
    assert window_gram(u, 1, 2, 2) is None


def test_minmax_cost_known_answer():
    """n = m = 1, Q = R = 1, P = 2, K = −0.5, X0 = [−1, 1], N = 2, z = (1, 0.5, 0), α = (0, 0.5, 0.2),
    v = (0.1, 0.2). l = 0: x = 1, u = −0.4: 1.16. l = 1: x ∈ {1, 0}, u ∈ {−0.3, 0.2}: max(1.09, 0.04)
    = 1.09. Terminal: x ∈ {±0.2}: 2·0.04 = 0.08. Total 2.33."""
    problem = SimpleNamespace(Q=np.eye(1), R=np.eye(1))
    des = SimpleNamespace(K=np.array([[-0.5]]), P=np.array([[2.0]]), X0_vertices=np.array([[1.0], [-1.0]]))
    J = minmax_cost(problem, des, np.array([[1.0], [0.5], [0.0]]), np.array([0.0, 0.5, 0.2]), np.array([[0.1], [0.2]]))
    assert J == pytest.approx(2.33, abs=1e-14)


def test_certainty_equivalence_cost_known_answer():
    """x_{k+1} = (1 + 0.5θ)x + u, θ̂ = 0.2: A(θ̂) = 1.1; K = −0.5, v = 0.1, x = 1: u = −0.4, stage
    1 + 0.16; x̂_1 = 1.1 − 0.4 = 0.7, terminal 2·0.49 = 0.98. Total 2.14."""
    problem = SimpleNamespace(A0=np.eye(1), A=np.array([[[0.5]]]), B0=np.eye(1), B=np.zeros((1, 1, 1)),
                              Q=np.eye(1), R=np.eye(1))
    des = SimpleNamespace(K=np.array([[-0.5]]), P=np.array([[2.0]]))
    J = certainty_equivalence_cost(problem, des, np.array([1.0]), np.array([0.2]), np.array([[0.1]]))
    assert J == pytest.approx(2.14, abs=1e-14)


# -- PE -----------------------------------------------------------------------------------------
def test_pe_run_certifies_with_pe_claims(pe_run, spec):
    cert = certify(fresh(pe_run), spec)
    assert cert.verdict == "pass", (cert.ids("fail"), cert.ids("not_run"))
    assert cert.ids()[-4:] == ["cost_value", "qp_optimality", "pe_level", "pe_bounds"]
    enforced = [k for k, s in enumerate(pe_run_statuses(pe_run)) if s.startswith("enforced")]
    assert len(enforced) >= 5  # the claim is exercised, not vacuous
    assert len(cert.claim("pe_level").data["per_step"]) == len(enforced)
    # the constraint binds: the realised λ_min sits on the recorded level (margin ~0, not large)
    assert abs(cert.claim("pe_level").margin) < 1e-6
    pe = cert.figures["persistent_excitation"]
    assert pe["window"] == 3 and sum(pe["status_counts"].values()) == len(pe_run["records"])
    data = json.loads(json.dumps(cert.to_dict(), allow_nan=False))
    jsonschema.validate(data, schema())


def pe_run_statuses(recorded: dict) -> list[str]:
    return [r.pe_status for r in fresh(recorded).records]


def _worst_enforced_step(cert) -> int:
    return int(cert.claim("pe_level").data["worst_step"])


def test_raised_pe_level_fails_only_pe_level(pe_run, spec):
    """The recorded level of the binding step raised by 1e-3: the applied inputs no longer reach it."""
    k = _worst_enforced_step(certify(fresh(pe_run), spec))
    tr = fresh(pe_run)
    tr.records[k].pe_level += 1e-3
    cert = certify(tr, spec)
    assert failed_and_not_run(cert) == ({"pe_level"}, [])
    assert cert.claim("pe_level").data["worst_step"] == k
    assert cert.claim("pe_level").margin == pytest.approx(-1e-3, abs=1e-6)


def test_bounds_that_exclude_the_input_fail_only_pe_bounds(pe_run, spec):
    """pe_bounds of an enforced step moved to [u_k + 0.01, ∞): the applied input lies outside, and the
    recorded decision is then not even feasible for the QP (20) with that bound (qp_optimality)."""
    tr = fresh(pe_run)
    k = next(r.k for r in tr.records if r.pe_status == "enforced")
    u = float(tr.records[k].u[0])
    tr.records[k].pe_bounds = (u + 0.01, float("inf"))
    cert = certify(tr, spec)
    assert failed_and_not_run(cert) == ({"pe_bounds", "qp_optimality"}, [])
    assert cert.claim("pe_bounds").margin == pytest.approx(-0.01 / max(1.0, abs(u + 0.01)), rel=1e-9)


def test_enforced_step_without_bounds_or_level_fails(pe_run, spec):
    """A record that says "enforced" but holds no bounds (or no level) contradicts itself: a failure.
    Without the bound, the QP (20) rebuilt for that step lacks the constraint that held its solution
    (the bound binds at an enforced step), so the recorded decision is not its minimiser either."""
    tr = fresh(pe_run)
    k = next(r.k for r in tr.records if r.pe_status == "enforced")
    tr.records[k].pe_bounds = None
    assert failed_and_not_run(certify(tr, spec)) == ({"pe_bounds", "qp_optimality"}, [])
    tr = fresh(pe_run)
    tr.records[k].pe_level = None
    assert failed_and_not_run(certify(tr, spec)) == ({"pe_level"}, [])


def test_pe_that_never_enforced_is_incomplete(spec, designed):
    """Two steps: the window history is too short, so no step enforces the constraint and the PE
    option made no checkable claim: pe_level and pe_bounds are not_run, the verdict incomplete."""
    cert = certify(fresh(_run(spec, designed, PE_OPTIONS, 2)), spec)
    assert cert.ids("fail") == [] and cert.ids("not_run") == ["pe_level", "pe_bounds"]
    assert cert.verdict == "incomplete"


def test_run_without_pe_has_no_pe_claims(minmax_run, spec):
    cert = certify(fresh(minmax_run), spec)
    assert not {"pe_level", "pe_bounds"} & set(cert.ids())
    assert "persistent_excitation" not in cert.figures


# -- min-max cost (19) --------------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_minmax_run_certifies(spec, designed, backend):
    recorded = _run(spec, designed, OnlineOptions(cost="minmax"), 10, backend)
    cert = certify(fresh(recorded), spec)
    assert cert.verdict == "pass", (cert.ids("fail"), cert.ids("not_run"))
    assert cert.claim("cost_value").data["cost"] == "minmax" and "(19)" in cert.claim("cost_value").name
    assert cert.claim("cost_value").margin > -1e-7


def test_tampered_minmax_cost_fails_only_cost_value(minmax_run, spec):
    tr = fresh(minmax_run)
    tr.records[4].cost += 1e-4 * max(1.0, tr.records[4].cost)
    cert = certify(tr, spec)
    assert failed_and_not_run(cert) == ({"cost_value"}, [])
    assert cert.claim("cost_value").data["worst_step"] == 4


def test_minmax_costs_are_not_certainty_equivalence_costs(minmax_run, spec):
    """The same recorded run read as a certainty-equivalence run: its costs are (19), not (17), so
    cost_value fails; the check depends on the formula it claims. Its decisions minimise (19), not
    (17), so qp_optimality fails too."""
    data = json.loads(json.dumps(minmax_run))
    data["options"]["cost"] = "certainty_equivalence"
    cert = certify(fresh(data), spec)
    assert failed_and_not_run(cert) == ({"cost_value", "qp_optimality"}, [])


def test_unattainable_level_falls_back_to_the_plain_qp_and_claims_nothing(spec, designed):
    """ρ = 5 with P = 3 and |u| <= 1: even the one-dimensional rung at 1/8 of its level needs
    Σ_window u² >= 5·1.5²/0.95/8 ≈ 1.48 from one new input after the transient, so no step enforces PE
    (the fallback of docs/explanation/paper.md §8: (20) alone). The run then equals the run without PE, and its
    certificate has no checkable PE claim (incomplete), with the fallback steps counted in the figure."""
    steps = 12
    pe = fresh(_run(spec, designed, OnlineOptions(pe_window=3, pe_level=5.0), steps))
    plain = fresh(_run(spec, designed, OnlineOptions(), steps))
    statuses = [r.pe_status for r in pe.records]
    assert statuses[:4] == ["inactive"] * 4 and set(statuses[4:]) == {"fallback"}
    np.testing.assert_array_equal(pe.u, plain.u)
    cert = certify(pe, spec)
    assert cert.ids("fail") == [] and cert.ids("not_run") == ["pe_level", "pe_bounds"]
    assert cert.verdict == "incomplete"
    assert cert.figures["persistent_excitation"]["status_counts"] == {"inactive": 4, "fallback": steps + 1 - 4}


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_minmax_cost_is_that_of_the_plan_on_badly_scaled_states(backend):
    """A min–max run in badly scaled units (tests/data/minmax-scaled-problem.json, found by the property
    suite: state scaling 1e2, x0 = 350, Q = 9.5e-5): the recorded cost equals (19) of the recorded plan
    by the certificate's numpy formula, to 1e-12 relative. Before, the backends recorded the solver's
    Σ s_l², whose epigraph rows hold only to Clarabel's tolerance relative to the largest variable:
    1.3e-6 relative below (19) at step 2, and the certificate's "cost (19)" claim failed."""
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.replay import run_scenario

    spec = load_spec("tests/data/minmax-scaled-problem.json")
    traj = run_scenario(spec, backend, design_backend="drake")
    solved = [r for r in traj.records if r.cost is not None]
    assert traj.stop_reason == "completed" and len(solved) >= 12
    for r in solved:
        J = minmax_cost(traj.problem, traj.design, r.z, r.alpha, r.v)
        assert abs(r.cost - J) <= 1e-12 * max(1.0, abs(J)), (r.k, r.cost, J)
    assert certify(traj, spec).claim("cost_value").status == "pass"
