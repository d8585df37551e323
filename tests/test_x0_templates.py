"""Cross-section templates of X0 and the automatic design.

Every property of a template is re-checked here with plain numpy/scipy (Qhull vertex enumeration
of the polytopes, vertices of boxes by itertools, random closed-loop samples), never with
``amcp_drake.model.polytope`` or the design code under test.
"""

from __future__ import annotations

import itertools
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import HalfspaceIntersection

from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.model.problem import DesignOptions, Problem
from amcp_drake.model.sls_mpc_2d import SLS_EPS_A_SWEEP, sls_mpc_2d_problem, sls_mpc_2d_spec
from amcp_drake.offline.auto import AUTO_FACETS, AutoDesignError, candidate_options
from amcp_drake.offline.design import design, design_fixed

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
#: Round-off of Qhull vertices and of the LP-based design (Clarabel ~1e-8).
TOL = 1e-7


# -- independent geometry ------------------------------------------------------------------------

def vertices_of(H: np.ndarray) -> np.ndarray:
    """Vertices of {H x <= 1} by Qhull, from an interior point found by a Chebyshev LP (HiGHS)."""
    n = H.shape[1]
    norms = np.linalg.norm(H, axis=1)
    res = linprog(np.r_[np.zeros(n), -1.0], A_ub=np.hstack([H, norms[:, None]]), b_ub=np.ones(len(H)),
                  bounds=[(None, None)] * n + [(0, None)], method="highs")
    assert res.status == 0 and res.x[-1] > 1e-9, "X0 has no interior"
    return HalfspaceIntersection(np.hstack([H, -np.ones((len(H), 1))]), res.x[:n]).intersections


def box_vertices(bounds: np.ndarray) -> np.ndarray:
    return np.array([np.array(s) * bounds for s in itertools.product((-1.0, 1.0), repeat=len(bounds))])


def closed_loop(problem: Problem, K: np.ndarray) -> np.ndarray:
    """A(θ) + B(θ)K at the 2^p corners of the box Θ = [-1, 1]^p (the SLS family and the test systems)."""
    corners = box_vertices(np.ones(problem.p))
    return np.array([problem.A0 + np.tensordot(t, problem.A, 1) + (problem.B0 + np.tensordot(t, problem.B, 1)) @ K
                     for t in corners])


def contraction_and_invariance(problem: Problem, d) -> tuple[float, float]:
    """(λ̄, max_k,i h̄^k_i + w̄_i) of X0 = {d.H_x x <= 1}, from vertices of X0, of W and of Θ."""
    X = vertices_of(d.H_x)
    W = box_vertices(1.0 / np.abs(problem.H_w).max(axis=1)[: problem.n])  # W is a box in these tests
    w_bar = np.max(d.H_x @ W.T, axis=1)
    h_bar = np.array([np.max(d.H_x @ Ak @ X.T, axis=1) for Ak in closed_loop(problem, d.K)])
    return float(np.max(h_bar)), float(np.max(h_bar + w_bar))


def sampled_invariance_violation(problem: Problem, d, samples: int = 2000, seed: int = 1) -> float:
    """Largest max_i [H_x]_i x⁺ - 1 over random x ∈ X0 (convex combinations of vertices), θ ∈ Θ, w ∈ W."""
    rng = np.random.default_rng(seed)
    X = vertices_of(d.H_x)
    wmax = 1.0 / np.abs(problem.H_w).max(axis=1)[: problem.n]
    worst = -np.inf
    for _ in range(samples):
        x = rng.dirichlet(np.ones(len(X))) @ X
        theta = rng.uniform(-1.0, 1.0, problem.p)
        w = rng.uniform(-wmax, wmax)
        u = d.K @ x
        x_next = problem.step(x, u, theta, w)
        worst = max(worst, float(np.max(d.H_x @ x_next - 1.0)))
    return worst


