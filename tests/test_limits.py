"""Resource limits (amcp_drake.model.limits): the size estimate against the QP Drake actually builds,
and the Qhull-based redundant-row removal against one LP per row (polytope.support, HiGHS)."""

from __future__ import annotations

import numpy as np
import pytest

from amcp_drake.model import polytope
from amcp_drake.model.limits import estimate_for, max_vertices, nonredundant_rows


def _implied_by_others(H: np.ndarray, h: np.ndarray, i: int, kept: np.ndarray) -> bool:
    """Reference: row i is implied by the kept rows when max{H_i x | kept rows} <= h_i (one LP)."""
    others = [j for j in kept if j != i]
    res = polytope.support(H[others], h[others], H[i])
    return res.status == "optimal" and res.value <= h[i] + 1e-7 * max(1.0, abs(h[i]))


@pytest.mark.parametrize("dim", [1, 2, 3, 4])
def test_nonredundant_rows_agree_with_one_lp_per_row(dim):
    """Random polytopes (a box, random cuts, duplicates and scaled copies): every removed row is
    implied by the kept ones (LP), and every kept row is not."""
    rng = np.random.default_rng(dim)
    for _ in range(5):
        H = np.vstack([np.eye(dim), -np.eye(dim), rng.normal(size=(30, dim))])
        h = np.concatenate([rng.uniform(0.5, 2.0, 2 * dim), rng.uniform(0.3, 3.0, 30)])
        H = np.vstack([H, H[:3], 2.0 * H[3:5]])  # duplicates and scaled duplicates
        h = np.concatenate([h, h[:3], 2.0 * h[3:5]])
        centre, radius = polytope.chebyshev_center(H, h)
        assert radius > 0
        kept = nonredundant_rows(H, h, centre)
        for i in range(len(H)):
            if i in kept:
                assert not _implied_by_others(H, h, i, kept), f"row {i} kept but implied"
            else:
                assert _implied_by_others(H, h, i, kept), f"row {i} removed but not implied"


def test_nonredundant_rows_of_an_unbounded_set_in_a_subspace():
    """Z of Example 1 lives in (x1, x2, u) but constrains only x2 and u (rows span 2 of 3
    dimensions); an extra row implied by the others is removed, the others kept."""
    FG = np.array([[0.0, -1 / 0.3, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.5], [0.0, -1.0, 0.0]])
    kept = nonredundant_rows(FG, np.ones(5), np.zeros(3))
    assert kept.tolist() == [0, 1, 2]


def test_the_estimate_counts_the_variables_and_rows_drake_builds(example_spec, example_design):
    """Example 1 (n = 2, m = 1, p = 3, 8 facets, 6 rows of Θ, 3 rows of Z), N = 4: the estimate's
    variables equal the decision vector of the Drake tube QP with every row of (15c) (q − p = 3
    multipliers per row, the other p solved from (15d)), and its rows bound the rows built
    (the terminal set is estimated by the rows of Z, so the difference is exactly that)."""
    from amcp_drake.backends.drake_tube import DrakeTubeMPC
    from amcp_drake.online.controller import AdaptiveMPC

    problem = example_spec.problem.with_changes(N=4)
    design = example_design
    ctrl = AdaptiveMPC(problem, design, backend="drake")
    prog = DrakeTubeMPC(ctrl.data, ctrl.mpc._solver, prune=False).prog
    est = estimate_for(problem, example_spec.design, steps=1)
    assert ctrl.mpc.prog.num_vars() < prog.num_vars()  # the default program leaves dominated rows out
    assert est.vertices == max_vertices(8, 2) == len(design.X0_vertices) == 8
    assert est.variables == prog.num_vars()
    linear_rows = sum(b.evaluator().num_constraints() for b in prog.linear_constraints()) \
        + sum(b.evaluator().num_constraints() for b in prog.linear_equality_constraints())
    terminal_rows = len(design.H_T)
    assert est.rows - len(problem.F) == linear_rows - terminal_rows


def test_upper_bound_theorem():
    """max_vertices is the cube's 8 for 6 facets in R^3 and the cyclic polytope's count in R^4."""
    assert max_vertices(6, 3) == 8
    assert max_vertices(8, 4) == 20  # C(6, 2) + C(5, 1)
    assert max_vertices(2, 1) == 2


