"""The offline design at n = 4 … 6: defaults valid at every n, the memory and time budget of every
design stage, the progress lines of the automatic mode, the parallelotope template and the scaled-copy
terminal set, each re-checked independently (offline/checks.py, numpy/scipy only)."""

from __future__ import annotations

import json
import re
import tracemalloc
from dataclasses import replace

import numpy as np
import pytest

from amcp_drake.model.problem import ProblemSpec, default_x0_facets
from amcp_drake.model.problem_io import load_spec, spec_from_dict, spec_to_dict
from amcp_drake.offline.auto import AutoDesignError, candidate_options, template_label
from amcp_drake.offline.budget import DesignBudget, DesignSizeError, chunked_row_maxima
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design, design_fixed
from amcp_drake.offline.terminal import SCALED_MARGIN, scaled_terminal_set
from amcp_drake.studies.chains import actuated_chain, integrator_chain


def _load(tmp_path, data: dict):
    path = tmp_path / f"{data['name']}.json"
    path.write_text(json.dumps(data))
    return load_spec(path)


# -- defaults valid at every n -----------------------------------------------------------------------
@pytest.mark.parametrize("n", [5, 6])
def test_file_without_design_section_designs_and_passes_every_check(tmp_path, n):
    spec = _load(tmp_path, actuated_chain(n))
    assert spec.design.x0_facets is None and spec.design.facets_for(n) == default_x0_facets(n) == 2 * n
    d = design(spec.problem, spec.design)
    checks = verify_design(spec.problem, d, spec.design.mu_state_bound)  # numpy/scipy only
    assert [c.name for c in checks if not c.passed] == []
    assert len(d.H_x) <= 4 * n and len(d.H_T) <= 4 * n  # bounded complexity at n >= 4


def test_default_facets_keep_every_design_up_to_n4():
    assert [default_x0_facets(n) for n in range(1, 7)] == [8, 8, 8, 8, 10, 12]


def test_problem_and_trajectory_layout_at_n6_with_x0_facets_12(tmp_path):
    """The certificate path: the trajectory records the problem by spec_to_dict(ProblemSpec(problem)),
    which refused n = 6 with the former default of 8 facets; the file's 12 facets load and round-trip."""
    spec = _load(tmp_path, actuated_chain(6, design_section={"x0_facets": 12}))
    assert spec.design.x0_facets == 12
    recorded = spec_to_dict(ProblemSpec(spec.problem))
    assert "x0_facets" not in recorded["design"]
    assert spec_from_dict(recorded).problem.n == 6
    assert spec_from_dict(spec_to_dict(spec)).design.x0_facets == 12
    with pytest.raises(Exception, match="x0_facets"):
        _load(tmp_path, actuated_chain(6, design_section={"x0_facets": 11}))


# -- memory budget ---------------------------------------------------------------------------------
def test_budget_require_just_inside_and_just_outside():
    budget = DesignBudget(max_memory_mb=1.0)
    budget.require("stage", 2**20)  # exactly the limit: allowed
    with pytest.raises(DesignSizeError, match="stage needs an estimated"):
        budget.require("stage", 2**20 + 1)


def test_design_over_the_memory_limit_is_refused_with_the_stage_before_allocating(tmp_path):
    spec = _load(tmp_path, integrator_chain(4))
    options = replace(spec.design, x0_template="contractive", x0_lambda=0.99)
    tracemalloc.start()
    try:
        with pytest.raises(DesignSizeError) as err:
            design_fixed(spec.problem, options, budget=DesignBudget(max_memory_mb=1.0))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert "X0 template" in err.value.stage and err.value.estimate > err.value.limit == 2**20
    assert "memory limit of 1.0 MiB" in str(err.value)
    assert peak < 20 * 2**20  # nothing of the refused size was allocated


def test_automatic_design_records_candidates_over_the_limit_and_never_crashes(tmp_path):
    """At 1 MiB the larger candidates of the 4-state integrator chain are refused as "too large" and
    recorded; the design goes on to a candidate within the limit, which passes every check."""
    spec = _load(tmp_path, integrator_chain(4))
    d = design(spec.problem, spec.design, budget=DesignBudget(max_memory_mb=1.0))  # no CPU budget: sizes only
    outcomes = [a["outcome"] for a in d.info["attempts"]]
    assert "too large" in outcomes and outcomes[-1] == "pass" and outcomes.count("pass") == 1
    assert len(outcomes) <= len(candidate_options(spec.problem, spec.design))
    assert [c.name for c in verify_design(spec.problem, d) if not c.passed] == []


def test_chunked_row_maxima_equal_the_full_product():
    rng = np.random.default_rng(0)
    rows, points = rng.normal(size=(1000, 5)), rng.normal(size=(300, 5))
    budget = DesignBudget(max_memory_mb=1.0)  # chunks of 64 KiB: many chunks
    # equal up to BLAS's summation order in the blocks (a few ulps), far below any design tolerance
    np.testing.assert_allclose(chunked_row_maxima(rows, points, budget, "test"), np.max(rows @ points.T, axis=1),
                               rtol=1e-13, atol=1e-13)


