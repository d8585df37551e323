"""The Assumption 11 check of verify_design ("X_f invariant", "X_f in Z") on designs with many vertices.

Its margins are compared with a literal enumeration written here (every vertex (z, α) of X_f, every
vertex A_k of A_cl(Θ), every vertex x_j of X0 and w of W, as Assumption 11 reads), on Example 1 and on
tampered copies of its design that fail each claim; and its cost on an X0 with a thousand vertices is
bounded: the check needs (vertices of X_f) × (vertices of Θ) × rows work, not that product times the
vertices of X0 (a generated 6-state design with 3,975 vertices of X0 and 3,976 of X_f took minutes).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.model import polytope
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.result import closed_loop_vertices


def _brute_force(problem, d):
    """(invariance margin, constraint margin) of Assumption 11 by enumerating every combination."""
    theta_v = polytope.vertices(problem.H_theta, problem.h_theta)
    A_cl = closed_loop_vertices(problem, d.K, theta_v)
    X0_v = polytope.vertices(d.H_x, np.ones(len(d.H_x)))
    W_v = problem.w_vertices()
    n = problem.n
    H = np.vstack([np.column_stack([d.H_T, d.h_T]), np.r_[np.zeros(n), -1.0]])
    verts = polytope.vertices(H, np.r_[np.ones(len(d.H_T)), 0.0])
    FGK = problem.F + problem.G @ d.K
    inv = con = np.inf
    for vert in verts:
        z, alpha = vert[:n], vert[n]
        z_next = d.A_z @ z
        # α⁺ = φ(z, α): the least α with A_k({z} ⊕ αX0) ⊕ W ⊆ {z⁺} ⊕ α⁺X0 for all k
        alpha_next = max(float(np.max(d.H_x @ (Ak @ (z + alpha * x) + w - z_next)))
                         for Ak in A_cl for x in X0_v for w in W_v)
        member = min(1.0 - float(np.max(d.H_T @ z_next + d.h_T * alpha_next)), alpha_next)
        inv = min(inv, member, 0.0)  # the inclusion holds with margin 0 for this α⁺ (its definition)
        con = min(con, min(1.0 - float(np.max(FGK @ (z + alpha * x))) for x in X0_v))
    return inv, con


TAMPERED = {
    "as designed": {},
    "X_f twice as large": {"H_T": 0.5, "h_T": 0.5},
    "X_f with a small alpha bound": {"h_T": 0.3},
    "another gain": {"K": 1.3},
    "another centre dynamics": {"A_z": 1.2},
    "X_f half as large": {"H_T": 2.0},
}


@pytest.mark.parametrize("name", TAMPERED)
def test_assumption_11_margins_equal_the_literal_enumeration(example_spec, example_design, name):
    d = replace(example_design, **{k: f * getattr(example_design, k) for k, f in TAMPERED[name].items()})
    inv, con = _brute_force(example_spec.problem, d)
    checks = {c.name: c for c in verify_design(example_spec.problem, d, example_spec.design.mu_state_bound)}
    assert checks["X_f invariant"].margin == pytest.approx(inv, abs=1e-12)
    assert checks["X_f in Z"].margin == pytest.approx(con, abs=1e-12)
    assert checks["X_f invariant"].passed == (inv >= -1e-8)
    assert checks["X_f in Z"].passed == (con >= -1e-8)


def test_the_tampered_designs_fail_each_claim(example_spec, example_design):
    """The comparison above covers failing claims too (margins well below zero)."""
    margins = {name: _brute_force(example_spec.problem, replace(
        example_design, **{k: f * getattr(example_design, k) for k, f in changes.items()}))
        for name, changes in TAMPERED.items()}
    assert margins["as designed"][0] > -1e-8 and margins["as designed"][1] > -1e-8
    assert margins["another centre dynamics"][0] < -0.1
    assert margins["X_f half as large"][1] < -0.1


#: Vertices of the X0 polygon of the cost test, and the lines of amcp_drake/offline/checks.py its check may
#: execute (a count, not a time: the same on every machine). The enumeration over the X0 vertices inside the
#: loop over the X_f vertices executes at least (vertices of X_f) x (vertices of X0) = 10^6 lines (it had
#: not ended after 200 s of CPU); the separated check executes a few hundred, whatever the vertex counts.
POLYGON_VERTICES = 1000
CHECK_LINES = 10_000


def _lines_executed_in(path: str, run) -> int:
    """Lines of the source file ``path`` executed while ``run()`` runs (sys.settrace; other files untraced)."""
    import sys

    count = 0

    def local(frame, event, arg):
        nonlocal count
        count += event == "line"
        return local

    def tracer(frame, event, arg):
        return local if frame.f_code.co_filename == path else None

    previous = sys.gettrace()
    sys.settrace(tracer)
    try:
        run()
    finally:
        sys.settrace(previous)
    return count


def test_assumption_11_check_cost_does_not_multiply_the_vertex_counts(example_spec, example_design):
    from amcp_drake.offline import checks as checks_module

    angles = 2 * np.pi * np.arange(POLYGON_VERTICES) / POLYGON_VERTICES
    H_x = np.column_stack([np.cos(angles), np.sin(angles)]) / 0.5  # a 1000-gon around the disc of radius 0.5
    X0_v = polytope.vertices(H_x, np.ones(len(H_x)))
    pr = example_spec.problem
    d = replace(example_design, H_x=H_x, X0_vertices=X0_v, H_T=2.0 * H_x, h_T=np.full(len(H_x), 0.5),
                w_bar=np.max(H_x @ pr.w_vertices().T, axis=1),
                f_bar=np.max((pr.F + pr.G @ example_design.K) @ X0_v.T, axis=1))
    found: dict = {}

    def run():
        found.update({c.name: c for c in verify_design(example_spec.problem, d, example_spec.design.mu_state_bound)})

    lines = _lines_executed_in(checks_module.__file__, run)
    checks = found
    assert "vertices of X_f" in checks["X_f invariant"].detail
    assert int(checks["X_f invariant"].detail.split()[0]) == POLYGON_VERTICES + 1  # the cone's apex and the base
    assert np.isfinite(checks["X_f invariant"].margin) and np.isfinite(checks["X_f in Z"].margin)
    assert lines < CHECK_LINES, f"the design checks executed {lines} lines of checks.py"


def test_the_line_count_sees_a_loop_over_the_vertices():
    """The measure can fail: a loop of 1000 x 10 iterations in a traced file executes >= 10^4 lines."""
    def loop():
        total = 0
        for i in range(1000):
            for j in range(10):
                total += i * j
        return total

    assert _lines_executed_in(__file__, loop) >= 10_000 > CHECK_LINES - 1