def strongly_stable_problem(w_max: float) -> Problem:
    """x⁺ = (0.3 I + 0.05 θ I) x + [0; 1] u + w, θ ∈ [-1, 1], |x_i| <= 1, |u| <= 1, ‖w‖∞ <= w_max."""
    return Problem(A0=0.3 * np.eye(2), B0=np.array([[0.0], [1.0]]), A=[0.05 * np.eye(2)], B=[np.zeros((2, 1))],
                   H_w=np.vstack([np.eye(2), -np.eye(2)]) / w_max, H_theta=[[1.0], [-1.0]], h_theta=[1.0, 1.0],
                   F=np.vstack([np.eye(2), -np.eye(2), np.zeros((2, 2))]),
                   G=np.vstack([np.zeros((4, 1)), [[1.0], [-1.0]]]), Q=np.eye(2), R=np.eye(1), N=3,
                   theta_hat0=[0.0], name="strongly_stable")


# -- each template: contractivity and robust invariance re-checked ---------------------------------

@pytest.mark.parametrize("eps_A", [0.05])
def test_mrpi_template_is_contractive_and_robustly_invariant(eps_A):
    problem = sls_mpc_2d_problem(eps_A)
    d = design_fixed(problem, DesignOptions(x0_template="mrpi", x0_facets=8))
    lam, inv = contraction_and_invariance(problem, d)
    assert len(d.H_x) == 8
    assert lam < 1.0 and inv <= 1.0 + TOL
    assert sampled_invariance_violation(problem, d) <= TOL


@pytest.mark.parametrize("eps_A, lam", [(0.25, 0.9), (0.35, 0.95)])
def test_contractive_template_is_lambda_contractive_robustly_invariant_and_inside_the_constraints(eps_A, lam):
    problem = sls_mpc_2d_problem(eps_A)
    d = design_fixed(problem, DesignOptions(x0_template="contractive", x0_lambda=lam))
    lam_bar, inv = contraction_and_invariance(problem, d)
    # the backward iteration builds A_cl(θ)X0 ⊕ W ⊆ λ X0: h̄ + w̄ <= λ, hence λ̄ <= λ and invariance
    assert lam_bar <= lam + TOL
    assert inv <= lam + TOL
    X = vertices_of(d.H_x)
    FGK = problem.F + problem.G @ d.K
    assert np.max(FGK @ X.T) <= 1.0 + TOL  # X0 ⊆ {(x, Kx) ∈ Z}
    assert sampled_invariance_violation(problem, d) <= TOL


def test_contractive_template_is_maximal_in_the_sense_of_its_last_rows():
    """Each facet of the contractive set is needed: pushing any row out by 5 % breaks h̄ + w̄ <= λ or Z."""
    problem = sls_mpc_2d_problem(0.25)
    lam = 0.9
    d = design_fixed(problem, DesignOptions(x0_template="contractive", x0_lambda=lam))
    A_cl = closed_loop(problem, d.K)
    FGK = problem.F + problem.G @ d.K
    W = box_vertices(np.full(2, 0.1))
    for i in range(len(d.H_x)):
        H = d.H_x.copy()
        H[i] /= 1.05
        X = vertices_of(H)
        w_bar = np.max(H @ W.T, axis=1)
        grown_ok = (np.max(FGK @ X.T) <= 1.0 + TOL
                    and all(np.max(np.max(H @ Ak @ X.T, axis=1) + w_bar) <= lam + TOL for Ak in A_cl))
        assert not grown_ok, f"row {i} can be relaxed: the set is not the maximal lambda-contractive set"


def test_given_template_is_used_as_given_and_checked():
    problem = sls_mpc_2d_problem(0.25)
    reference = design_fixed(problem, DesignOptions(x0_template="contractive", x0_lambda=0.9))
    given = design(problem, DesignOptions(x0_template="given", x0_H=reference.H_x))
    assert np.array_equal(given.H_x, reference.H_x)
    lam, inv = contraction_and_invariance(problem, given)
    assert lam < 1.0 and inv <= 1.0 + TOL


