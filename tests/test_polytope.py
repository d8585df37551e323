"""Polytope helpers against values computed by hand."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.model import polytope


def test_vertices_of_a_box_are_its_corners():
    H, h = polytope.box([-1.0, -2.0], [3.0, 4.0])
    verts = polytope.vertices(H, h)
    expected = {(-1.0, -2.0), (-1.0, 4.0), (3.0, -2.0), (3.0, 4.0)}
    assert {tuple(np.round(v, 9)) for v in verts} == expected


def test_vertices_of_a_triangle_and_an_interval():
    H = np.array([[-1.0, 0.0], [0.0, -1.0], [1.0, 1.0]])
    h = np.array([0.0, 0.0, 1.0])
    assert {tuple(np.round(v, 9) + 0.0) for v in polytope.vertices(H, h)} == {(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)}
    np.testing.assert_allclose(sorted(polytope.vertices(np.array([[2.0], [-1.0]]), np.array([1.0, 3.0])).ravel()), [-3.0, 0.5])


def test_vertices_refuse_unbounded_and_empty_sets():
    with pytest.raises(ValueError):
        polytope.vertices(np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([1.0, 1.0]))
    with pytest.raises(ValueError):
        polytope.vertices(np.array([[1.0], [-1.0]]), np.array([-1.0, -1.0]))


def test_support_function_and_unbounded_direction():
    H, h = polytope.box([-1.0, -2.0], [3.0, 4.0])
    assert polytope.support(H, h, np.array([1.0, 1.0])).value == pytest.approx(7.0)
    assert polytope.support(H, h, np.array([-2.0, 0.5])).value == pytest.approx(4.0)
    half = polytope.support(np.array([[1.0, 0.0]]), np.array([1.0]), np.array([0.0, 1.0]))
    assert half.status == "unbounded" and half.value == np.inf


def test_boundedness():
    H, h = polytope.box([0.0], [1.0])
    assert polytope.is_bounded(H, h)
    assert not polytope.is_bounded(np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([1.0, 1.0]))


def test_chebyshev_centre_of_a_rectangle():
    H, h = polytope.box([0.0, 0.0], [4.0, 2.0])
    centre, radius = polytope.chebyshev_center(H, h)
    assert radius == pytest.approx(1.0)
    assert centre[1] == pytest.approx(1.0)
    assert 1.0 - 1e-9 <= centre[0] <= 3.0 + 1e-9
    _, empty = polytope.chebyshev_center(np.array([[1.0], [-1.0]]), np.array([-1.0, -1.0]))
    assert empty == -np.inf


def test_redundant_rows_are_removed_and_facets_kept():
    H = np.array([[1.0, 0], [-1.0, 0], [0, 1.0], [0, -1.0], [1.0, 1.0], [2.0, 0.0]])
    h = np.array([1.0, 1, 1, 1, 5.0, 2.0])  # x+y <= 5 is redundant, 2x <= 2 duplicates x <= 1
    Hr, hr = polytope.remove_redundant(H, h)
    assert len(hr) == 4
    rows = {tuple(np.round(np.r_[a, b], 9)) for a, b in zip(Hr, hr)}
    assert rows == {(1.0, 0.0, 1.0), (-1.0, 0.0, 1.0), (0.0, 1.0, 1.0), (0.0, -1.0, 1.0)}


def test_membership_margin():
    H, h = polytope.box([-1.0], [1.0])
    assert polytope.max_violation(H, h, np.array([0.25])) == pytest.approx(-0.75)
    assert polytope.contains(H, h, np.array([1.0]))
    assert not polytope.contains(H, h, np.array([1.001]))


def _exact_supports_2d(H, h, directions):
    """Supports of a bounded 2-D polytope in rational arithmetic: every pairwise intersection of
    rows, exactly, kept when it satisfies every row exactly (independent of any LP solver)."""
    import itertools
    from fractions import Fraction

    Hf = [[Fraction(x) for x in row] for row in H]
    hf = [Fraction(x) for x in h]
    vertices = []
    for i, j in itertools.combinations(range(len(hf)), 2):
        (a0, a1), (b0, b1) = Hf[i], Hf[j]
        det = a0 * b1 - a1 * b0
        if det == 0:
            continue
        x, y = (hf[i] * b1 - a1 * hf[j]) / det, (a0 * hf[j] - hf[i] * b0) / det
        if all(r0 * x + r1 * y <= c for (r0, r1), c in zip(Hf, hf)):
            vertices.append((x, y))
    return np.array([float(max(Fraction(d0) * x + Fraction(d1) * y for x, y in vertices)) for d0, d1 in directions])


def test_certified_support_of_a_thin_window_sliver_is_exact():
    """The moving-window LP on which HiGHS at its default tolerances answered 4.4e-5 too large
    (a generated lockstep case): the certified supports equal the rational answer."""
    import json
    from pathlib import Path

    data = json.loads((Path(__file__).parent / "data" / "window-sliver-lp.json").read_text())
    H, h, directions = np.array(data["H"]), np.array(data["h"]), np.array(data["directions"])
    exact = _exact_supports_2d(H, h, directions)
    found = polytope.support_certified(H, h, directions)
    assert found is not None
    np.testing.assert_allclose(found.values, exact, rtol=0, atol=1e-12)


def test_the_window_sliver_run_agrees_in_lockstep():
    """The recorded Drake run of that failure (40 steps, moving window 8), replayed step by step on
    the cvxpy backend: at step 9 its LP answer fails the dual-certificate check and the controller
    falls back to the certified HiGHS supports, which must now agree with Drake's h_θ."""
    from pathlib import Path
    from types import SimpleNamespace

    pytest.importorskip("amcp_properties")
    from amcp_drake.online.simulate import Trajectory
    from amcp_properties import lockstep

    traj = Trajectory.load(Path(__file__).parent / "data" / "window-sliver-trajectory.json.gz")
    assert traj.options.update == "window" and traj.backend == "drake"
    case = SimpleNamespace(problem=traj.problem, design=traj.design, options=traj.options)
    result = lockstep.backends_agree(traj, case, "cvxpy")
    assert result.passed, result.detail


def test_chebyshev_centre_when_highs_gives_no_answer_on_the_lp_as_written():
    """Example 1's terminal set in states x̃ = 1e-4 x (rows of size 1e4 next to the α column of size
    1): scipy's HiGHS ends the Chebyshev LP as written with status 4, on which a design check that
    trusts it raises a raw ValueError. The centre returned must be that of the LP solved independently
    (Clarabel through cvxpy), and its ball inside the set (numpy)."""
    import json
    from pathlib import Path

    import cvxpy as cp
    from scipy.optimize import linprog

    data = json.loads((Path(__file__).parent / "data" / "chebyshev-highs-status4.json").read_text())
    H, h = np.array(data["H"]), np.array(data["h"])
    norms = np.linalg.norm(H, axis=1)
    as_written = linprog(np.r_[np.zeros(3), -1.0], A_ub=np.hstack([H, norms[:, None]]), b_ub=h,
                         bounds=[(None, None)] * 4, method="highs")
    assert as_written.status == 4  # the case this test is about (else the recorded data lost it)
    centre, radius = polytope.chebyshev_center(H, h)
    x, r = cp.Variable(3), cp.Variable()
    cp.Problem(cp.Maximize(r), [(H / norms[:, None]) @ x + r <= h / norms]).solve(solver=cp.CLARABEL)
    assert radius == pytest.approx(float(r.value), rel=1e-6)
    assert np.all(H @ centre + radius * norms <= h + 1e-9)
    assert 1e-5 < radius < 1e-3
