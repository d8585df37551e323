"""Shared fixtures: Example 1 (docs/explanation/paper.md §9), its design and a closed-loop run, computed once per
session."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.model.examples import lorenzen2019_spec


@pytest.fixture(scope="session")
def example_spec():
    return lorenzen2019_spec()


@pytest.fixture(scope="session")
def example_design(example_spec):
    from amcp_drake.offline.design import design

    return design(example_spec.problem, example_spec.design, backend="drake")


def _example_1_run(spec, offline, backend: str):
    """Example 1, 50 steps from x0 = [2, 3], uniform disturbance (seed 0), on ``backend``."""
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    sc = spec.scenario
    ctrl = AdaptiveMPC(spec.problem, offline, backend=backend)
    return simulate(ctrl, sc.x0, sc.theta_star, 50, "uniform", seed=0, mu_state_bound=spec.design.mu_state_bound)


@pytest.fixture(scope="session")
def example_run(example_spec, example_design):
    """Example 1, 50 steps from x0 = [2, 3], uniform disturbance (seed 0), Drake backend."""
    return _example_1_run(example_spec, example_design, "drake")


@pytest.fixture(scope="session")
def example_run_cvxpy(example_spec, example_design):
    """The run of ``example_run`` (Example 1, 50 steps, seed 0) with the cvxpy backend."""
    return _example_1_run(example_spec, example_design, "cvxpy")


def scalar_problem(**changes):
    """A scalar system x+ = (0.5 + 0.2 θ) x + u + w, θ ∈ [-1, 1], |w| <= 0.1, |x| <= 5, |u| <= 2."""
    from amcp_drake.model.problem import Problem

    data = dict(A0=[[0.5]], B0=[[1.0]], A=[[[0.2]]], B=[[[0.0]]], H_w=[[10.0], [-10.0]],
                H_theta=[[1.0], [-1.0]], h_theta=[1.0, 1.0], F=[[0.2], [-0.2], [0.0], [0.0]],
                G=[[0.0], [0.0], [0.5], [-0.5]], Q=[[1.0]], R=[[1.0]], N=3, theta_hat0=[0.0], name="scalar")
    data.update(changes)
    return Problem(**data)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