def test_given_template_that_is_not_invariant_fails_in_auto_mode_and_the_next_candidate_is_taken():
    problem = sls_mpc_2d_problem(0.05)
    tiny_box = np.vstack([np.eye(2), -np.eye(2)]) / 0.01  # |x_i| <= 0.01: smaller than W itself
    d = design(problem, DesignOptions(x0_H=tiny_box))
    attempts = d.info["attempts"]
    assert attempts[0]["label"].startswith("given") and attempts[0]["outcome"] != "pass"
    assert attempts[1]["label"] == "mrpi, 8 facets" and attempts[1]["outcome"] == "pass"


def test_lower_gain_option_keeps_the_terminal_cost_condition_with_the_true_R():
    """gain_R_scale > 1: the LMI is solved with 100 R; (16) must still hold with R (eigenvalues here)."""
    problem = sls_mpc_2d_problem(0.25)
    d = design_fixed(problem, DesignOptions(x0_template="contractive", x0_lambda=0.95, gain_R_scale=100.0))
    assert d.gain_source == "lmi (R x 100)"
    for Ak in closed_loop(problem, d.K):
        M = Ak.T @ d.P @ Ak + problem.Q + d.K.T @ problem.R @ d.K - d.P
        assert np.max(np.linalg.eigvalsh(0.5 * (M + M.T))) <= 1e-9


# -- the automatic mode ---------------------------------------------------------------------------

def test_auto_keeps_example_1_design_identical_to_the_mrpi_8_design(example_spec, example_design):
    fixed = design_fixed(example_spec.problem, replace(example_spec.design, x0_template="mrpi"))
    assert example_design.info["x0_template"] == "mrpi, 8 facets"
    assert [a["outcome"] for a in example_design.info["attempts"]] == ["pass"]
    for key in ("K", "P", "H_x", "H_T", "h_T", "w_bar", "f_bar"):
        assert np.array_equal(getattr(example_design, key), getattr(fixed, key)), key


def test_auto_order_is_documented_order():
    problem = sls_mpc_2d_problem(0.25)
    labels = [(o.x0_template, o.x0_facets if o.x0_template == "mrpi" else o.x0_lambda, o.gain_R_scale)
              for o in candidate_options(problem, DesignOptions())]
    assert labels[0] == ("mrpi", 8, 1.0)
    lambdas = [0.9, 0.95, 0.98, 0.99]
    # lowest gain first (K from 100 R), the LMI gain last, each with the λ list
    assert labels[1:13] == [("contractive", lam, scale) for scale in (100.0, 10.0, 1.0) for lam in lambdas]
    assert labels[13:] == [("mrpi", facets, 1.0) for facets in AUTO_FACETS]


def test_auto_takes_the_second_candidate_when_the_first_fails_and_records_why():
    problem = sls_mpc_2d_problem(0.15)
    d = design(problem, DesignOptions())
    attempts = d.info["attempts"]
    assert [a["label"] for a in attempts] == ["mrpi, 8 facets", "contractive, lambda 0.9, K from R x 100"]
    assert attempts[0]["outcome"] == "design failed" and "not converged" in attempts[0]["reason"]
    assert "Next:" in attempts[0]["reason"]
    assert attempts[1]["outcome"] == "pass"
    assert d.info["options"] == {"x0_template": "contractive", "x0_facets": 8, "x0_lambda": 0.9, "gain_R_scale": 100.0}


