"""The size table (``amcp bench --only size``), campaigns over larger state dimensions
(``amcp campaign --state-dims``) and the property suite's draws by state dimension.

No test here is timed: the table's numbers are measurements (benchmarks/README.md); these tests check
that every row ends with a result or a reason, that the limits are applied, and that the options are
validated and recorded."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.studies import bench_size
from amcp_drake.studies.bench_size import SizeRow, default_rows, faster_form, run_row, size_markdown
from amcp_drake.studies.chains import CHAIN_KINDS, actuated_chain, chain, integrator_chain


def _invoke(*args: str):
    from amcp_drake.cli import main

    return CliRunner().invoke(main, list(args))


# -- chains ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 5, 8])
def test_chain_files_load_at_every_n_without_a_design_section(n):
    for kind in CHAIN_KINDS:
        data = chain(kind, n)
        assert "design" not in data
        spec = spec_from_dict(data)
        assert spec.problem.n == n and spec.problem.p == 2
    assert spec_from_dict(integrator_chain(n)).problem.m == 1
    assert spec_from_dict(actuated_chain(n)).problem.m == n


@pytest.mark.parametrize("bad", [1, 0, 2.5, True])
def test_chain_refuses_a_dimension_below_two(bad):
    with pytest.raises(ValueError, match="n: expected an integer >= 2"):
        actuated_chain(bad)


# -- rows of the size table ------------------------------------------------------------------------------
def test_default_rows_are_every_chain_and_every_built_in_example_with_four_or_more_states(tmp_path):
    from amcp_drake.model.examples import EXAMPLES

    path = tmp_path / "mine.json"
    path.write_text(json.dumps(integrator_chain(3)))
    rows = default_rows(problem_files=(str(path),))
    chains = [r for r in rows if r.source == "chain"]
    assert [(r.label.split()[0], spec_from_dict(r.problem).problem.n) for r in chains] == \
        [(kind, n) for kind in CHAIN_KINDS for n in range(2, 9)]
    examples = {r.label for r in rows if r.source == "example"}
    expected = {name for name, make in EXAMPLES.items() if make().problem.n >= 4}
    assert examples == expected
    assert rows[-1].source == "file" and rows[-1].label == "mine"


def test_a_row_runs_in_its_own_process_and_reports_every_column():
    lines: list[str] = []
    row = SizeRow("actuated chain n=2", "chain", actuated_chain(2))
    result = run_row(row, steps=3, seed=0, max_memory_mb=2048, candidate_seconds=60, row_seconds=600,
                     progress=lines.append)
    assert result["status"] == "completed", result
    assert result["n"] == 2 and result["x0_facets"] >= 4 and result["x0_vertices"] >= 4 and result["xf_rows"] >= 1
    assert result["design_cpu_s"] > 0 and result["design_s"] > 0 and result["peak_rss_mib"] > 10
    assert [r["formulation"] for r in result["runs"]] == ["plain", "vertex", "fast"]
    assert all(r["times_ms"]["cpu_total"]["n"] == 3 for r in result["runs"])
    assert result["auto"]["formulation"] in ("plain", "vertex")
    assert faster_form(result) in ("plain", "vertex")
    assert any("design candidate" in line for line in lines)  # the child's progress is relayed
    table = size_markdown([result])
    assert "| actuated chain n=2 | 2 | 2 | 2 |" in table and "completed" in table


def test_a_row_over_its_cpu_limit_is_killed_by_the_kernel_and_classified_so(monkeypatch):
    """A real child under RLIMIT_CPU = 1 s: the kernel ends it (the wall-time guard is set to an hour, so a
    loaded machine cannot end it first) and the row is classified as over its CPU-time limit. How much CPU the
    kernel counted is not asserted: its accounting differs from ``wait4``'s by a tick."""
    from tests.guards import GUARD_SECONDS

    monkeypatch.setattr(bench_size, "WALL_FACTOR", GUARD_SECONDS)
    row = SizeRow("actuated chain n=4", "chain", actuated_chain(4))
    result = run_row(row, steps=30, seed=0, max_memory_mb=2048, candidate_seconds=60, row_seconds=1.0)
    assert "CPU-time limit of 1 s" in result["status"], result["status"]
    assert result["cpu_s"] > 0 and "killed after" in size_markdown([result])


