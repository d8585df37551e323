"""Decisions added for scale and masking, each tested so that changing it fails a test: the byte width of the
numbers a run records in its size estimate (model/limits.py), the terminal-set construction chosen per n
(offline/terminal.py), the Θ the formulation sizes are counted on (online/formulation_choice.py), and how a
projection fallback is recorded (online/controller.py). Expected values come from measurements of real runs
and designs, or are counted by hand, never from the code under test."""

from __future__ import annotations

import json
import sys
from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.model import polytope
from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.offline.terminal import terminal_set_kind
from amcp_drake.online import answers


# -- the byte width of a recorded number -----------------------------------------------------------
def test_the_size_estimate_records_numbers_at_their_measured_width(example_spec, example_design):
    """The estimate's memory per extra step of Example 1 (plain form), divided by the numbers one record of a
    real run holds, is the bytes a recorded number takes: at least its three copies measured here (8 in the
    numpy record, a Python float and its list slot in the JSON tree, its characters in the JSON text) and at
    most twice that (the allocator's slack)."""
    from amcp_drake.model.limits import estimate_for
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="plain")
    sc = example_spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, 4, "uniform", seed=0)
    record = traj.records[2]
    numbers = [float(x) for v in vars(record).values() if isinstance(v, np.ndarray) for x in np.ravel(v)]
    held = 8 + sys.getsizeof(1.5) + 8 + len(json.dumps(numbers)) / len(numbers)
    short, long = (estimate_for(example_spec.problem, example_spec.design, steps=s, design=example_design,
                                formulation="plain") for s in (5, 40))
    width = (long.memory_bytes - short.memory_bytes) / 35 / len(numbers)
    assert held <= width <= 2 * held, (held, width)


# -- the terminal set chosen per n -----------------------------------------------------------------
@pytest.mark.parametrize("n, kind", [(1, "recursion"), (2, "recursion"), (3, "recursion"), (4, "scaled"),
                                     (5, "scaled"), (8, "scaled")])
def test_the_automatic_terminal_set_is_the_recursion_up_to_n_3(n, kind):
    from amcp_drake.model.problem import DesignOptions

    assert terminal_set_kind(DesignOptions(), n) == kind
    assert terminal_set_kind(DesignOptions(terminal_set="recursion"), n) == "recursion"
    assert terminal_set_kind(DesignOptions(terminal_set="scaled"), n) == "scaled"


@pytest.mark.parametrize("n", [3, 4])
def test_the_design_builds_the_terminal_set_of_its_dimension(n):
    """Automatic designs of the actuated chain: at n = 3 the recursion of Appendix A.1 (at least one iteration,
    nominal centre dynamics A_z ≠ 0), at n = 4 the scaled copy of X0 (A_z = 0, no iteration, every row of H_T
    a positive multiple of the matching row of H_x)."""
    from amcp_drake.offline.design import design
    from amcp_drake.studies.chains import chain

    spec = spec_from_dict(chain("actuated", n))
    d = design(spec.problem, spec.design, backend="drake")
    H_T, H_x = np.asarray(d.H_T), np.asarray(d.H_x)
    scaled = (H_T.shape == H_x.shape and float(np.max(np.abs(d.A_z))) == 0.0 and d.terminal_iterations == 0
              and np.allclose(H_T / np.linalg.norm(H_T, axis=1, keepdims=True),
                              H_x / np.linalg.norm(H_x, axis=1, keepdims=True), rtol=0, atol=1e-12))
    assert scaled == (n == 4)
    if n == 3:
        assert d.terminal_iterations >= 1 and float(np.max(np.abs(d.A_z))) > 0


# -- the Θ the formulation sizes are counted on ----------------------------------------------------
def test_the_formulation_sizes_count_the_designs_theta(example_spec):
    """A design whose shape of (9) has one extra direction (1, 1, 0)/√2 beside the box Θ (q_θ = 7 rows; Θ0 keeps
    the box's 8 vertices, the new row only touches an edge): the plain size is 8 kept rows × (7 − 3 + 1) = 40,
    not the 8 × (6 − 3 + 1) = 32 of the problem's Θ; the vertex size 8 facets × 8 vertices = 64."""
    from amcp_drake.offline.design import design
    from amcp_drake.online.formulation_choice import formulation_sizes

    options = replace(example_spec.design, theta_extra_directions=np.array([[1.0, 1.0, 0.0]]))
    d = design(example_spec.problem, options, backend="drake")
    assert len(d.H_theta) == 7 and len(example_spec.problem.H_theta) == 6 and len(d.H_x) == 8
    theta0 = polytope.vertices(np.asarray(d.H_theta), np.asarray(d.h_theta0))
    assert len(theta0) == 8
    assert formulation_sizes(example_spec.problem, d) == (64, 40)


# -- how a projection fallback is recorded ---------------------------------------------------------
def test_a_projection_fallback_is_recorded_as_a_fallback_of_its_kind(example_spec, example_design, monkeypatch):
    """Projections onto Θ_k (Remark 7) under vertex disturbances, the backend answering θ̃ itself ("optimal",
    outside Θ_k) and the least-distance solver failing: at every step where θ̃ ∉ Θ_k, θ̂_(k−1) is kept when it
    lies in Θ_k and the Chebyshev centre of Θ_k is used otherwise; each is recorded as a fallback of that kind
    (never a first answer), counted so by the certificate, which then skips (12) at that step and fails the
    backend's conformance."""
    from amcp_drake.certificate.certify import certify
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.online import controller as controller_module
    from amcp_drake.online.answer_checks import PROJECTION_MEMBERSHIP_TOL
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate
    from tests.test_answer_checks import WrongBackend

    monkeypatch.setattr(controller_module.polytope, "least_distance_point", lambda *a: None)
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake", options=OnlineOptions(projection="Theta_k"))
    ctrl.backend = WrongBackend(ctrl.backend, wrong_project=lambda real, point, H, h: point.copy())
    sc = example_spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star, 10, "vertices", seed=0, mu_state_bound=example_spec.design.mu_state_bound)
    kinds = {}
    for prev, r in zip(traj.records, traj.records[1:]):
        H, h = polytope.normalize_rows(r.H_theta, r.h_theta)
        if float(np.max(H @ r.theta_tilde - h)) <= 0:
            continue  # θ̃ ∈ Θ_k: θ̂_k = θ̃, no solver asked
        kept = float(np.max(H @ prev.theta_hat - h)) <= PROJECTION_MEMBERSHIP_TOL
        kind = "kept_previous_estimate" if kept else "chebyshev_centre"
        expected = prev.theta_hat if kept else polytope.chebyshev_center(r.H_theta, r.h_theta)[0]
        entry = answers.of(r, "projection")
        assert entry is not None and (entry["outcome"], entry["kind"]) == ("fallback", kind), (r.k, entry)
        assert np.allclose(r.theta_hat, expected, rtol=0, atol=1e-12)
        kinds[r.k] = kind
    assert set(kinds.values()) == {"kept_previous_estimate", "chebyshev_centre"}, kinds
    cert = certify(traj, example_spec)
    assert cert.solver_answers["problems"]["projection"]["fallback"] == len(kinds)
    assert cert.conformance == "fail"
    checked = {k for k, _ in cert.claim("lms_update").data["per_step"]}
    assert not checked & set(kinds)