def test_cli_design_prints_one_line_per_candidate_and_the_full_reasons_under_verbose(tmp_path):
    """Without -v each candidate of the automatic design appears on exactly one line (what it tried,
    how it ended, the short reason) and the vectors w_bar, f_bar are summarised; -v adds every full
    reason (with the next thing to try) and the vectors in full."""
    from click.testing import CliRunner

    from amcp_drake.cli.main import main

    labels = ["mrpi, 8 facets", "contractive, lambda 0.9, K from R x 100", "contractive, lambda 0.95, K from R x 100"]
    result = CliRunner().invoke(main, ["design", str(EXAMPLES / "sls_mpc_2d_eps0.25.json")])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    for label in labels:
        assert len([line for line in lines if f": {label}: " in line]) == 1, (label, result.output)
    # divergence is reported as divergence
    assert "design candidate 1: mrpi, 8 facets: design failed (diverged" in result.output
    assert "design candidate 3: contractive, lambda 0.95, K from R x 100: pass, X0 8 facets / 8 vertices" in result.output
    assert "w_bar = [" in result.output  # 8 values: printed in full
    assert "Next:" not in result.output and "P = " not in result.output
    assert "all design checks pass" in result.output

    verbose = CliRunner().invoke(main, ["design", str(EXAMPLES / "sls_mpc_2d_eps0.25.json"), "-v"])
    assert verbose.exit_code == 0, verbose.output
    assert "design attempt 1: mrpi, 8 facets: design failed (X0 template mrpi (8 facets): diverged" in verbose.output
    assert "Next: more facets (design.x0_facets), or x0_template = 'contractive'" in verbose.output
    assert "design attempt 3: contractive, lambda 0.95, K from R x 100: pass" in verbose.output
    assert "P = [" in verbose.output


def test_cli_x0_template_option_forces_one_template():
    from click.testing import CliRunner

    from amcp_drake.cli.main import main

    result = CliRunner().invoke(main, ["design", str(EXAMPLES / "sls_mpc_2d_eps0.25.json"), "--x0-template", "mrpi"])
    assert result.exit_code == 1
    assert "diverged" in result.output and "Next:" in result.output


def test_auto_failure_lists_every_attempt_with_its_reason():
    problem = strongly_stable_problem(w_max=1.0)  # W as large as the state box: no tube fits in Z
    options = DesignOptions()
    expected = len(candidate_options(problem, options))
    with pytest.raises(AutoDesignError) as info:
        design(problem, options)
    err = info.value
    assert isinstance(err, DesignError)
    assert len(err.attempts) == expected
    assert all(a.outcome != "pass" and a.reason for a in err.attempts)
    text = str(err)
    assert f"none of the {expected} candidates passed" in text
    # one line per distinct failure, naming the numbers of the candidates that ended with it: every candidate
    # is counted exactly once and every distinct reason is printed
    numbers = []
    for line in text.splitlines():
        head = re.match(r"^  (\d+(?:, \d+)*)(?: \((\d+) x; first: [^)]*\)|\. [^:]*):", line)
        if head:
            group = [int(k) for k in head.group(1).split(", ")]
            assert head.group(2) is None or int(head.group(2)) == len(group)
            numbers += group
    assert sorted(numbers) == list(range(1, expected + 1))
    for attempt in err.attempts:
        assert attempt.reason in text


def test_the_same_system_with_a_small_disturbance_designs():
    """Control for the failure test: the failure above comes from W, not from the system."""
    d = design(strongly_stable_problem(w_max=0.05), DesignOptions())
    assert d.info["attempts"][-1]["outcome"] == "pass"


@pytest.mark.parametrize("eps_A", SLS_EPS_A_SWEEP)
def test_sls_family_designs_at_default_settings(eps_A):
    """The default (auto) design succeeds and passes every design check for every ε_A."""
    from amcp_drake.offline.checks import verify_design

    spec = sls_mpc_2d_spec(eps_A)
    d = design(spec.problem, spec.design)
    assert all(c.passed for c in verify_design(spec.problem, d))
    lam, inv = contraction_and_invariance(spec.problem, d)
    assert lam < 1.0 and inv <= 1.0 + TOL
    # the default scenario starts where the first QP is feasible (vertex-form LP of the property suite,
    # independent of both backends)
    from amcp_properties.feasible import TubeGeometry, feasibility_margin

    geo = TubeGeometry.build(spec.problem, d, spec.problem.theta_vertices())
    assert feasibility_margin(geo, spec.scenario.x0) > 0.0