class _FakeChild:
    """A child that was never started: ``run_row``'s Popen replaced, its end given by a fake ``wait4``."""

    pid = 99999999

    def __init__(self, *args, **kwargs):
        import io

        self.stderr, self.killed = io.StringIO(""), False

    def kill(self):
        self.killed = True


def _fake_end(monkeypatch, signum: int, cpu_s: float, clock_step: float = 0.0):
    """``run_row`` with a fake child that ends by ``signum`` after ``cpu_s`` seconds of CPU (user + system,
    as ``wait4`` reports it), and a fake wall clock that moves ``clock_step`` s per reading."""
    import types

    usage = types.SimpleNamespace(ru_utime=cpu_s / 2, ru_stime=cpu_s / 2, ru_maxrss=1024)
    clock = [0.0]

    def perf_counter():
        clock[0] += clock_step
        return clock[0]

    children: list[_FakeChild] = []
    monkeypatch.setattr(bench_size.subprocess, "Popen", lambda *a, **k: children.append(_FakeChild()) or children[-1])
    monkeypatch.setattr(bench_size.os, "wait4", lambda pid, options: (
        (0, 0, usage) if options and clock_step and not children[-1].killed else (pid, signum, usage)))
    monkeypatch.setattr(bench_size.time, "perf_counter", perf_counter)
    monkeypatch.setattr(bench_size, "POLL_SECONDS", 0.0)
    row = SizeRow("actuated chain n=2", "chain", actuated_chain(2))
    return run_row(row, steps=3, seed=0, max_memory_mb=2048, candidate_seconds=60, row_seconds=1.0), children


@pytest.mark.parametrize(("signum", "cpu_s", "over_cpu"), [
    (24, 0.97, True),    # SIGXCPU: the kernel's own CPU limit, whatever wait4's CPU says
    (9, 1.0, True),      # SIGKILL one second after SIGXCPU, at the limit
    (9, 0.99, False),    # SIGKILL below the limit: someone else killed it
])
def test_the_cpu_limit_classification_is_read_from_the_signal_and_wait4s_cpu(monkeypatch, signum, cpu_s, over_cpu):
    import signal

    assert signum in (signal.SIGXCPU, signal.SIGKILL)
    result, _ = _fake_end(monkeypatch, signum, cpu_s)
    assert ("CPU-time limit of 1 s" in result["status"]) is over_cpu, result["status"]
    assert result["cpu_s"] == pytest.approx(cpu_s)
    if not over_cpu:
        assert "SIGKILL" in result["status"]


def test_a_row_over_its_wall_limit_is_killed_by_a_fake_clock(monkeypatch):
    """The wall-time guard (WALL_FACTOR x the CPU limit) read from a fake clock that moves 4 s per reading:
    the child is killed at the first poll past 10 s, and the row is classified by the wall limit."""
    result, children = _fake_end(monkeypatch, 9, 0.1, clock_step=4.0)
    assert children[0].killed
    assert "10 s of wall time" in result["status"] and "CPU-time limit" not in result["status"], result["status"]


def test_a_design_over_the_memory_limit_is_a_row_with_the_stage_named():
    row = SizeRow("integrator chain n=5", "chain", integrator_chain(5))  # no design at n = 5 (docs/decisions.md)
    result = run_row(row, steps=3, seed=0, max_memory_mb=1.0, candidate_seconds=5, row_seconds=600)
    assert result["status"].startswith("no design candidate passed; the first: parallelotope: ")
    assert any(a["outcome"] == "too large" and "memory limit of 1.0 MiB" in a["reason"] for a in result["attempts"])
    assert "runs" not in result


def test_a_child_that_cannot_start_within_its_address_space_shows_the_limit(monkeypatch):
    monkeypatch.setattr(bench_size, "ADDRESS_SPACE_OVERHEAD_MB", 16)  # too small even for Python and numpy
    row = SizeRow("actuated chain n=2", "chain", actuated_chain(2))
    result = run_row(row, steps=3, seed=0, max_memory_mb=1.0, candidate_seconds=5, row_seconds=120)
    assert result["status"] != "completed"
    assert "address space limit 17 MiB" in result["status"] or "out of memory" in result["status"], result["status"]


