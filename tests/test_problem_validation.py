"""Bad input: every malformed problem is rejected with the right typed error and a message that
names the field, what was expected and what was received (never a numpy/scipy/Drake traceback,
never SystemExit)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from amcp_drake.model.errors import AmcpError, ProblemError
from amcp_drake.model.problem import DesignOptions, Problem, Scenario

from .conftest import scalar_problem

GOOD = dict(A0=[[0.5, 0.2], [-0.1, 0.6]], B0=[[0.0], [0.5]],
            A=[[[0.042, 0.0], [0.072, 0.03]], [[0.015, 0.019], [0.009, 0.035]]],
            B=[[[0.0], [0.0]], [[0.04], [0.054]]],
            H_w=[[10.0, 0], [-10.0, 0], [0, 10.0], [0, -10.0]],
            H_theta=[[1.0, 0], [-1.0, 0], [0, 1.0], [0, -1.0]], h_theta=[1.0, 1, 1, 1],
            F=[[0.0, -1 / 0.3], [0, 0], [0, 0]], G=[[0.0], [1.0], [-1.0]],
            Q=np.eye(2), R=[[1.0]], N=5, theta_hat0=[0.0, 0.0])

#: (case id, changed fields, expected message fragments)
MALFORMED = [
    ("A0 not square", dict(A0=[[0.5, 0.2, 0.1], [0.1, 0.2, 0.3]]), ["system.A0", "square"]),
    ("A0 NaN", dict(A0=[[math.nan, 0.2], [-0.1, 0.6]]), ["system.A0", "finite", "nan"]),
    ("A0 inf", dict(A0=[[math.inf, 0.2], [-0.1, 0.6]]), ["system.A0", "finite"]),
    ("A0 text", dict(A0="abc"), ["system.A0", "real numbers"]),
    ("B0 wrong rows", dict(B0=[[0.0], [0.5], [1.0]]), ["system.B0", "2 rows", "3 rows"]),
    ("A_i wrong shape", dict(A=[[[0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]]), ["system.A", "2x2"]),
    ("B count differs", dict(B=[[[0.0], [0.0]]]), ["system.B", "2 matrices", "1"]),
    ("parameter absent", dict(A=[[[0.0, 0.0], [0.0, 0.0]], [[0.015, 0.019], [0.009, 0.035]]],
                              B=[[[0.0], [0.0]], [[0.04], [0.054]]]), ["system.A[0]", "non-zero"]),
    ("W unbounded", dict(H_w=[[10.0, 0], [-10.0, 0], [0, 10.0]]), ["W.H", "bounded", "unbounded"]),
    ("W wrong columns", dict(H_w=[[10.0, 0, 0], [-10.0, 0, 0]]), ["W.H", "2 columns", "3 columns"]),
    ("Theta empty", dict(h_theta=[1.0, -2.0, 1.0, 1.0]), ["Theta.H", "non-empty"]),
    ("Theta unbounded", dict(H_theta=[[1.0, 0], [-1.0, 0], [0, 1.0]], h_theta=[1.0, 1.0, 1.0]), ["Theta.H", "bounded"]),
    ("Theta flat", dict(h_theta=[0.0, 0.0, 1.0, 1.0]), ["Theta.H", "interior"]),
    ("h_theta length", dict(h_theta=[1.0, 1.0, 1.0]), ["Theta.h", "length 4", "length 3"]),
    ("Q indefinite", dict(Q=[[1.0, 0.0], [0.0, -1.0]]), ["cost.Q", "positive definite", "-1"]),
    ("Q asymmetric", dict(Q=[[1.0, 0.5], [0.0, 1.0]]), ["cost.Q", "symmetric"]),
    ("R zero", dict(R=[[0.0]]), ["cost.R", "positive definite"]),
    ("N zero", dict(N=0), ["cost.N", ">= 1", "0"]),
    ("N float", dict(N=2.5), ["cost.N", "integer", "2.5"]),
    ("N bool", dict(N=True), ["cost.N", "integer"]),
    ("theta_hat0 outside", dict(theta_hat0=[2.0, 0.0]), ["theta_hat0", "Theta", "outside"]),
    ("theta_hat0 length", dict(theta_hat0=[0.0]), ["theta_hat0", "length 2", "length 1"]),
    ("G wrong rows", dict(G=[[0.0], [1.0]]), ["Z.G", "3 rows", "2 rows"]),
    ("Z zero row", dict(F=[[0.0, 0.0], [0, 0], [0, 0]]), ["Z.F, Z.G", "all-zero row", "row 0"]),
    ("empty name", dict(name=""), ["name", "non-empty string"]),
]


@pytest.mark.parametrize("case,changes,fragments", MALFORMED, ids=[c[0] for c in MALFORMED])
def test_malformed_problem_is_rejected_with_a_message_naming_the_field(case, changes, fragments):
    data = dict(GOOD)
    data.update(changes)
    with pytest.raises(ProblemError) as info:
        Problem(**data)
    message = str(info.value)
    for fragment in fragments:
        assert fragment.lower() in message.lower(), f"{case}: {fragment!r} not in {message!r}"
    assert isinstance(info.value, ValueError) and isinstance(info.value, AmcpError)
    assert info.value.field and info.value.expected and info.value.received


def test_the_good_problem_is_accepted_and_its_arrays_are_read_only():
    problem = Problem(**GOOD)
    assert (problem.n, problem.m, problem.p) == (2, 1, 2)
    with pytest.raises(ValueError):
        problem.A0[0, 0] = 1.0


def test_model_matrices_follow_eq_2():
    problem = Problem(**GOOD)
    theta = np.array([0.3, -0.7])
    expected_A = np.array(GOOD["A0"]) + 0.3 * np.array(GOOD["A"][0]) - 0.7 * np.array(GOOD["A"][1])
    expected_B = np.array(GOOD["B0"]) + 0.3 * np.array(GOOD["B"][0]) - 0.7 * np.array(GOOD["B"][1])
    np.testing.assert_allclose(problem.A_of(theta), expected_A)
    np.testing.assert_allclose(problem.B_of(theta), expected_B)
    x, u = np.array([1.0, -2.0]), np.array([0.5])
    # A(θ)x + B(θ)u = A0 x + B0 u + D(x,u) θ (the regressor, docs/explanation/paper.md §1)
    np.testing.assert_allclose(problem.regressor(x, u) @ theta,
                               expected_A @ x + expected_B @ u - (np.array(GOOD["A0"]) @ x + np.array(GOOD["B0"]) @ u))


SCENARIOS = [
    (dict(x0=[1.0]), "scenario.x0"),
    (dict(theta_star=[5.0, 0.0]), "scenario.theta_star"),
    (dict(disturbance="gaussian"), "scenario.disturbance"),
    (dict(steps=0), "scenario.steps"),
    # θ*_k sequences (Section 4.1): wrong length for steps, a row outside Θ (named by its index)
    (dict(steps=3, theta_star=[[0.1, 0.1]] * 6), "scenario.theta_star"),
    (dict(steps=2, theta_star=[[0.1, 0.1], [0.1, 0.1], [5.0, 0.1]]), r"scenario.theta_star\[2\]"),
    (dict(steps=2, theta_star=[[0.1, 0.1, 0.1]] * 3), "scenario.theta_star"),
]


@pytest.mark.parametrize("changes,field", SCENARIOS, ids=[s[1] + "-" + str(i) for i, s in enumerate(SCENARIOS)])
def test_malformed_scenario_is_rejected(changes, field):
    data = dict(x0=[1.0, 1.0], theta_star=[0.1, 0.1])
    data.update(changes)
    with pytest.raises(ProblemError, match=field.replace(".", r"\.")):
        Scenario(**data).validate_for(Problem(**GOOD))


def test_theta_star_sequence_is_accepted_and_cut_to_the_run_length():
    seq = [[0.1, 0.1], [0.1, 0.11], [0.1, 0.12], [0.1, 0.13]]
    sc = Scenario(x0=[1.0, 1.0], theta_star=seq, steps=3).validate_for(Problem(**GOOD))
    assert sc.time_varying and sc.theta_star.shape == (4, 2)
    assert sc.max_theta_rate() == pytest.approx(0.01)
    np.testing.assert_array_equal(sc.theta_star_for(2), np.array(seq[:3]))
    np.testing.assert_array_equal(sc.theta_star_for(3), np.array(seq))
    with pytest.raises(ProblemError, match="steps"):
        sc.theta_star_for(5)


def test_theta_star_sequence_faster_than_d_theta_is_rejected():
    """Assumption 17 in a problem spec: the file's online.d_theta must bound the sequence's steps."""
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.model.problem import ProblemSpec

    seq = [[0.1, 0.1], [0.1, 0.11], [0.1, 0.15]]
    sc = Scenario(x0=[1.0, 1.0], theta_star=seq, steps=2)
    with pytest.raises(ProblemError, match=r"scenario\.theta_star.*d_theta = 0\.01.*0\.04"):
        ProblemSpec(Problem(**GOOD), scenario=sc, online=OnlineOptions(d_theta=0.01))
    ProblemSpec(Problem(**GOOD), scenario=Scenario(x0=[1.0, 1.0], theta_star=seq, steps=2),
                online=OnlineOptions(d_theta=0.04))


DESIGNS = [
    (dict(x0_facets=3), "design.x0_facets"),
    (dict(mu_fraction=1.0), "design.mu_fraction"),
    (dict(mu_state_bound=-1.0), "design.mu_state_bound"),
    (dict(K=[[1.0, 2.0, 3.0]]), "design.K"),
    (dict(centre_dynamics="magic"), "design.centre_dynamics"),
]


@pytest.mark.parametrize("changes,field", DESIGNS, ids=[d[1] + "-" + str(i) for i, d in enumerate(DESIGNS)])
def test_malformed_design_options_are_rejected(changes, field):
    with pytest.raises(ProblemError, match=field.replace(".", r"\.")):
        DesignOptions(**changes).validate_for(Problem(**GOOD))


def test_scalar_reference_problem_is_valid():
    problem = scalar_problem()
    assert (problem.n, problem.m, problem.p) == (1, 1, 1)
