"""Designs reused: `amcp design --out FILE` writes the design with the SHA-256 of its canonical problem
(model/problem_hash.py); `--design FILE` on run, certify, compare, coverage and baseline uses it without
designing again, after refusing (exit 2) a design of another problem or one that fails a check
(offline/design_file.py). `--x0` and `--theta-star` on run, certify and compare."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.cli import main
from amcp_drake.model.errors import DesignError
from amcp_drake.model.examples import get_example
from amcp_drake.model.problem_hash import HASHED_FIELDS, canonical_problem, problem_hash, spec_hash


def invoke(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


@pytest.fixture(scope="module")
def design_file(tmp_path_factory):
    """Example 1's design, written by `amcp design --out`."""
    path = tmp_path_factory.mktemp("design") / "design.json"
    result = invoke("design", "--out", path)
    assert result.exit_code == 0, result.output
    return path


@pytest.fixture
def no_redesign(monkeypatch):
    """Any call of the offline design fails the command: the commands below must not design."""
    import amcp_drake.offline.design as module

    def refuse(*args, **kwargs):
        raise DesignError("the offline design was called although --design was given")

    monkeypatch.setattr(module, "design", refuse)


def _edited(design_file, tmp_path, edit, name="edited.json"):
    data = json.loads(design_file.read_text())
    edit(data)
    path = tmp_path / name
    path.write_text(json.dumps(data))
    return path


# -- the hash of the canonical problem --------------------------------------------------------------------
def test_the_canonical_text_holds_exactly_the_problems_numbers_and_the_hash_is_its_sha256():
    spec = get_example("lorenzen2019")
    text = canonical_problem(spec.problem, spec.design.mu_state_bound)
    data = json.loads(text)
    for name in HASHED_FIELDS:
        recorded = np.asarray(data[name], float)
        assert np.array_equal(recorded, np.asarray(getattr(spec.problem, name), float)), name
    assert data["mu_state_bound"] == spec.design.mu_state_bound
    assert problem_hash(spec.problem, spec.design.mu_state_bound) == hashlib.sha256(text.encode()).hexdigest()


def test_one_unit_in_the_last_place_of_any_number_changes_the_hash_and_the_name_does_not():
    spec = get_example("lorenzen2019")
    pr = spec.problem
    base = problem_hash(pr)
    for name in ("A0", "B", "H_w", "h_theta", "F", "Q", "theta_hat0"):
        value = np.array(getattr(pr, name), float)
        flat = value.reshape(-1)
        flat[-1] = np.nextafter(flat[-1], np.inf)
        assert problem_hash(pr.with_changes(**{name: value})) != base, name
    assert problem_hash(pr.with_changes(N=pr.N + 1)) != base
    assert problem_hash(pr, 5.0) != base  # the region of μ (11)
    assert problem_hash(pr.with_changes(name="renamed")) == base
    negative_zero = np.array(pr.A0, float)
    zero = np.argwhere(negative_zero == 0)
    if len(zero):
        negative_zero[tuple(zero[0])] = -0.0
        assert problem_hash(pr.with_changes(A0=negative_zero)) == base


# -- amcp design --out, and reuse --------------------------------------------------------------------------
def test_design_out_writes_the_design_with_the_problems_hash(design_file):
    data = json.loads(design_file.read_text())
    assert data["format"] == "amcp-design" and data["version"] == 1
    assert data["problem"]["sha256"] == spec_hash(get_example("lorenzen2019"))
    assert {"K", "P", "H_x", "X0_vertices", "H_T", "h_T", "mu"} <= set(data["design"])


def test_design_out_does_not_write_a_design_that_fails_a_check(tmp_path, monkeypatch):
    """A failing check (here: every check reported failed) writes nothing and exits 1."""
    import amcp_drake.offline.checks as checks
    from amcp_drake.model.check_result import judge

    monkeypatch.setattr(checks, "verify_design",
                        lambda *a, **k: [judge("stub", "a failing check", -1.0, 0.0)])
    out = tmp_path / "d.json"
    result = invoke("design", "--out", out)
    assert result.exit_code == 1 and not out.exists(), result.output


def test_certify_with_a_design_certifies_without_designing(design_file, tmp_path, no_redesign):
    out = tmp_path / "out"
    result = invoke("certify", "--design", design_file, "--steps", "5", "--out", out)
    assert result.exit_code == 0, result.output
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "pass"