def test_bench_only_size_writes_the_table_and_the_json_and_no_plot(tmp_path):
    problem = tmp_path / "chain3.json"
    problem.write_text(json.dumps(actuated_chain(3)))
    result = _invoke("bench", "--only", "size", "--no-chains", "--example", "lorenzen2019", "--problem", str(problem),
                     "--scaling-steps", "2", "--out", str(tmp_path / "out"))
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert data["version"] == 6 and data["example"] is None and data["scaling"] is None
    assert [(r["label"], r["source"], r["status"]) for r in data["size"]] == [
        ("lorenzen2019", "example", "completed"), ("chain3", "file", "completed")]
    table = (tmp_path / "out" / "size.md").read_text()
    assert "| lorenzen2019 | 2 | 1 | 3 |" in table and "| chain3 | 3 | 3 | 2 |" in table
    assert "| 1: 1 pass |" in table  # the first candidate of both passed
    assert "size table (one row per system):" in result.output
    assert not (tmp_path / "out" / "bench.png").exists()


def test_candidates_are_counted_by_outcome():
    from amcp_drake.studies.bench_size import candidates_text

    attempts = [{"outcome": "time budget"}, {"outcome": "too large"}, {"outcome": "time budget"}, {"outcome": "pass"}]
    assert candidates_text(attempts) == "4: 2 time budget, 1 too large, 1 pass"
    assert candidates_text([]) == candidates_text(None) == "-"


def test_faster_form_is_read_from_the_medians():
    def run(formulation, ms):
        return {"formulation": formulation, "status": "completed", "times_ms": {"cpu_total": {"median": ms}}}

    assert faster_form({"runs": [run("plain", 2.0), run("vertex", 1.0)]}) == "vertex"
    assert faster_form({"runs": [run("plain", 1.0), run("vertex", 2.0)]}) == "plain"
    assert faster_form({"runs": [run("plain", 1.0)]}) is None


@pytest.mark.parametrize(("args", "field"), [
    (["--chains", "1-4"], "--chains"), (["--chains", "4-3"], "--chains"), (["--chains", "x"], "--chains"),
    (["--chains", "2-13"], "--chains"), (["--example", "nope"], "--example"),
])
def test_bench_size_bad_options_exit_2_naming_the_option(args, field, tmp_path):
    result = _invoke("bench", "--only", "size", "--out", str(tmp_path), *args)
    assert result.exit_code == 2, result.output
    assert field in result.output and "Traceback" not in result.output
    assert not (tmp_path / "size.md").exists()


# -- campaigns over larger state dimensions --------------------------------------------------------------
@pytest.mark.parametrize("value", ["0-3", "4-9", "6-4", "four", "4-5-6"])
def test_campaign_state_dims_bad_values_exit_2(value, tmp_path):
    result = _invoke("campaign", "--state-dims", value, "--store", str(tmp_path / "c.sqlite"), "--systems", "1")
    assert result.exit_code == 2, result.output
    assert "--state-dims" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "c.sqlite").exists()


def test_campaign_help_documents_state_dims():
    result = _invoke("campaign", "--help")
    assert result.exit_code == 0 and "--state-dims" in result.output


def test_state_dims_are_recorded_only_when_not_the_default_and_a_resume_with_others_is_refused(tmp_path):
    from amcp_drake.studies.campaign import campaign_settings
    from amcp_drake.studies.campaign_store import CampaignStore, settings_differences

    default = campaign_settings(0, 5, ("drake",), 6)
    assert "state_dims" not in default
    assert campaign_settings(0, 5, ("drake",), 6, (1, 3)) == default  # stores made before the option still match
    larger = campaign_settings(0, 5, ("drake",), 6, (4, 6))
    assert larger["state_dims"] == [4, 6]
    store = CampaignStore(tmp_path / "s.sqlite")
    store.require_settings(larger)
    assert sorted(settings_differences(store.settings(), default)) == ["--state-dims None (store: 4,6)",
                                                                       "formulation plain (store: auto)"]
    from amcp_drake.model.errors import CampaignStoreError

    with pytest.raises(CampaignStoreError, match="--state-dims"):
        store.require_settings(campaign_settings(0, 5, ("drake",), 6, (4, 5)))
    store.close()


def test_campaigns_over_other_state_dimensions_run_and_replay_the_automatic_formulation(tmp_path):
    from amcp_drake.studies.campaign import FORMULATION, campaign_formulation, campaign_settings, replay_command

    assert campaign_formulation(None) == campaign_formulation((1, 3)) == FORMULATION == "plain"
    assert campaign_formulation((4, 6)) == "auto"
    assert campaign_settings(0, 5, ("drake",), 6, (4, 6))["formulation"] == "auto"
    command = replay_command(tmp_path / "0-1", "cvxpy", campaign_formulation((4, 6)))
    assert "--formulation auto" in command and "--backend cvxpy" in command


