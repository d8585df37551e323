"""The Drake plain form (15) without the rows of (15c) implied by others on Θ0.

``backends/dominated_rows.py`` leaves out row (l, j, i) when another vertex j' of X0 has
g_{ij'}(θ) = [H_x]_i A_cl(θ) x^{j'} >= g_{ij}(θ) on all of Θ0; the multipliers of the rows left out
are recorded from their own LPs (``multiplier_basis.optimal_multipliers``). Checked here against
independent computations: scipy LPs for the rows' maxima over Θ_k, the program with every row
(``prune=False``) and numpy residuals of (15c), (15d) and Λ >= 0 on every row.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import linprog

from amcp_drake.backends import TubeMPCData
from amcp_drake.backends.dominated_rows import kept_vertices
from amcp_drake.backends.drake_solver import DrakeSolver
from amcp_drake.backends.drake_tube import DrakeTubeMPC
from amcp_drake.backends.vertex_form import theta_vertices
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answer_checks

TIGHT = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
#: v agreement of two solves of the same QP at TIGHT tolerances (as tests/test_formulations.py)
AGREE_TOL = 1e-6


def tube_data(problem, d) -> TubeMPCData:
    return TubeMPCData(A0=problem.A0, B0=problem.B0, A=problem.A, B=problem.B, F=problem.F, G=problem.G, Q=problem.Q,
                       R=problem.R, N=problem.N, K=d.K, P=d.P, H_x=d.H_x, X0_vertices=d.X0_vertices, w_bar=d.w_bar,
                       f_bar=d.f_bar, H_T=d.H_T, h_T=d.h_T, H_theta=d.H_theta, h_theta0=d.h_theta0)


@pytest.fixture(scope="module")
def example(example_spec, example_design):
    data = tube_data(example_spec.problem, example_design)
    pruned = DrakeTubeMPC(data, DrakeSolver("clarabel", TIGHT))
    every = DrakeTubeMPC(data, DrakeSolver("clarabel", TIGHT), prune=False)
    return example_spec, example_design, data, pruned, every


def random_sub_box_offsets(rng, d) -> np.ndarray:
    """Offsets (in Θ0's rows) of a random box inside Θ0 (Example 1: Θ0 is a box)."""
    V = theta_vertices(d.H_theta, d.h_theta0)
    lo, hi = V.min(axis=0), V.max(axis=0)
    centre = rng.uniform(lo, hi)
    radius = rng.uniform(0.02, 1.0, size=len(lo)) * (hi - lo) / 2
    a, b = np.maximum(lo, centre - radius), np.minimum(hi, centre + radius)
    corners = np.array(np.meshgrid(*zip(a, b), indexing="ij")).reshape(len(lo), -1).T
    return np.max(corners @ np.asarray(d.H_theta).T, axis=0)


def test_example_1_keeps_one_vertex_per_facet(example):
    spec, d, data, pruned, every = example
    pr = spec.problem
    keep = kept_vertices(d.H_x, pr.A0 + pr.B0 @ d.K, pr.A + pr.B @ d.K, d.X0_vertices,
                         theta_vertices(d.H_theta, d.h_theta0))
    assert keep.shape == (8, 8) and keep.sum(axis=1).tolist() == [1] * 8
    u, nv, q, p = 8, 8, len(d.H_theta), pr.p
    assert every.prog.num_vars() - pruned.prog.num_vars() == pr.N * (u * nv - 8) * (q - p)


@pytest.mark.parametrize("seed", range(4))
def test_the_rows_left_out_are_implied_on_random_subsets_of_theta0(example, seed):
    """For random (z_l, α_l >= 0, v_l) and random boxes Θ_k ⊆ Θ0: per facet i, the largest of the
    row maxima max_{θ∈Θ_k} [H_x]_i (A_cl(θ)(z_l + α_l x^j) + B(θ) v_l) over all vertices j (scipy,
    one LP per row) is reached by a kept j."""
    spec, d, *_ = example
    pr = spec.problem
    rng = np.random.default_rng(seed)
    keep = kept_vertices(d.H_x, pr.A0 + pr.B0 @ d.K, pr.A + pr.B @ d.K, d.X0_vertices,
                         theta_vertices(d.H_theta, d.h_theta0))
    H_th = np.asarray(d.H_theta)
    for _ in range(5):
        h = random_sub_box_offsets(rng, d)
        z, alpha, v = rng.normal(size=pr.n), rng.uniform(0.0, 2.0), rng.normal(size=pr.m)
        for i, row in enumerate(np.asarray(d.H_x)):
            values = []
            for xj in np.asarray(d.X0_vertices):
                point = z + alpha * xj
                # affine in θ: [H_x]_i (A_cl0 point + B0 v) + Σ_r θ_r [H_x]_i (A_cl,r point + B_r v)
                grad = np.array([row @ ((pr.A[r] + pr.B[r] @ d.K) @ point + pr.B[r] @ v) for r in range(pr.p)])
                const = row @ ((pr.A0 + pr.B0 @ d.K) @ point + pr.B0 @ v)
                lp = linprog(-grad, A_ub=H_th, b_ub=h, bounds=[(None, None)] * pr.p, method="highs")
                values.append(const - lp.fun)
            values = np.array(values)
            assert values[keep[i]].max() >= values.max() - 1e-9


def _residuals_every_row(sol, data, h, H_theta) -> tuple[float, float, float]:
    """(max (15c) violation, max |(15d) residual|, min Λ) over every row (l, j, i), numpy."""
    K, H_x, Xv = np.asarray(data.K), np.asarray(data.H_x), np.asarray(data.X0_vertices)
    Acl0 = data.A0 + data.B0 @ K
    Acl = data.A + data.B @ K
    worst15c, worst15d = -np.inf, 0.0
    for l in range(data.N):
        for j, xj in enumerate(Xv):
            point = sol.z[l] + sol.alpha[l] * xj
            d_lj = Acl0 @ point + data.B0 @ sol.v[l] - sol.z[l + 1]
            D_lj = np.stack([Acl[r] @ point + data.B[r] @ sol.v[l] for r in range(len(data.A))], axis=1)
            lam = sol.Lambda[l, j]                                                   # (u, q)
            worst15c = max(worst15c, float(np.max(lam @ h + H_x @ d_lj - sol.alpha[l + 1] + data.w_bar)))
            worst15d = max(worst15d, float(np.max(np.abs(H_x @ D_lj - lam @ H_theta))))
    return worst15c, worst15d, float(sol.Lambda.min())


@pytest.mark.parametrize("seed", range(3))
def test_pruned_and_every_row_programs_agree_and_every_multiplier_is_recorded(example, seed):
    """Random Θ_k ⊆ Θ0 one after the other on the same program (its cache of Θ_k's bases is keyed
    by the bits of h_θ: a stale entry would give the left-out rows wrong multipliers)."""
    spec, d, data, pruned, every = example
    rng = np.random.default_rng(10 + seed)
    theta_hat = np.asarray(spec.problem.theta_hat0, float)
    solved = 0
    for _ in range(10):
        h = random_sub_box_offsets(rng, d)
        angle = rng.uniform(0, 2 * np.pi)
        x = rng.uniform(0.2, 2.0) * np.array([np.cos(angle), np.sin(angle)])
        a, b = pruned.solve(x, h, theta_hat), every.solve(x, h, theta_hat)
        assert a.status is b.status
        if a.status is not SolveStatus.OPTIMAL:
            continue
        solved += 1
        assert float(np.max(np.abs(a.v - b.v))) <= AGREE_TOL
        assert a.Lambda.shape == b.Lambda.shape == (data.N, len(d.X0_vertices), len(d.H_x), len(d.H_theta))
        c15, d15, lam_min = _residuals_every_row(a, data, h, np.asarray(d.H_theta))
        assert c15 <= 1e-7 and d15 <= 1e-9 and lam_min >= -1e-9
        checks = answer_checks.check_tube(a, data, x, h)
        assert not answer_checks.failures(checks)
    assert solved >= 4


def _every_row_solves(monkeypatch) -> list:
    """Every solve that the reduced program hands to the program with every row of (15c), with its reason."""
    import amcp_drake.backends.drake_tube as drake_tube

    calls: list = []
    real = drake_tube.DrakeTubeMPC._with_every_row

    def spy(self, *args, **kwargs):
        calls.append(args[-1] if args else kwargs.get("why"))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(drake_tube.DrakeTubeMPC, "_with_every_row", spy)
    return calls


def test_a_theta_k_outside_theta0_is_solved_with_every_row(example, monkeypatch):
    spec, d, data, pruned, every = example
    h = np.asarray(d.h_theta0, float) * 1.2  # Θ_k ⊋ Θ0: the dominance shown on Θ0 does not apply
    theta_hat = np.asarray(spec.problem.theta_hat0, float)
    x = np.array([1.0, 0.5])
    handed = _every_row_solves(monkeypatch)
    a = pruned.solve(x, h, theta_hat)
    assert len(handed) == 1       # the dominance shown on Θ0 is not used outside it
    b = every.solve(x, h, theta_hat)
    assert a.status is SolveStatus.OPTIMAL and float(np.max(np.abs(a.v - b.v))) <= 1e-9


def test_no_multipliers_for_the_rows_left_out_solves_with_every_row(example, monkeypatch):
    import amcp_drake.backends.drake_tube as drake_tube

    spec, d, data, _, every = example
    pruned = DrakeTubeMPC(data, DrakeSolver("clarabel", TIGHT))
    monkeypatch.setattr(drake_tube, "optimal_multipliers", lambda *args: None)
    theta_hat = np.asarray(spec.problem.theta_hat0, float)
    x = np.array([1.0, 0.5])
    handed = _every_row_solves(monkeypatch)
    a = pruned.solve(x, d.h_theta0, theta_hat)
    assert len(handed) == 1       # no multipliers for the rows left out: the program with every row answers
    b = every.solve(x, d.h_theta0, theta_hat)
    assert a.status is SolveStatus.OPTIMAL
    assert float(np.max(np.abs(a.v - b.v))) <= 1e-9
    assert a.Lambda.shape == b.Lambda.shape


def test_without_theta0_every_row_is_built(example):
    spec, d, data, pruned, every = example
    plain = DrakeTubeMPC(dataclasses.replace(data, h_theta0=None), DrakeSolver("clarabel", TIGHT))
    assert plain.prog.num_vars() == every.prog.num_vars() > pruned.prog.num_vars()


def test_the_bases_of_theta_k_follow_its_offsets(example):
    """With a cut in Θ's shape the feasible bases of Θ_k change with h_θ (for a box they do not):
    the program's cache returns the bases of the offsets asked for, and the left-out rows'
    multipliers stay right after Θ_k changes."""
    from amcp_drake.backends.multiplier_basis import feasible_bases

    spec, d, data, *_ = example
    cut = np.array([[1.0, 1.0, 0.0]]) / np.sqrt(2.0)
    H = np.vstack([d.H_theta, cut])
    h0 = np.concatenate([d.h_theta0, [10.0]])                      # the cut is redundant on Θ0
    shaped = dataclasses.replace(data, H_theta=H, h_theta0=h0)
    qp = DrakeTubeMPC(shaped, DrakeSolver("clarabel", TIGHT))
    assert len(qp._left_out)
    theta_hat = np.zeros(3)
    x = np.array([0.5, 0.5])
    for h_cut in (10.0, 0.1, 10.0):                                 # inactive, cutting a corner, inactive
        h = np.concatenate([d.h_theta0, [h_cut]])
        expected = feasible_bases(H, h)
        got = qp._bases_of(h)
        assert sorted(map(tuple, got.rows)) == sorted(map(tuple, expected.rows))
        sol = qp.solve(x, h, theta_hat)
        assert sol.status is SolveStatus.OPTIMAL
        c15, d15, lam_min = _residuals_every_row(sol, shaped, h, H)
        assert c15 <= 1e-7 and d15 <= 1e-9 and lam_min >= -1e-9


def _dominance_by_pairs(points: np.ndarray) -> np.ndarray:
    """Points (v, S) that no other point dominates, by comparing every pair (the definition)."""
    keep = np.ones(len(points), dtype=bool)
    for j in range(len(points)):
        for k in range(len(points)):
            if k != j and np.all(points[k] >= points[j]) and (np.any(points[k] > points[j]) or k < j):
                keep[j] = False
                break
    return keep


@pytest.mark.parametrize("seed", range(4))
def test_the_kept_vertices_are_those_no_other_dominates(seed):
    """kept_vertices visits the vertices by decreasing sum and compares each with those kept so far and
    with those of equal sum: the same mask as comparing every pair, on random facets with ties (equal
    rows, coordinates on a grid) and without."""
    from amcp_drake.backends.dominated_rows import _maximal

    rng = np.random.default_rng(seed)
    for trial in range(60):
        v, S = int(rng.integers(1, 40)), int(rng.integers(1, 6))
        if trial % 2:
            points = rng.integers(-2, 3, (v, S)).astype(float)
        else:
            points = rng.standard_normal((v, S)) @ rng.standard_normal((S, S))
        if trial % 3 == 0 and v > 2:
            points[1] = points[0]
            points[-1] = points[0]
        assert np.array_equal(_maximal(points), _dominance_by_pairs(points)), (seed, trial)
