"""The condensed cost (17)-(18) shared by the Drake formulations and the fast path
(amcp_drake/backends/condensed_cost.py): vᵀHv + 2gᵀv + c equals J_N rolled out step by step in
plain numpy (amcp_reference.nominal_cost, written independently) on random data."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.backends.condensed_cost import CondensedCost
from amcp_reference.nominal_cost import nominal_cost


@pytest.mark.parametrize("seed", range(6))
def test_condensed_cost_equals_the_rolled_out_cost(example_design, example_spec, seed):
    from amcp_drake.online.controller import AdaptiveMPC

    rng = np.random.default_rng(seed)
    data = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="vertex").data
    model = CondensedCost(data)
    N, m = int(data.N), np.shape(data.B0)[1]
    for _ in range(5):
        x = rng.normal(scale=2.0, size=np.shape(data.B0)[0])
        theta = rng.uniform(-1.0, 1.0, size=np.shape(data.A)[0])
        v = rng.normal(size=(N, m))
        H, g, c = model.matrices(x, theta)
        assert np.allclose(H, H.T) and np.all(np.linalg.eigvalsh(H) > 0)
        J = float(v.reshape(-1) @ H @ v.reshape(-1) + 2 * g @ v.reshape(-1) + c)
        assert J == pytest.approx(nominal_cost(data, x, theta, v), rel=1e-12, abs=1e-12)


@pytest.mark.parametrize("n, m, p, N", [(1, 1, 1, 1), (2, 2, 3, 2), (3, 1, 2, 3), (3, 2, 4, 7), (2, 1, 3, 16)])
def test_condensed_cost_other_dimensions(n, m, p, N):
    """The same on random systems of other sizes and horizons."""
    from amcp_drake.backends.base import TubeMPCData

    rng = np.random.default_rng(100 * n + 10 * m + N)
    sym = lambda k: (lambda M: M @ M.T + 0.1 * np.eye(k))(rng.normal(size=(k, k)))  # noqa: E731
    base = TubeMPCData(A0=0.5 * rng.normal(size=(n, n)), B0=rng.normal(size=(n, m)), A=0.1 * rng.normal(size=(p, n, n)),
                       B=0.1 * rng.normal(size=(p, n, m)), F=np.zeros((1, n)), G=np.zeros((1, m)), Q=sym(n), R=sym(m),
                       N=N, K=0.2 * rng.normal(size=(m, n)), P=sym(n), H_x=np.zeros((1, n)), X0_vertices=np.zeros((1, n)),
                       w_bar=np.zeros(1), f_bar=np.zeros(1), H_T=np.zeros((1, n)), h_T=np.zeros(1),
                       H_theta=np.zeros((1, p)))
    model = CondensedCost(base)
    for _ in range(3):
        x, theta, v = rng.normal(size=n), rng.uniform(-1.0, 1.0, size=p), rng.normal(size=(N, m))
        H, g, c = model.matrices(x, theta)
        J = float(v.reshape(-1) @ H @ v.reshape(-1) + 2 * g @ v.reshape(-1) + c)
        assert J == pytest.approx(nominal_cost(base, x, theta, v), rel=1e-10, abs=1e-10)


def test_buffers_written_in_place_carry_nothing_between_calls(example_design, example_spec):
    """The powers, W and G are buffers rewritten by every call: alternating θ̂ gives, to the
    bit, what a fresh model gives for each θ̂, and an answer already returned is not changed by a later
    call (the returned H, g, c are never views of the buffers)."""
    from amcp_drake.online.controller import AdaptiveMPC

    data = AdaptiveMPC(example_spec.problem, example_design, backend="drake", formulation="vertex").data
    rng = np.random.default_rng(7)
    x = rng.normal(size=np.shape(data.B0)[0])
    thetas = [rng.uniform(-1.0, 1.0, size=np.shape(data.A)[0]) for _ in range(3)]
    fresh = [CondensedCost(data).matrices(x, theta) for theta in thetas]
    model = CondensedCost(data)
    kept = []
    for i in (0, 1, 2, 0, 2, 1):
        H, g, c = model.matrices(x, thetas[i])
        kept.append((i, H, g, c, H.copy(), g.copy()))
        assert H.tobytes() == fresh[i][0].tobytes() and g.tobytes() == fresh[i][1].tobytes() and c == fresh[i][2]
    for i, H, g, c, H_then, g_then in kept:
        assert H.tobytes() == H_then.tobytes() and g.tobytes() == g_then.tobytes()
