"""The property suite's Lemma 3 check when the left side of (10) is judged empty: θ* lies in Θ_k and in
every Δ_j (Assumption 1), so a point that violates every unit row by at most v bounds the signed
Chebyshev radius from below by −v. HiGHS's primal tolerance (1e-7) is the size of the claim's
tolerance, so its "empty" alone does not decide the claim."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("amcp_properties")
from amcp_drake.model import polytope  # noqa: E402
from amcp_drake.online.simulate import Trajectory  # noqa: E402
from amcp_properties import claims  # noqa: E402
from amcp_properties.geometry import delta_set, signed_chebyshev_radius, unit_rows  # noqa: E402

SET_TOL = 1e-7  # the documented tolerance of the property's (10), written here


def _interval(gap: float) -> tuple[np.ndarray, np.ndarray]:
    """{θ <= 0, −θ <= −gap}: empty by ``gap`` for gap > 0 (signed radius −gap/2)."""
    return np.array([[1.0], [-1.0]]), np.array([0.0, -gap])


@pytest.mark.parametrize("factor, passes", [(2.0, False), (0.5, True)])
def test_the_witness_bound_at_the_tolerance_edge(factor, passes):
    """A witness at the middle of the gap violates both rows by gap/2, the LP's radius is −gap/2: the
    margin is −gap/2, judged at ±SET_TOL (2× outside fails, 0.5× inside passes)."""
    gap = 2 * factor * SET_TOL
    H, h = _interval(gap)
    radius = claims._signed_radius_with_witness(H, h, np.array([gap / 2]))
    assert radius == pytest.approx(-factor * SET_TOL, rel=1e-9)
    assert (radius >= -SET_TOL) is passes


def test_a_worse_witness_never_lowers_the_lp_radius():
    H, h = _interval(1e-3)
    assert claims._signed_radius_with_witness(H, h, np.array([5.0])) == pytest.approx(-5e-4, rel=1e-9)


def test_a_better_witness_raises_a_radius_the_lp_got_wrong():
    """The LP's radius of a set that contains the witness is replaced by the witness's slack (≥ 0)."""
    H, h = np.array([[1.0], [-1.0]]), np.array([1.0, 1.0])
    assert claims._signed_radius_with_witness(H, h, np.array([0.25])) == pytest.approx(1.0, rel=1e-9)
    inside = claims._signed_radius_with_witness(H, h, np.array([0.9]))
    assert inside == pytest.approx(1.0, rel=1e-9)  # the LP's optimum, larger than the witness's 0.1


def test_the_recorded_window_run_passes_lemma3_where_the_lp_alone_says_empty():
    """A generated Drake run (n = 1, p = 2, moving window M = 5, θ* on a facet of Θ, disturbances at
    vertices of W): at step 13 HiGHS finds Θ_12 ∩ Δ_13 ∩ … ∩ Δ_9 empty by 1.08e-7, while θ* violates
    its rows by at most 5.4e-13."""
    traj = Trajectory.load(Path(__file__).parent / "data" / "lemma3-window-witness-trajectory.json.gz")
    assert traj.options.update == "window" and traj.options.window == 5
    pr, k = traj.problem, 12
    rows_H, rows_h = [], []
    Ha, ha = unit_rows(traj.records[k].H_theta, traj.records[k].h_theta)
    rows_H.append(Ha)
    rows_h.append(ha)
    for j in range(k, k - 5, -1):
        Hd, hd = delta_set(pr, traj.x[j], traj.u[j], traj.x[j + 1])
        rows_H.append(Hd)
        rows_h.append(hd)
    H, h = polytope.normalize_rows(np.vstack(rows_H), np.concatenate(rows_h))
    violation = float(np.max(H @ traj.theta_star - h))
    assert violation < 1e-12
    lp = signed_chebyshev_radius(H, h)
    assert lp < -SET_TOL  # the case this test is about (else the recorded data lost it)
    result = claims.set_inclusions(traj)
    assert result.passed, result.detail
    assert "empty" not in result.detail and result.margin >= -1e-9  # another step's round-off: -6.5e-10