@pytest.mark.parametrize("command", [
    ["run", "--steps", "3"],
    ["compare", "--steps", "2", "--quiet", "--out", "{tmp}/c.json"],
    ["compare", "--steps", "2", "--quiet", "--mode", "independent", "--out", "{tmp}/c.json"],
    ["coverage", "--grid", "3", "--no-progress", "--out", "{tmp}/cov"],
    ["baseline", "--seeds", "1", "--steps", "3", "--grid", "3"],
])
def test_every_command_with_a_design_runs_without_designing(design_file, tmp_path, no_redesign, command):
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    result = invoke(args[0], "--design", design_file, *args[1:])
    assert result.exit_code == 0, result.output


def test_a_design_of_another_problem_is_refused(design_file, tmp_path, no_redesign):
    """Example 1's design on kothare1996 (another problem), and a file whose recorded hash was changed:
    exit 2 naming --design and the hash, nothing written."""
    out = tmp_path / "out"
    result = invoke("certify", "--example", "kothare1996", "--design", design_file, "--out", out)
    assert result.exit_code == 2, result.output
    assert "--design problem.sha256" in result.output and "another problem" in result.output
    assert not out.exists()
    wrong = _edited(design_file, tmp_path, lambda d: d["problem"].update(sha256="0" * 64))
    result = invoke("run", "--design", wrong, "--steps", "2")
    assert result.exit_code == 2 and "--design problem.sha256" in result.output, result.output


def _scale(key, index, factor):
    def edit(data):
        arr = np.array(data["design"][key], float)
        arr[index] *= factor
        data["design"][key] = arr.tolist()
    return edit


@pytest.mark.parametrize(("edit", "named"), [
    (_scale("P", (0, 0), 0.5), r"fails .*terminal cost \(16\)"),
    (_scale("K", (0, 1), 3.0), r"design\.h_bar"),  # h̄ depends on K: the first check to see it
    (_scale("mu", (), 100.0), r"fails .*mu condition \(11\)"),
    (_scale("w_bar", (0,), 0.5), r"fails .*w_bar, f_bar recomputed"),
    (_scale("h_T", (0,), 0.01), r"fails .*X_f"),
    (lambda d: d["design"].update(X0_vertices=d["design"]["X0_vertices"][1:]), r"design\.X0_vertices"),
    (_scale("X0_vertices", (0,), 1.01), r"design\.X0_vertices"),
    (lambda d: d["design"].update(lambda_bar=d["design"]["lambda_bar"] * 0.5), r"design\.lambda_bar"),
    (lambda d: d["design"].update(h_theta0=[2 * v for v in d["design"]["h_theta0"]]), r"design\.h_theta0"),
    (lambda d: d["design"].update(K=[[1.0, 2.0, 3.0]]), r"design\.K: expected n = 2 along axis 1"),
    (lambda d: d["design"].pop("P"), r"design\.P: expected a value"),
    (lambda d: d["design"].update(mu="big"), r"design\.mu: expected a finite number"),
    (lambda d: d["design"].update(mu_state_bound=4.0), r"design\.mu_state_bound"),
    (lambda d: d.update(format="amcp-problem"), r"--design format"),
    (lambda d: d.update(version=2), r"--design version"),
])
def test_a_tampered_design_file_is_refused_before_anything_runs(design_file, tmp_path, no_redesign, edit, named):
    import re

    path = _edited(design_file, tmp_path, edit)
    out = tmp_path / "out"
    result = invoke("certify", "--design", path, "--out", out)
    assert result.exit_code == 2, result.output
    assert re.search(named, result.output), result.output
    assert "Traceback" not in result.output and not out.exists()


@pytest.mark.parametrize(("shift", "accepted"), [(0.5e-6, True), (2e-6, False)])
def test_the_recorded_h_bar_is_held_to_its_tolerance(design_file, tmp_path, no_redesign, shift, accepted):
    """h̄ of Appendix A.1 recomputed over the vertices of X0: a shift of half the tolerance (1e-6) passes,
    twice it is refused."""
    def edit(data):
        h_bar = np.array(data["design"]["h_bar"], float)
        h_bar[0, 0] += shift
        data["design"]["h_bar"] = h_bar.tolist()
        data["design"]["lambda_bar"] = float(np.max(h_bar))

    result = invoke("run", "--design", _edited(design_file, tmp_path, edit), "--steps", "1")
    assert (result.exit_code == 0) is accepted, result.output
    if not accepted:
        assert result.exit_code == 2 and "design.h_bar" in result.output