# -- the run's size once the design is known ------------------------------------------------------
def _design_with(facets: int, vertices: int, theta_rows: int):
    """A stand-in for an OfflineDesign: only the sizes of X0 and of its H_θ enter the estimate."""
    from types import SimpleNamespace

    return SimpleNamespace(H_x=np.zeros((facets, 4)), X0_vertices=np.zeros((vertices, 4)),
                           H_theta=np.zeros((theta_rows, 3)))


def test_the_estimate_after_the_design_uses_the_designs_own_facets_and_vertices():
    """Tube block N·v·u counted from the design's X0, not from the upper bound theorem; before the
    design of an automatic n >= 4 problem the smallest candidate (parallelotope: 2n facets, 2^n
    vertices) is taken."""
    from amcp_drake.model.examples import get_example
    from amcp_drake.model.limits import estimate_run_size

    spec = get_example("ji2022_quadrotor")  # n = 4, no design section
    pr = spec.problem
    before = estimate_for(pr, spec.design, steps=50)
    assert (before.facets, before.vertices) == (8, 16)
    after = estimate_for(pr, spec.design, steps=50, design=_design_with(102, 318, len(pr.H_theta)))
    assert (after.facets, after.vertices) == (102, 318)
    by_hand = estimate_run_size(pr.n, pr.m, pr.p, int(pr.N), 102, len(pr.H_theta), len(pr.H_w), len(pr.F), steps=50,
                                vertices=318)
    assert after.memory_bytes == by_hand.memory_bytes
    # the plain form's multipliers alone: N·v·u·(q − p) variables
    assert after.variables >= int(pr.N) * 318 * 102 * (len(pr.H_theta) - pr.p)


@pytest.mark.parametrize("factor, refused", [(0.5, True), (2.0, False)])
def test_a_design_larger_than_the_memory_limit_is_refused_after_the_design(factor, refused):
    """The limit at half the design's estimate refuses the run (naming the design's X0 and the option);
    at twice it the run goes on."""
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.examples import get_example
    from amcp_drake.model.limits import check_run_size

    spec = get_example("ji2022_quadrotor")
    offline = _design_with(102, 318, len(spec.problem.H_theta))
    est = estimate_for(spec.problem, None, steps=50, design=offline)
    limit_mb = factor * est.memory_bytes / 2**20
    if refused:
        with pytest.raises(ProblemError, match=r"with the design found.*X0 facets = 102 \(318 vertices\).*--max-memory") as err:
            check_run_size(spec.problem, spec.design, 50, None, limit_mb, design=offline)
        assert "design.x0_facets" in str(err.value)  # what to change
    else:
        assert check_run_size(spec.problem, spec.design, 50, None, limit_mb, design=offline).memory_bytes \
            == est.memory_bytes


def test_one_size_check_before_and_after_the_design():
    """The same function refuses before the design (the file's design.x0_facets, the bound on its
    vertices) and after it (the design's facets and vertices); each refusal names its stage, the
    estimate, the limit, the facets and the vertices."""
    import re

    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.examples import get_example
    from amcp_drake.model.limits import check_run_size

    spec = get_example("ji2022_quadrotor")
    with pytest.raises(ProblemError) as before:
        check_run_size(spec.problem, spec.design, 50, None, 0.01)
    with pytest.raises(ProblemError) as after:
        check_run_size(spec.problem, spec.design, 50, None, 0.01, design=_design_with(12, 20, len(spec.problem.H_theta)))
    text_before, text_after = str(before.value), str(after.value)
    assert "with the design found" not in text_before and "with the design found" in text_after
    assert "design.x0_facets = 8 (<= 16 vertices)" in text_before
    assert "X0 facets = 12 (20 vertices)" in text_after
    for text in (text_before, text_after):
        assert re.search(r"estimated memory [\d.,]+ MiB", text) and "0.01 MiB" in text and "--max-memory" in text