# -- progress and time budget ----------------------------------------------------------------------
def test_automatic_mode_prints_one_line_per_candidate_in_order_at_n6(tmp_path, monkeypatch):
    """The budget's CPU counter faked (0.2 s per reading, so a 0.5 s budget runs out within a candidate's
    first ticks on any machine): every candidate of the documented order (first round: the open-ended
    templates capped at 16 n = 96 facets) ends in exactly one line, in order, and the budget's end is an
    outcome with its reason."""
    import amcp_drake.offline.budget as budget_module

    cpu = [0.0]

    def process_time():
        cpu[0] += 0.2
        return cpu[0]

    monkeypatch.setattr(budget_module.time, "process_time", process_time)
    spec = _load(tmp_path, integrator_chain(6))
    lines: list[str] = []
    with pytest.raises(AutoDesignError) as err:
        design(spec.problem, spec.design, budget=DesignBudget(candidate_seconds=0.5, progress=lines.append))
    labels = [template_label(o, dimension=6) for o in candidate_options(spec.problem, spec.design)]
    assert labels[0] == "parallelotope"  # bounded complexity first from n = 4 on
    capped = [label if label.startswith(("parallelotope", "mrpi")) else f"{label}, at most 96 facets" for label in labels]
    assert [a.label for a in err.value.attempts] == capped  # none was stopped by the cap: no second round
    events = [line for line in lines if line.startswith("design candidate")]
    # one line per candidate, in order: its label and outcome, with its reason, or, for a failure identical to an
    # earlier candidate's, the number of that candidate
    assert len(events) == len(err.value.attempts)
    for i, (line, a) in enumerate(zip(events, err.value.attempts), start=1):
        assert line.startswith(f"design candidate {i}: {a.label}: {a.outcome}")
        same = re.search(r"the same as candidate (\d+)", line)
        if same is None:
            assert a.brief in line
        else:
            earlier = err.value.attempts[int(same.group(1)) - 1]
            assert int(same.group(1)) < i and (earlier.outcome, earlier.reason) == (a.outcome, a.reason)
    assert any(a.outcome == "time budget" and "0.5 s of CPU used up" in a.reason for a in err.value.attempts)


def test_the_candidate_budget_counts_cpu_time_not_wall_time(monkeypatch):
    """Waiting (a loaded machine) uses no budget; computing does. With the clocks faked (the process's
    real CPU time also counts other threads, e.g. BLAS workers spinning after an earlier test): 10 s of
    wall time and 0.05 s of CPU leave a 0.2 s budget intact; 0.4 s of CPU use it up."""
    import amcp_drake.offline.budget as budget_module
    from amcp_drake.offline.budget import CandidateTimeout

    wall, cpu = [100.0], [7.0]
    monkeypatch.setattr(budget_module.time, "perf_counter", lambda: wall[0])
    monkeypatch.setattr(budget_module.time, "monotonic", lambda: wall[0])
    monkeypatch.setattr(budget_module.time, "time", lambda: wall[0])
    monkeypatch.setattr(budget_module.time, "process_time", lambda: cpu[0])
    budget = DesignBudget(candidate_seconds=0.2)
    wall[0], cpu[0] = 110.0, 7.05
    budget.tick("asleep")  # no CandidateTimeout: 10 s of wall time, 0.05 s of CPU
    assert budget.elapsed() == pytest.approx(0.05)
    cpu[0] = 7.4
    with pytest.raises(CandidateTimeout, match=r"0\.2 s of CPU used up in busy"):
        budget.tick("busy")


def test_progress_lines_come_at_most_every_progress_seconds_of_wall_time(monkeypatch):
    """With progress_seconds = 2: a tick 1.9 s after the last line prints nothing, one 2.1 s after it
    prints one line naming the stage; the next line is due 2 s after that one, not after the start."""
    import amcp_drake.offline.budget as budget_module

    clock = [100.0]
    monkeypatch.setattr(budget_module.time, "perf_counter", lambda: clock[0])
    lines: list[str] = []
    budget = DesignBudget(progress=lines.append, label="cand", progress_seconds=2.0)
    clock[0] = 101.9
    budget.tick("early")
    assert lines == []
    clock[0] = 102.1
    budget.tick("due")
    assert len(lines) == 1 and lines[0].startswith("  ... cand: due (") and lines[0].endswith(" s CPU)")
    clock[0] = 103.9
    budget.tick("too soon after the last line")
    assert len(lines) == 1
    clock[0] = 104.2
    budget.tick("due again")
    assert len(lines) == 2 and "due again" in lines[1]


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_a_progress_interval_that_is_not_a_positive_finite_number_is_refused(value):
    with pytest.raises(ValueError, match="progress_seconds: expected a positive finite number"):
        DesignBudget(progress_seconds=value)