# -- bad input -------------------------------------------------------------------------------------

@pytest.mark.parametrize("changes, field", [
    ({"x0_template": "box"}, "design.x0_template"),
    ({"x0_lambda": 1.0}, "design.x0_lambda"),
    ({"x0_lambda": True}, "design.x0_lambda"),
    ({"x0_template": "given"}, "design.x0_H"),
    ({"x0_template": "mrpi", "x0_H": np.eye(2)}, "design.x0_H"),
    ({"x0_template": "given", "x0_H": [[1.0, 0.0], [0.0, 1.0]]}, "design.x0_H"),
    ({"gain_R_scale": 0.5}, "design.gain_R_scale"),
])
def test_bad_template_options_name_the_field(changes, field):
    with pytest.raises(ProblemError, match=field.replace(".", r"\.")):
        DesignOptions(**changes).validate_for(sls_mpc_2d_problem(0.05))


def test_problem_file_round_trips_the_template_fields(tmp_path):
    from amcp_drake.model.problem_io import load_spec, save_spec

    spec = sls_mpc_2d_spec(0.25)
    H = np.vstack([np.eye(2), -np.eye(2)])
    spec = replace(spec, design=replace(spec.design, x0_template="given", x0_H=H, gain_R_scale=10.0))
    back = load_spec(save_spec(spec, tmp_path / "p.json"))
    assert back.design.x0_template == "given" and back.design.gain_R_scale == 10.0
    assert np.array_equal(back.design.x0_H, H)


def test_example_files_match_the_constructor():
    from amcp_drake.model.problem_io import load_spec

    for eps_A in SLS_EPS_A_SWEEP:
        spec = load_spec(EXAMPLES / f"sls_mpc_2d_eps{eps_A:g}.json")
        ref = sls_mpc_2d_problem(eps_A)
        assert np.array_equal(spec.problem.A, ref.A) and np.array_equal(spec.problem.B, ref.B)
        assert spec.problem.A[0, 0, 0] == eps_A and spec.problem.B[1, 1, 0] == 0.1
        assert spec.design.x0_template == "auto"


def three_state_problem() -> Problem:
    """A 3-state chain x⁺ = (A0 + 0.05 θ E11) x + B u + w, θ ∈ [-1, 1], ‖x‖∞ <= 5, |u| <= 2, ‖w‖∞ <= 0.05."""
    A0 = np.array([[0.9, 0.2, 0.0], [0.0, 0.9, 0.2], [0.0, 0.0, 0.9]])
    E = np.zeros((3, 3))
    E[0, 0] = 0.05
    return Problem(A0=A0, B0=np.array([[0.0], [0.0], [1.0]]), A=[E], B=[np.zeros((3, 1))],
                   H_w=np.vstack([np.eye(3), -np.eye(3)]) / 0.05, H_theta=[[1.0], [-1.0]], h_theta=[1.0, 1.0],
                   F=np.vstack([np.eye(3), -np.eye(3), np.zeros((2, 3))]) / 5.0,
                   G=np.vstack([np.zeros((6, 1)), [[0.5], [-0.5]]]), Q=np.eye(3), R=np.eye(1), N=3,
                   theta_hat0=[0.0], name="chain3")


def test_contractive_template_in_three_dimensions_is_checked_independently():
    problem = three_state_problem()
    lam = 0.95
    d = design_fixed(problem, DesignOptions(x0_template="contractive", x0_lambda=lam))
    lam_bar, inv = contraction_and_invariance(problem, d)
    assert lam_bar <= lam + TOL and inv <= lam + TOL
    assert sampled_invariance_violation(problem, d, samples=500) <= TOL