def test_design_is_refused_with_x0_template_and_with_a_trajectory(design_file, tmp_path):
    result = invoke("run", "--design", design_file, "--x0-template", "mrpi")
    assert result.exit_code == 2 and "--x0-template, --design" in result.output, result.output
    traj = tmp_path / "t.json"
    assert invoke("run", "--steps", "1", "--save", traj).exit_code == 0
    result = invoke("certify", "--trajectory", traj, "--design", design_file, "--out", tmp_path / "o")
    assert result.exit_code == 2 and "--design" in result.output, result.output


# -- --x0 and --theta-star ---------------------------------------------------------------------------------
def test_x0_and_theta_star_replace_the_scenarios_values(design_file, tmp_path, no_redesign):
    from amcp_drake.online.simulate import Trajectory

    traj = tmp_path / "t.json"
    result = invoke("run", "--design", design_file, "--steps", "2", "--x0", "1.5,-0.25",
                    "--theta-star", "0.1,-0.2,0.3", "--save", traj)
    assert result.exit_code == 0, result.output
    saved = Trajectory.load(traj)
    assert saved.x[0].tolist() == [1.5, -0.25]
    assert np.asarray(saved.theta_star, float).reshape(-1)[:3].tolist() == [0.1, -0.2, 0.3]


@pytest.mark.parametrize("command", ["run", "certify", "compare"])
@pytest.mark.parametrize(("option", "value", "says"), [
    ("--x0", "1,2,3", r"--x0: expected 2 finite numbers separated by commas; received 3 number"),
    ("--x0", "1", r"--x0: expected 2 finite numbers"),
    ("--x0", "1,nan", r"--x0: expected 2 finite numbers.*not finite"),
    ("--x0", "1,inf", r"--x0: expected 2 finite numbers.*not finite"),
    ("--x0", "1,a", r"--x0: expected 2 finite numbers"),
    ("--theta-star", "0,0", r"--theta-star: expected 3 finite numbers"),
    ("--theta-star", "0,0,-inf", r"--theta-star: expected 3 finite numbers.*not finite"),
    ("--theta-star", "1.5,0,0", r"--theta-star: expected a point of Theta"),
])
def test_bad_x0_or_theta_star_exits_2_naming_the_option(tmp_path, no_redesign, command, option, value, says):
    import re

    extra = ["--out", str(tmp_path / ("o" if command == "certify" else "c.json"))] if command != "run" else []
    result = invoke(command, option, value, *extra)
    assert result.exit_code == 2, result.output
    assert re.search(says, result.output), result.output
    assert "Traceback" not in result.output


def test_theta_star_just_inside_theta_is_accepted_just_outside_refused(design_file, tmp_path, no_redesign):
    """Θ of Example 1 is the box |θ_i| <= 1 (rows normalised to right-hand side 1): θ*_1 = 1 + 5e-10 lies
    within the membership tolerance 1e-9, 1 + 2e-9 outside it."""
    spec = get_example("lorenzen2019")
    top = max(spec.problem.h_theta[r] / spec.problem.H_theta[r, 0] for r in range(len(spec.problem.H_theta))
              if spec.problem.H_theta[r, 0] > 0)
    inside = invoke("run", "--design", design_file, "--steps", "1", "--theta-star", f"{float(top) + 5e-10!r},0,0")
    outside = invoke("run", "--design", design_file, "--steps", "1", "--theta-star", f"{float(top) + 2e-9!r},0,0")
    assert "--theta-star" not in inside.output, inside.output
    assert outside.exit_code == 2 and "--theta-star: expected a point of Theta" in outside.output


def test_x0_and_theta_star_make_a_scenario_for_a_file_without_one(design_file, tmp_path, no_redesign):
    from amcp_drake.model.problem_io import spec_to_dict

    data = spec_to_dict(get_example("lorenzen2019"))
    data.pop("scenario")
    problem = tmp_path / "p.json"
    problem.write_text(json.dumps(data))
    only_x0 = invoke("run", problem, "--design", design_file, "--x0", "1,1")
    assert only_x0.exit_code == 2 and "--theta-star" in only_x0.output, only_x0.output
    both = invoke("run", problem, "--design", design_file, "--x0", "1,1", "--theta-star", "0,0,0", "--steps", "2")
    assert both.exit_code == 0, both.output