def test_the_size_with_the_design_counts_the_extra_directions_of_theta(example_spec):
    """design.theta_extra_directions adds rows to the shape H_θ of (9), so to the multipliers of (15):
    a run of Example 1 with two extra directions whose memory limit lies between the estimate without
    them and the estimate with them is refused after the design (run_scenario, as amcp certify)."""
    from dataclasses import replace

    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.limits import estimate_run_size
    from amcp_drake.offline.budget import DesignBudget
    from amcp_drake.online.replay import run_scenario

    extra = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 1.0]])
    spec = replace(example_spec, design=replace(example_spec.design, theta_extra_directions=extra))
    pr, steps = spec.problem, 5
    q = len(pr.H_theta)  # 6; the design's H_θ has q + 2 rows, X0 8 facets and 8 vertices (n = 2)
    sizes = dict(n=pr.n, m=pr.m, p=pr.p, N=int(pr.N), facets=8, w_rows=len(pr.H_w), z_rows=len(pr.F), steps=steps,
                 vertices=8)
    without = estimate_run_size(theta_rows=q, **sizes).memory_bytes
    with_extra = estimate_run_size(theta_rows=q + 2, **sizes).memory_bytes
    assert with_extra > 1.01 * without
    limit_mb = 0.5 * (without + with_extra) / 2**20
    with pytest.raises(ProblemError, match=rf"with the design found.*X0 facets = 8 \(8 vertices\), {q + 2} rows of Theta"):
        run_scenario(spec, "drake", steps=steps, design_budget=DesignBudget(limit_mb))


def test_a_campaign_problem_whose_design_is_too_large_is_recorded_as_refused(tmp_path, example_spec):
    """A campaign problem (Example 1 with two extra directions of Θ) whose memory limit lies between the
    estimate without the extra rows and the estimate with the design found: the problem is recorded as
    an error naming the stage, after the design and before any run."""
    from dataclasses import replace
    from types import SimpleNamespace

    from amcp_drake.model.limits import estimate_run_size
    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.studies.campaign import run_problem

    extra = np.array([[1.0, 1.0, 0.0], [0.0, 1.0, 1.0]])
    spec = replace(example_spec, design=replace(example_spec.design, theta_extra_directions=extra))
    pr, steps = spec.problem, 4
    sizes = dict(n=pr.n, m=pr.m, p=pr.p, N=int(pr.N), facets=8, w_rows=len(pr.H_w), z_rows=len(pr.F), steps=steps,
                 vertices=8)
    without = estimate_run_size(theta_rows=len(pr.H_theta), **sizes).memory_bytes
    with_extra = estimate_run_size(theta_rows=len(pr.H_theta) + 2, **sizes).memory_bytes
    case = SimpleNamespace(spec=spec, x0=np.array([2.0, 3.0]), theta_star=np.array([0.8, 0.2, -0.5]),
                           w=np.zeros((steps, 2)), options=OnlineOptions(), labels={}, seed=0)
    result = run_problem(0, 0, ("drake",), str(tmp_path), steps=steps, draw=lambda seed, idx, s: case,
                         max_memory_mb=0.5 * (without + with_extra) / 2**20)
    assert result["status"] == "error", result
    assert "problem size with the design found" in result["message"] and "8 rows of Theta" in result["message"]
    assert result["claims"] == {}


def test_coverage_refuses_a_design_too_large_for_the_limit():
    """`amcp coverage --formulation plain --plane 1,2` on the quadrotor (no design section; a slice of 441
    points, within the point limit): before the design its QP
    is estimated at 13 MiB (the parallelotope's 8 facets and 16 vertices), with the design found (102
    facets, 318 vertices) above the default 2 GiB: exit 2 naming the design's size, before any QP is built."""
    from click.testing import CliRunner

    from amcp_drake.cli import main

    result = CliRunner().invoke(main, ["coverage", "--example", "ji2022_quadrotor", "--formulation", "plain",
                                       "--plane", "1,2", "--no-progress"])
    assert result.exit_code == 2, result.output
    assert "problem size with the design found" in result.output and "--max-memory" in result.output
    assert "X0 facets = 102 (318 vertices)" in result.output