def test_random_shape_draws_n_in_the_range_and_the_default_draws_are_unchanged():
    from amcp_drake.studies.random_problems import random_shape

    drawn = {random_shape(np.random.default_rng(s), min_n=4, max_n=6).n for s in range(60)}
    assert drawn == {4, 5, 6}
    # the default range draws n as rng.integers(1, 4) first, exactly as before the option
    for s in range(20):
        assert random_shape(np.random.default_rng(s)).n == int(np.random.default_rng(s).integers(1, 4))
    with pytest.raises(Exception, match="state dimensions"):
        random_shape(np.random.default_rng(0), min_n=4, max_n=3)


def test_generated_problems_use_the_automatic_design_from_n4_and_the_drawn_mrpi_below():
    from amcp_drake.studies.random_problems import ProblemShape, random_problem

    small, _ = random_problem(np.random.default_rng(1), ProblemShape(n=3))
    large, _ = random_problem(np.random.default_rng(1), ProblemShape(n=4))
    assert (small.design.x0_template, small.design.x0_facets) == ("mrpi", 6)
    assert (large.design.x0_template, large.design.x0_facets) == ("auto", None)


def test_a_campaign_draw_with_state_dims_4_to_6_is_designed_and_passes_every_design_check():
    from amcp_drake.offline.checks import verify_design
    from amcp_drake.studies.campaign import draw_case

    case = draw_case(11, 0, 4, state_dims=(4, 6))
    assert 4 <= case.problem.n <= 6 and case.labels["n"] == str(case.problem.n)
    checks = verify_design(case.problem, case.design, case.spec.design.mu_state_bound)  # numpy/scipy only
    assert [c.name for c in checks if not c.passed] == []


def test_a_rejected_draw_is_recorded_with_its_dimensions_and_reason():
    from amcp_drake.model.errors import DesignError
    from amcp_drake.offline.auto import Attempt, AutoDesignError
    from amcp_drake.studies.random_problems import REJECTION_CHARS, ProblemShape, rejection_reason

    shape = ProblemShape(n=5, m=2, p=3)
    auto = AutoDesignError([Attempt("parallelotope", "design failed", "LP infeasible", 0.1),
                            Attempt("contractive, lambda 0.9", "too large", "X0 template needs 3 GiB", 0.2),
                            Attempt("mrpi, 10 facets", "design failed", "diverged", 0.3)])
    text = rejection_reason(shape, auto)
    assert text == "n=5 m=2 p=3: AutoDesignError: 2 design failed, 1 too large; last: mrpi, 10 facets: diverged"
    assert rejection_reason(shape, DesignError("no robust gain\nmore")) == "n=5 m=2 p=3: DesignError: no robust gain"
    assert len(rejection_reason(shape, DesignError("x" * 500))) == REJECTION_CHARS


def test_the_campaign_summary_counts_problems_by_n_and_rejected_draws_by_reason():
    from amcp_drake.cli.campaign import draw_lines

    labels = [(0, 0, {"n": "4", "design attempts": "1"}),
              (0, 1, {"n": "6", "design attempts": "3",
                      "rejected draws": "n=6 m=1 p=2: AutoDesignError: 14 design failed; last: a: b | "
                                        "n=5 m=2 p=1: AutoDesignError: 14 design failed; last: c: d"}),
              (0, 2, {"n": "4", "design attempts": "2", "rejected draws": "n=4 m=1 p=1: DesignError: no gain"})]
    lines = draw_lines(labels)
    assert lines[0] == "problems by state dimension: n=4: 2, n=6: 1"
    assert lines[1] == "draws rejected by the offline design (and replaced by the next draw): 3"
    assert lines[2:] == ["     2 x AutoDesignError: 14 design failed", "     1 x DesignError: no gain"]


# -- the property suite's draws by state dimension -------------------------------------------------------
def test_property_profiles_draw_up_to_5_states_in_thorough_and_3_in_ci():
    from amcp_properties.profiles import SIZES

    assert SIZES["ci"].max_n == 3 and SIZES["thorough"].max_n == 5