# -- the scaled terminal set -----------------------------------------------------------------------
def _terminal_inputs(product: float):
    """(H_x, f̄, w̄, h̄) of a box X0 with α_∞ · max f̄ = product."""
    H_x = np.vstack([np.eye(2), -np.eye(2)])
    h_bar = np.full((2, 4), 0.5)
    w_bar = np.full(4, 0.1)  # α_∞ = 0.1 / 0.5 = 0.2
    return H_x, np.full(3, product / 0.2), w_bar, h_bar


def test_scaled_terminal_set_needs_alpha_inf_below_alpha_bar():
    H_T, h_T = scaled_terminal_set(*_terminal_inputs(1.0 - 2 * SCALED_MARGIN))  # just inside
    assert np.allclose(h_T * 0.2, (1.0 - 2 * SCALED_MARGIN) / (1.0 - SCALED_MARGIN))
    with pytest.raises(Exception, match="alpha_inf"):
        scaled_terminal_set(*_terminal_inputs(1.0 - 0.5 * SCALED_MARGIN))  # just outside


@pytest.mark.parametrize("n", [4, 5, 6])
def test_scaled_terminal_set_satisfies_assumption_11_by_sampling(tmp_path, n):
    """Independent of offline/checks.py: random (z, α) ∈ X_f, θ ∈ Θ, x ∈ {z} ⊕ αX0, w ∈ W; the successor
    A_cl(θ)x + w lies in α⁺X0 (z⁺ = 0) with (0, α⁺) ∈ X_f, and (x, Kx) ∈ Z."""
    spec = _load(tmp_path, actuated_chain(n))
    pr = spec.problem
    d = design_fixed(pr, replace(spec.design, x0_template="parallelotope", terminal_set="scaled"))
    rng = np.random.default_rng(n)
    alpha_bar = 1.0 / d.h_T[0]
    W_v, X_v = pr.w_vertices(), d.X0_vertices
    for _ in range(200):
        alpha = rng.uniform(0, alpha_bar)
        z = rng.dirichlet(np.ones(len(X_v))) @ X_v * (alpha_bar - alpha) * rng.uniform()
        assert np.all(d.H_T @ z + d.h_T * alpha <= 1 + 1e-12)
        x = z + alpha * (rng.dirichlet(np.ones(len(X_v))) @ X_v)
        assert np.all(pr.F @ x + pr.G @ (d.K @ x) <= 1 + 1e-9)
        theta = rng.uniform(-0.1, 0.1, size=2)
        succ = (pr.A_of(theta) + pr.B_of(theta) @ d.K) @ x + rng.dirichlet(np.ones(len(W_v))) @ W_v
        alpha_next = float(np.max(d.H_x @ succ))  # the least α⁺ with succ ∈ α⁺X0
        assert alpha_next <= alpha_bar + 1e-9


@pytest.mark.parametrize("n", [4, 6])
def test_parallelotope_template_is_contractive_and_invariant_by_independent_checks(tmp_path, n):
    spec = _load(tmp_path, actuated_chain(n))
    d = design_fixed(spec.problem, replace(spec.design, x0_template="parallelotope"))
    assert len(d.H_x) == 2 * n and len(d.X0_vertices) == 2 ** n
    by_name = {c.name: c for c in verify_design(spec.problem, d)}
    for name in ("terminal cost (16)", "Assumption 8", "X0 contractive", "X0 robustly invariant", "X_f invariant",
                 "X_f in Z", "X_f non-empty"):
        assert by_name[name].passed, (name, by_name[name].detail)
    # contractivity recomputed here from the vertices, without offline/checks.py
    theta_v = np.array([[s1, s2] for s1 in (-0.1, 0.1) for s2 in (-0.1, 0.1)])
    lam = max(float(np.max(d.H_x @ (spec.problem.A_of(t) + spec.problem.B_of(t) @ d.K) @ d.X0_vertices.T))
              for t in theta_v)
    assert lam < 1.0 and np.isclose(lam, d.lambda_bar, atol=1e-8)


def test_certify_refuses_a_run_whose_design_is_too_large_before_building_the_controller(tmp_path):
    """The quadrotor's automatic design passes with a 102-facet X0 (318 vertices): the run's estimate with
    that design exceeds the default limit in the plain form (15), so `amcp certify --formulation plain`
    exits 2 naming the design's size and the option, after the design and before the controller is built;
    nothing is written."""
    from click.testing import CliRunner

    from amcp_drake.cli import main

    out = tmp_path / "out"
    result = CliRunner().invoke(main, ["certify", "--example", "ji2022_quadrotor", "--steps", "50", "--formulation",
                                       "plain", "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert "problem size with the design found" in result.output and "--max-memory" in result.output
    assert "X0 facets = 102 (318 vertices)" in result.output
    assert not out.exists()
