"""The projection QP of (12) on degenerate and lower-dimensional sets, both backends.

Expected points come from :func:`exact_projection`, a brute-force active-set enumeration in numpy
written here (independent of both backends and of ``backends.projection_form``).
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).parent / "data"
BACKENDS = ("drake", "cvxpy")
#: The backends solve the scaled QP at 1e-10 and pass flat slabs (width <= 1e-8) as their mid-plane,
#: which moves the optimum by <= 5e-9: 1e-8 is the accuracy we promise (docs/decisions.md).
POINT_TOL = 1e-8
#: A returned point may violate a row by the solver's feasibility tolerance (1e-10) times the scale.
MEMBERSHIP_TOL = 1e-9


def exact_projection(point: np.ndarray, H: np.ndarray, h: np.ndarray, feas_tol: float = 1e-12) -> np.ndarray:
    """argmin{‖θ − point‖ | H θ <= h} by enumerating every active set of at most p rows: the optimum is
    the projection of ``point`` onto the affine set of its active rows (a face), so it is the nearest
    feasible one of those projections."""
    p = H.shape[1]
    best, best_dist = None, np.inf
    for size in range(p + 1):
        for rows in itertools.combinations(range(len(h)), size):
            if size == 0:
                cand = point.copy()
            else:
                A, b = H[list(rows)], h[list(rows)]
                lam = np.linalg.lstsq(A @ A.T, A @ point - b, rcond=None)[0]
                cand = point - A.T @ lam
            if np.max(H @ cand - h) <= feas_tol * (1.0 + np.max(np.abs(h))):
                dist = float(np.linalg.norm(cand - point))
                if dist < best_dist:
                    best, best_dist = cand, dist
    assert best is not None, "the reference found no feasible face (test data wrong)"
    return best


def _backend(name: str):
    from amcp_drake.backends import get_backend

    return get_backend(name)


@pytest.mark.parametrize("backend", BACKENDS)
def test_campaign_0_19_projection_onto_collapsed_theta_1(backend):
    """Campaign seed 0, problem 0-19: Θ_1 collapsed to a box of width ~3e-6 around θ* = [0.084, −1, −0.6]
    and θ̃_1 0.55 away. cvxpy ended "inaccurate" here (unscaled QP at 1e-11), and the controller then
    projected onto Θ instead: [0.1165, −0.4474, −0.6], 0.55 outside Θ_1."""
    case = json.loads((DATA / "campaign-0-19-projection.json").read_text())
    point, H, h = (np.asarray(case[k], float) for k in ("point", "H", "h"))
    result = _backend(backend).project(point, H, h)
    assert result.status.value == "optimal"
    assert np.max(H @ result.theta - h) <= MEMBERSHIP_TOL
    assert np.linalg.norm(result.theta - exact_projection(point, H, h)) <= POINT_TOL
    assert np.linalg.norm(result.theta - np.array([0.084, -1.0, -0.6])) < 1e-5


@pytest.mark.parametrize("backend", BACKENDS)
def test_campaign_0_13_point_outside_by_round_off(backend):
    """θ̃ = −1.2 outside Θ_k = [−1.2 + 1.5e-13, −0.79] by round-off only: scaled by the violation alone,
    the other offset became 3e12 and both backends ended "inaccurate" (SCALE_FLOOR keeps it <= 1e3)."""
    case = json.loads((DATA / "campaign-0-13-projection.json").read_text())
    point, H, h = (np.asarray(case[k], float) for k in ("point", "H", "h"))
    result = _backend(backend).project(point, H, h)
    assert result.status.value == "optimal"
    assert np.max(H @ result.theta - h) <= MEMBERSHIP_TOL
    assert np.linalg.norm(result.theta - exact_projection(point, H, h)) <= POINT_TOL


def _collapsed_box(rng, widths, extra_rows: int, touching: bool):
    """A box of the given widths around a random centre (rows ±e_i, as the fixed shape of (9) has), and
    ``extra_rows`` random unit rows through a vertex of it (touching) or 0.1 outside it."""
    p = len(widths)
    centre = rng.uniform(-1.0, 1.0, p)
    H = np.vstack([np.eye(p), -np.eye(p)])
    h = np.concatenate([centre + widths / 2, -centre + widths / 2])
    corners = np.array(list(itertools.product(*[(c - w / 2, c + w / 2) for c, w in zip(centre, widths)])))
    extra = rng.normal(size=(extra_rows, p))
    extra /= np.linalg.norm(extra, axis=1)[:, None]
    h_extra = np.max(extra @ corners.T, axis=1) + (0.0 if touching else 0.1)
    return np.vstack([H, extra]), np.concatenate([h, h_extra]), centre


#: width of the flat directions: exactly flat, flat up to round-off, thin, emptied by round-off
WIDTHS = (0.0, 1e-12, 1e-9, -1e-13)
SHAPES = ("point", "segment", "facet")


@pytest.mark.parametrize("width", WIDTHS)
@pytest.mark.parametrize("shape", SHAPES)
@pytest.mark.parametrize("backend", BACKENDS)
def test_projection_onto_lower_dimensional_sets(backend, shape, width):
    """Points, segments and flat facets (the Θ_k that vertex disturbances pin), with extra rows touching
    the set or not, θ̃ at distances 1e-6..10: optimal, in the set, and the exact projection."""
    be = _backend(backend)
    rng = np.random.default_rng([SHAPES.index(shape), WIDTHS.index(width)])
    flat = {"point": 3, "segment": 2, "facet": 1}[shape]
    failures = []
    for trial in range(8):
        widths = np.array([width] * flat + [0.4] * (3 - flat))
        H, h, centre = _collapsed_box(rng, widths, extra_rows=3, touching=bool(trial % 2))
        point = centre + rng.normal(size=3) * 10.0 ** rng.uniform(-6, 1)
        if np.all(H @ point <= h):
            continue
        expected = exact_projection(point, H, h)
        result = be.project(point, H, h)
        if result.status.value != "optimal":
            failures.append((trial, result.status.value))
            continue
        violation = float(np.max(H @ result.theta - h))
        error = float(np.linalg.norm(result.theta - expected))
        if violation > MEMBERSHIP_TOL + max(0.0, -width) or error > POINT_TOL:
            failures.append((trial, violation, error))
    assert not failures


# -- regression: campaign seed 0, problem 0-19 -------------------------------------------------------------------
@pytest.mark.parametrize("backend", BACKENDS)
def test_regression_campaign_0_19_closed_loop_certifies(backend):
    """`amcp campaign --systems 20 --seed 0` failed lms_update on 0-19 with cvxpy (margin −0.55 at step 1):
    the projection onto Θ_1 ended inaccurate and the controller silently projected onto Θ."""
    from amcp_drake.certificate.certify import certify
    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = load_spec(DATA / "campaign-0-19-problem.json")
    w = np.array(json.loads((DATA / "campaign-0-19-disturbances.json").read_text())["w"])
    ctrl = AdaptiveMPC(spec.problem, design(spec.problem, spec.design, backend="drake"), backend=backend,
                       options=spec.online)
    assert ctrl.options.projection == "Theta_k"
    traj = simulate(ctrl, spec.scenario.x0, spec.scenario.theta_star, len(w), w,
                    mu_state_bound=spec.design.mu_state_bound)
    assert traj.stop_reason == "completed"
    # every step answered (by its first solve or a checked fallback: which one is this machine's solvers' business)
    assert all(r.u is not None for r in traj.records)
    cert = certify(traj, spec)
    assert cert.claim("lms_update").status == "pass", cert.claim("lms_update").margin
    assert cert.verdict == "pass", [(c.name, c.margin) for c in cert.claims if c.status != "pass"]