def test_problem_shapes_with_max_n_5_reach_4_and_5_and_with_max_n_3_stay_below():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from amcp_properties.strategies import problem_shapes

    seen: dict[int, set[int]] = {3: set(), 5: set()}

    @settings(max_examples=200, derandomize=True, database=None)
    @given(st.sampled_from([3, 5]).flatmap(lambda m: st.tuples(st.just(m), problem_shapes(max_n=m))))
    def collect(pair):
        max_n, shape = pair
        seen[max_n].add(shape.n)

    collect()
    assert seen[3] == {1, 2, 3}
    assert seen[5] == {1, 2, 3, 4, 5}


def test_the_dimension_line_counts_draws_accepted_and_runs_per_n():
    from amcp_properties.coverage import dimension_line
    from amcp_properties.strategies import GeneratorStats

    stats = GeneratorStats()
    for key in ("draws n=2", "draws n=2", "accepted n=2", "draws n=5", "accepted n=5", "draws n=4"):
        stats.add(key)
    summary = {"t[drake]": {"labels": {"n=2": 3, "n=5": 1, "m=1": 4}}, "u[cvxpy]": {"labels": {"n=5": 2}}}
    assert stats.by_dimension() == {2: (2, 1), 4: (1, 0), 5: (1, 1)}
    assert dimension_line(stats.by_dimension(), summary, {5: (3, 1)}) == \
        ("state dimension n: draws (accepted) / refused by the run's memory estimate / runs of all tests: "
         "n=2: 2 (1) / 0 / 3, n=4: 1 (0) / 0 / 0, n=5: 1 (1) / 1 / 3")


# -- the generator's boundary LP with the row maxima over X0's vertices ----------------------------------
def test_the_ray_length_with_row_maxima_equals_the_one_with_every_vertex(example_spec, example_design):
    """Two formulations of the same set (tube_feasibility's module docstring), solved by HiGHS: equal to
    its tolerances along every direction; the row-maxima LP has q times fewer rows of (5b)."""
    from amcp_drake.studies.tube_feasibility import TubeGeometry, _rows, max_ray_length

    pr = example_spec.problem
    geo = TubeGeometry.build(pr, example_design, pr.theta_vertices())
    for angle in np.linspace(0.0, 2 * np.pi, 9)[:-1]:
        d = np.array([np.cos(angle), np.sin(angle)])
        full, reduced = max_ray_length(geo, d), max_ray_length(geo, d, row_maxima=True)
        assert np.isfinite(full) and full > 0
        assert abs(full - reduced) <= 1e-7 * max(1.0, full), (angle, full, reduced)
    q = len(geo.X0_vertices)
    rows_full = _rows(geo, np.array([1.0, 0.0]), None)[0].shape[0]
    rows_reduced = _rows(geo, np.array([1.0, 0.0]), None, row_maxima=True)[0].shape[0]
    per_block = pr.N * len(geo.A_cl) * len(geo.H_x)
    assert rows_full - rows_reduced == per_block * (q - 1)


def test_mass_chain_generator_gives_the_built_in_chains_data():
    """mass_chain(3), mass_chain(4) load to the built-in files' problems and scenarios (every matrix equal)."""
    from amcp_drake.model.examples import get_example
    from amcp_drake.model.problem_io import spec_from_dict
    from amcp_drake.studies.chains import mass_chain

    for masses in (3, 4):
        made, shipped = spec_from_dict(mass_chain(masses)), get_example(f"mass_chain{masses}")
        for field in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "Q", "R", "theta_hat0"):
            np.testing.assert_array_equal(getattr(made.problem, field), getattr(shipped.problem, field), err_msg=field)
        assert made.problem.N == shipped.problem.N
        np.testing.assert_array_equal(made.scenario.x0, shipped.scenario.x0)
        np.testing.assert_array_equal(made.scenario.theta_star, shipped.scenario.theta_star)
    big = spec_from_dict(mass_chain(8)).problem
    assert (big.n, big.m, big.p) == (16, 8, 7)


def test_mass_chain_rows_of_the_size_table_have_two_states_per_mass():
    rows = default_rows(chain_ns=(), examples=(), mass_chains=(5, 8))
    assert [(r.source, spec_from_dict(r.problem).problem.n) for r in rows] == [("chain", 10), ("chain", 16)]
    assert all("design" not in r.problem for r in rows)
