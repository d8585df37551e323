"""Cross-backend comparison: agreement on Example 1 and on 20 random scenarios, and proof
that `compare` catches a disagreement (an injected perturbation, a loose solver)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.backends import available_backends
from amcp_drake.comparison.compare import TOLERANCES, lockstep
from amcp_drake.model.problem import ProblemSpec, Scenario

pytestmark = pytest.mark.skipif("cvxpy" not in available_backends(), reason="cvxpy backend not installed")


def _scenario_spec(spec, x0, theta_star, seed, steps=6):
    return ProblemSpec(spec.problem, spec.design, Scenario(x0=x0, theta_star=theta_star, steps=steps,
                                                            disturbance="uniform", seed=seed))


def test_lockstep_agrees_on_example_1(example_spec):
    comp = lockstep(example_spec, steps=20, seed=0)
    assert comp.agree, [d.to_dict() for d in comp.disagreements()][:5]
    worst = comp.worst()
    for quantity in ("u", "v", "cost", "h_theta", "theta_hat"):
        assert quantity in worst
        assert worst[quantity].difference <= worst[quantity].tolerance
    assert len(comp.statuses) == 21 and all(a == b == "optimal" for _, a, b in comp.statuses)
    design_quantities = {d.quantity for d in comp.differences if d.step is None}
    assert design_quantities >= {"K", "P", "mu", "H_x", "w_bar", "f_bar", "X_f support"}


def test_both_backends_agree_on_20_random_scenarios(example_spec):
    rng = np.random.default_rng(2024)
    count_optimal = 0
    for i in range(20):
        theta_star = rng.uniform(-1, 1, size=3)
        if i % 4 == 0:
            theta_star = np.sign(theta_star)  # a vertex of Θ
        x0 = rng.uniform([-2.5, -0.3], [2.5, 3.0])
        comp = lockstep(_scenario_spec(example_spec, x0, theta_star, seed=i), steps=6, seed=i, compare_offline=False)
        assert comp.agree, (i, x0, theta_star, [d.to_dict() for d in comp.disagreements()][:3])
        count_optimal += sum(a == "optimal" for _, a, _b in comp.statuses)
    assert count_optimal >= 100  # most steps were solved (not 20 agreeing infeasible starts)


def test_an_injected_perturbation_is_caught_with_quantity_and_step(example_spec, monkeypatch):
    from amcp_reference import tube_mpc

    solver_cls = next(obj for obj in vars(tube_mpc).values()
                      if isinstance(obj, type) and hasattr(obj, "solve") and obj.__module__ == tube_mpc.__name__)
    original = solver_cls.solve
    calls = {"n": 0}

    def perturbed(self, *args, **kwargs):
        sol = original(self, *args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 4 and sol.v is not None:  # step 3
            return dataclasses.replace(sol, v=sol.v + 1e-3)
        return sol

    monkeypatch.setattr(solver_cls, "solve", perturbed)
    # the controller's answer checks would refuse v + 1e-3 ((15c) breaks) and solve the vertex form
    # instead; switched off here, so that what lockstep itself localises is tested
    from amcp_drake.online import answer_checks

    monkeypatch.setattr(answer_checks, "failures", lambda checks: [])
    comp = lockstep(example_spec, steps=6, seed=0, compare_offline=False)
    assert not comp.agree
    first = min(comp.disagreements(), key=lambda d: d.step)
    assert first.step == 3 and first.quantity in ("u", "v")
    assert {d.quantity for d in comp.disagreements() if d.step == 3} >= {"u", "v"}


def test_cli_compare_exits_0_and_writes_every_difference(tmp_path):
    from amcp_drake.cli import main

    out = tmp_path / "cmp.json"
    result = CliRunner().invoke(main, ["compare", "--steps", "8", "--quiet", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "backends agree" in result.output
    data = json.loads(out.read_text())
    assert data["agree"] is True
    assert {d["quantity"] for d in data["differences"]} >= {"u", "v", "cost", "h_theta", "theta_hat"}
    assert data["tolerances"]["v"] == {"abs": TOLERANCES["v"][0], "rel": TOLERANCES["v"][1]}


def test_cli_compare_shows_non_unique_quantities_as_information_never_with_a_tolerance(tmp_path):
    """z and α of (20) are not unique: their (large) differences are marked as information in the per-step table and
    the summary, have no tolerance and no verdict in compare.json, and nothing prints a NaN tolerance."""
    from amcp_drake.cli import main

    out = tmp_path / "cmp.json"
    result = CliRunner().invoke(main, ["compare", "--steps", "3", "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "nan" not in result.output.lower()
    header = next(line for line in result.output.splitlines() if line.lstrip().startswith("k "))
    assert header.split()[-2:] == ["z*", "alpha*"]
    assert "* information only, never compared" in result.output
    assert "information only, no tolerance, never a disagreement" in result.output
    summary = result.output[result.output.index("quantity"):]
    assert not any(line.split()[:1] in (["z"], ["alpha"]) for line in summary.splitlines())
    data = json.loads(out.read_text())
    info = data["informational"]
    assert {d["quantity"] for d in info} == {"z", "alpha"} and max(d["difference"] for d in info) > 1e-3
    assert all(d["tolerance"] is None and d["agree"] is None and d["information_only"] for d in info)
    assert data["agree"] is True


def test_cli_compare_with_a_loose_solver_exits_1_and_names_quantity_and_step(tmp_path):
    from amcp_drake.cli import main

    result = CliRunner().invoke(main, ["compare", "--steps", "6", "--quiet", "--cvxpy-solver", "OSQP",
                                       "--out", str(tmp_path / "c.json")])
    assert result.exit_code == 1, result.output
    assert "DISAGREE" in result.output
    assert "at step" in result.output


def test_cli_compare_bad_problem_file_exits_2(tmp_path):
    from amcp_drake.cli import main

    bad = tmp_path / "bad.json"
    bad.write_text("{")
    result = CliRunner().invoke(main, ["compare", str(bad), "--out", str(tmp_path / "c.json")])
    assert result.exit_code == 2
    assert "valid JSON" in result.output
    assert not (tmp_path / "c.json").exists()


def test_cli_compare_accurate_runs_both_backends_at_tight_tolerances(tmp_path):
    """The flat optimum of a generated case (tests/data/lockstep-flat-optimum-problem.json):
    with --accurate both backends' Clarabel run at 1e-10 and v agrees to far below its tolerance;
    at the defaults v is determined only to ~1e-5 there, so the default comparison's v difference is
    larger. --accurate with another solver is refused, naming the option."""
    from pathlib import Path

    from amcp_drake.cli import main

    problem = Path(__file__).parent / "data" / "lockstep-flat-optimum-problem.json"
    worst = {}
    for flag in ([], ["--accurate"]):
        out = tmp_path / f"c{len(flag)}.json"
        result = CliRunner().invoke(main, ["compare", str(problem), "--steps", "2", "--quiet", *flag, "--out", str(out)])
        assert result.exit_code in (0, 1), result.output
        data = json.loads(out.read_text())
        worst[bool(flag)] = max(d["difference"] for d in data["differences"] if d["quantity"] == "v")
        if flag:
            assert result.exit_code == 0 and "(--accurate)" in result.output
    assert worst[True] < 1e-7 < worst[False]
    result = CliRunner().invoke(main, ["compare", "--accurate", "--cvxpy-solver", "OSQP", "--steps", "2",
                                       "--out", str(tmp_path / "osqp.json")])
    assert result.exit_code == 2 and "--accurate" in result.output and not (tmp_path / "osqp.json").exists()


def test_cli_compare_names_a_flat_optimum_and_suggests_accurate(tmp_path):
    """The vertex form on the saved flat optimum: at the defaults v differs by ~3e-5 at step 0 while
    the cost agrees; the verdict stays DISAGREE (exit 1) and a hint names the step and --accurate.
    With --accurate both agree and there is no hint."""
    from pathlib import Path

    from amcp_drake.cli import main

    problem = Path(__file__).parent / "data" / "lockstep-flat-optimum-problem.json"
    args = ["compare", str(problem), "--steps", "1", "--quiet", "--formulation", "vertex"]
    result = CliRunner().invoke(main, [*args, "--out", str(tmp_path / "d.json")])
    assert result.exit_code == 1, result.output
    assert "hint: at step 0 v differs while the cost agrees" in result.output
    assert json.loads((tmp_path / "d.json").read_text())["flat_optimum_steps"] == [0]
    result = CliRunner().invoke(main, [*args, "--accurate", "--out", str(tmp_path / "a.json")])
    assert result.exit_code == 0, result.output
    assert "hint:" not in result.output


def test_flat_optimum_steps_need_v_apart_and_the_cost_within_tolerance():
    from amcp_drake.comparison.compare import Comparison, Difference

    comp = Comparison("lockstep", ("drake", "cvxpy"), differences=[
        Difference("v", 2, 3e-5, 1.0, 1e-5, False), Difference("cost", 2, 1e-8, 1.0, 1e-5, True),
        Difference("v", 3, 3e-5, 1.0, 1e-5, False), Difference("cost", 3, 1e-3, 1.0, 1e-5, False),
        Difference("v", 4, 1e-9, 1.0, 1e-5, True), Difference("cost", 4, 1e-9, 1.0, 1e-5, True)])
    assert comp.flat_optimum_steps() == [2]


#: The shipped examples whose two designs are compared here; bujarbaruah2022 is left to the command
#: (`amcp compare --example bujarbaruah2022`: its cvxpy design alone takes ~50 s; K within 5.6e-7 of
#: Drake's at 2.9e-4 tolerance).
_DESIGN_EXAMPLES = ("lorenzen2019", "lorenzen2019_ex2", "massera2017", "parsi2020_siso", "parsi2020_mimo",
                    "sls_mpc_2d_eps0.05", "sls_mpc_2d_eps0.15", "sls_mpc_2d_eps0.25", "sls_mpc_2d_eps0.35",
                    "sls_mpc_2d_eps0.45", "kothare1996", "tranos2022")


@pytest.mark.parametrize("name", _DESIGN_EXAMPLES)
def test_both_backends_design_every_shipped_example_alike(name):
    # K is fixed only to about √(the LMI's relative gap) (gain_scaling.GAIN_TIGHT): at Clarabel's default
    # 1e-8 the two backends' K of sls_mpc_2d_eps0.05 and eps0.15 were 2.7e-4 and 3.4e-4 apart, over the
    # comparison's tolerance (1.95e-4, 2.6e-4), and `amcp compare` said DISAGREE on a shipped example
    from amcp_drake.comparison.compare import compare_designs
    from amcp_drake.model.examples import get_example

    diffs, _ = compare_designs(get_example(name))
    assert {d.quantity for d in diffs} >= {"K", "P", "mu", "H_x", "X_f support"}
    assert all(d.agree for d in diffs), [d.to_dict() for d in diffs if not d.agree]