# -- the estimate follows the formulation of (20) ------------------------------------------------------
def test_the_vertex_form_estimate_counts_the_variables_and_rows_drake_builds(example_spec, example_design):
    """Example 1 with N = 4 in the vertex form: (N+1)·(n+1) + N·m variables (no Λ) and N·u·S rows of (5b)
    (u = 8 facets of X0, S = 8 vertices of the box Θ0 in p = 3), counted here by hand."""
    from amcp_drake.online.controller import AdaptiveMPC

    problem = example_spec.problem.with_changes(N=4)
    ctrl = AdaptiveMPC(problem, example_design, backend="drake", formulation="vertex")
    est = estimate_for(problem, example_spec.design, steps=1, design=example_design, formulation="vertex")
    assert est.formulation == "vertex"
    assert est.variables == 5 * 3 + 4 * 1 == ctrl.mpc.prog.num_vars()
    assert est.rows == 4 * 3 + 8 + 4 * 8 * 8 + 3
    assert est.nonzeros == 4 * 3 * 4 + 8 * 3 + 4 * 8 * 8 * (2 * 2 + 1 + 2) + 3 * 3
    plain = estimate_for(problem, example_spec.design, steps=1, design=example_design)
    assert "tube QP (20) in the vertex form" in est.describe() and "tube QP (15)" in plain.describe()
    auto = estimate_for(problem, example_spec.design, steps=1, formulation="auto")
    assert auto.memory_bytes == min(estimate_for(problem, example_spec.design, steps=1, formulation=f).memory_bytes
                                    for f in ("plain", "vertex"))
    with pytest.raises(ValueError, match="formulation: expected one of plain, vertex, auto; received 'dense'"):
        estimate_for(problem, example_spec.design, formulation="dense")


@pytest.mark.parametrize("formulation, refused", [("plain", True), ("vertex", False)])
def test_a_design_is_refused_for_the_form_it_runs(formulation, refused):
    """The quadrotor's 102-facet X0 (318 vertices): at a limit between the two estimates the plain form
    (15) is refused and the vertex form, whose size does not grow with X0's vertices, is admitted."""
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.model.examples import get_example
    from amcp_drake.model.limits import check_run_size

    spec = get_example("ji2022_quadrotor")
    offline = _design_with(102, 318, len(spec.problem.H_theta))
    plain = estimate_for(spec.problem, None, steps=50, design=offline, formulation="plain")
    vertex = estimate_for(spec.problem, None, steps=50, design=offline, formulation="vertex")
    assert vertex.memory_bytes * 10 < plain.memory_bytes
    limit_mb = (vertex.memory_bytes * plain.memory_bytes) ** 0.5 / 2**20
    if refused:
        with pytest.raises(ProblemError, match=r"tube QP \(15\)"):
            check_run_size(spec.problem, spec.design, 50, None, limit_mb, design=offline, formulation=formulation)
    else:
        assert check_run_size(spec.problem, spec.design, 50, None, limit_mb, design=offline,
                              formulation=formulation).memory_bytes == vertex.memory_bytes


@pytest.mark.parametrize("factor, answered", [(0.5, False), (2.0, True)])
def test_the_other_formulation_is_built_only_within_the_memory_limit(monkeypatch, example_spec, example_design,
                                                                     factor, answered):
    """A plain form whose every answer is wrong (tests/tampered_backends.py) falls back to the vertex form;
    with the memory limit at half the vertex form's estimate the fallback is not built: the step is
    left unsolved, and its record says why. At twice the estimate the fallback answers."""
    from amcp_drake.online.controller import AdaptiveMPC
    from tests import tampered_backends as tb

    tb.use_as_drake(monkeypatch, tb.WrongTubeDrake)
    est = estimate_for(example_spec.problem, None, 1, None, design=example_design, formulation="vertex")
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend="drake",
                       max_memory_mb=factor * est.memory_bytes / 2**20)
    u, record = ctrl.step(np.asarray(example_spec.scenario.x0, float))
    from amcp_drake.online import answers

    e = answers.of(record, "tube_qp")
    if answered:
        assert u is not None and (e["outcome"], e["kind"]) == ("fallback", "vertex_form"), e
    else:
        assert u is None and (e["outcome"], e["kind"]) == ("not_solved", ""), e   # no fallback was built
        assert "the vertex form's estimated size exceeds the memory limit" in record.detail  # the reason, named
