"""Problems as engineers write them (model/problem_builder.py, docs/problem-format.md "Engineering
forms"): each form equals the hand-written normalised rows (the numbers below are worked out by hand,
not by the code under test), bad input is named by its JSON path, and the names, units and sample time
travel with the problem."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.problem import Problem
from amcp_drake.model.problem_io import load_spec, save_spec, spec_from_dict, spec_to_dict

ROOT = Path(__file__).resolve().parents[1]

#: A 2-state file in the engineering forms: x = (p [m], v [m/s]), u = F [N], discrete time.
ENGINEER = {
    "format": "amcp-problem", "version": 1, "name": "cart",
    "states": [{"name": "p", "unit": "m"}, {"name": "v", "unit": "m/s"}],
    "inputs": [{"name": "F", "unit": "N"}],
    "dt": 0.1,
    "system": {"A0": [[1.0, 0.1], [0.0, 1.0]], "B0": [[0.0], [0.1]], "A": [[[0.0, 0.0], [0.0, 0.1]]],
               "B": [[[0.0], [0.02]]]},
    "W": {"box": [0.05, 0.25]},
    "Theta": {"box": [[-1.0, 3.0]]},
    "bounds": {"x": {"p": [-0.5, 2.0], "v": [None, 4.0]}, "u": {"F": [-10.0, 5.0]}},
    "cost": {"Q": [[1.0, 0.0], [0.0, 1.0]], "R": [[1.0]], "N": 5},
}

#: The same problem written by hand as the paper's rows (right-hand side 1):
#: p <= 2 -> [0.5, 0]; p >= -0.5 -> [-2, 0]; v <= 4 -> [0, 0.25]; F <= 5 -> G 0.2; F >= -10 -> G -0.1;
#: |w_1| <= 0.05 -> ±20; |w_2| <= 0.25 -> ±4; θ ∈ [-1, 3] -> θ <= 3, -θ <= 1; θ̂0 = 1 (the centre).
HAND = {
    "format": "amcp-problem", "version": 1, "name": "cart",
    "system": ENGINEER["system"],
    "W": {"H": [[20.0, 0.0], [-20.0, 0.0], [0.0, 4.0], [0.0, -4.0]]},
    "Theta": {"H": [[1.0], [-1.0]], "h": [3.0, 1.0]},
    "Z": {"F": [[0.5, 0.0], [-2.0, 0.0], [0.0, 0.25], [0.0, 0.0], [0.0, 0.0]],
          "G": [[0.0], [0.0], [0.0], [0.2], [-0.1]]},
    "cost": ENGINEER["cost"],
    "theta_hat0": [1.0],
}


def _data(**changes):
    data = copy.deepcopy(ENGINEER)
    for key, value in changes.items():
        if value is None:
            data.pop(key, None)
        else:
            data[key] = value
    return data


def _same_rows(a: Problem, b: Problem) -> None:
    for name in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "theta_hat0"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-15, err_msg=name)


def test_bounds_box_W_and_box_theta_equal_the_hand_written_rows():
    engineer = spec_from_dict(_data(), reduce_rows=False).problem
    hand = spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem
    _same_rows(engineer, hand)
    assert engineer.states[1].name == "v" and engineer.states[1].unit == "m/s" and engineer.dt == 0.1
    # the set is the same: a point just inside/outside each bound
    assert engineer.in_Z(np.array([1.999, 3.999]), np.array([4.99])) < 0
    assert engineer.in_Z(np.array([2.001, 0.0]), np.array([0.0])) > 0
    assert engineer.in_Z(np.array([0.0, 0.0]), np.array([-10.01])) > 0
    assert engineer.in_Z(np.array([0.0, -1e6]), np.array([0.0])) < 0  # v has no lower bound


def test_min_max_arrays_equal_bounds_by_name():
    by_arrays = _data(bounds={"x": {"min": [-0.5, None], "max": [2.0, 4.0]}, "u": {"min": [-10.0], "max": [5.0]}})
    _same_rows(spec_from_dict(by_arrays, reduce_rows=False).problem,
               spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem)


def test_default_names_x1_u1_accepted_without_names():
    data = _data(states=None, inputs=None, bounds={"x": {"x1": [-0.5, 2.0], "x2": [None, 4.0]},
                                                   "u": {"u1": [-10.0, 5.0]}})
    problem = spec_from_dict(data, reduce_rows=False).problem
    _same_rows(problem, spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem)
    assert problem.state_names == ("x1", "x2") and problem.state_label(0) == "x1"


def test_general_rows_are_kept_after_the_bounds():
    # x1 + x2 <= 2 as a general row [0.5, 0.5]; the bound rows come first
    data = _data(Z={"F": [[0.5, 0.5]], "G": [[0.0]]})
    problem = spec_from_dict(data, reduce_rows=False).problem
    np.testing.assert_array_equal(problem.F[-1], [0.5, 0.5])
    np.testing.assert_array_equal(problem.F[:5], HAND["Z"]["F"])
    assert problem.F.shape == (6, 2)


def test_round_trip_keeps_names_units_and_sample_time(tmp_path):
    spec = spec_from_dict(_data())
    again = load_spec(save_spec(spec, tmp_path / "p.json"))
    assert again.problem.states == spec.problem.states and again.problem.inputs == spec.problem.inputs
    assert again.problem.dt == 0.1
    _same_rows(again.problem, spec.problem)
    written = json.loads((tmp_path / "p.json").read_text())
    assert written["states"] == [{"name": "p", "unit": "m"}, {"name": "v", "unit": "m/s"}]
    assert "bounds" not in written and written["Z"]["F"][0] == [0.5, 0.0]


def test_from_matrices_equals_the_file_form():
    problem = Problem.from_matrices(
        [[1.0, 0.1], [0.0, 1.0]], [[0.0], [0.1]], [[[0.0, 0.0], [0.0, 0.1]]], [[[0.0], [0.02]]],
        W_box=[0.05, 0.25], Theta_box=[[-1.0, 3.0]], x_bounds={"p": (-0.5, 2.0), "v": (None, 4.0)},
        u_bounds={"F": (-10.0, 5.0)}, Q=np.eye(2), R=[[1.0]], N=5, states=[("p"), {"name": "v", "unit": "m/s"}],
        inputs=["F"], dt=0.1, name="cart")
    _same_rows(problem, spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem)
    assert problem.state_label(1) == "v [m/s]" and problem.state_label(0) == "p" and problem.input_names == ("F",)


# -- zero-order hold ---------------------------------------------------------------------------------------
def test_zoh_of_a_double_integrator_with_an_uncertain_input_gain_is_the_closed_form():
    # p' = v, v' = (1 + 0.5 θ) F: A_d = [[1, dt], [0, 1]], B_d = [[dt²/2], [dt]], B_d1 = 0.5 B_d
    dt = 0.2
    problem = Problem.from_matrices([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], B=[[[0.0], [0.5]]], continuous=True,
                                    dt=dt, W_box=[0.01, 0.01], Theta_box=[[-1, 1]], x_bounds={"x1": (-1, 1)},
                                    u_bounds={"u1": (-1, 1)}, Q=np.eye(2), R=[[1.0]], N=3)
    np.testing.assert_allclose(problem.A0, [[1.0, 0.2], [0.0, 1.0]], rtol=0, atol=1e-15)
    np.testing.assert_allclose(problem.B0, [[0.02], [0.2]], rtol=1e-13)
    np.testing.assert_allclose(problem.B[0], [[0.01], [0.1]], rtol=1e-13)
    np.testing.assert_array_equal(problem.A[0], np.zeros((2, 2)))
    assert problem.dt == dt


def test_zoh_of_a_scalar_system_is_the_closed_form():
    # x' = a x + b (1 + θ) u: A_d = e^{a dt}, B_d = (e^{a dt} − 1)/a · b
    a, b, dt = -2.0, 3.0, 0.5
    problem = Problem.from_matrices([[a]], [[b]], B=[[[b]]], continuous=True, dt=dt, W_box=[0.1],
                                    Theta_box=[[-0.5, 0.5]], x_bounds={"x1": (-5, 5)}, Q=[[1.0]], R=[[1.0]], N=2)
    assert problem.A0[0, 0] == pytest.approx(math.exp(-1.0), rel=1e-14)
    assert problem.B0[0, 0] == pytest.approx((math.exp(-1.0) - 1.0) / a * b, rel=1e-13)
    assert problem.B[0][0, 0] == pytest.approx((math.exp(-1.0) - 1.0) / a * b, rel=1e-13)


def test_zoh_of_the_cartpole_example_equals_scipy_signal_cont2discrete():
    from scipy.signal import cont2discrete

    data = json.loads((ROOT / "examples" / "own-system" / "cartpole.json").read_text())
    sysc = data["system"]
    Ac, Bc, Bc1 = (np.array(sysc[k], float) for k in ("A0", "B0", "B"))
    dt = data["dt"]
    Ad, Bd, *_ = cont2discrete((Ac, Bc, np.eye(4), np.zeros((4, 1))), dt, method="zoh")
    _, Bd1, *_ = cont2discrete((Ac, Bc1[0], np.eye(4), np.zeros((4, 1))), dt, method="zoh")
    problem = load_spec(ROOT / "examples" / "own-system" / "cartpole.json").problem
    np.testing.assert_allclose(problem.A0, Ad, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(problem.B0, Bd, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(problem.B[0], Bd1, rtol=1e-12, atol=1e-14)
    # the model is not the Euler step: the difference is far above the tolerance
    assert np.max(np.abs(problem.A0 - (np.eye(4) + dt * Ac))) > 1e-3


def test_continuous_time_with_theta_in_A_is_refused_naming_the_matrix():
    with pytest.raises(ProblemError) as info:
        spec_from_dict(_data(system={**ENGINEER["system"], "continuous": True}))
    assert info.value.field == "system.A[0]"
    with pytest.raises(ProblemError) as info:
        spec_from_dict(_data(dt=None, system={**ENGINEER["system"], "A": [[[0, 0], [0, 0]]], "continuous": True}))
    assert info.value.field == "dt"


# -- bad input is named ------------------------------------------------------------------------------------
BAD = [
    ({"bounds": {"x": {"p": [0.5, 2.0]}}}, "bounds.x.p[0]", "lower bound < 0"),
    ({"bounds": {"x": {"p": [-1.0, 0.0]}}}, "bounds.x.p[1]", "upper bound > 0"),
    ({"bounds": {"x": {"q": [-1.0, 1.0]}}}, "bounds.x.q", "name of a signal"),
    ({"bounds": {"x": {"p": [None, None]}}}, "bounds.x.p", "at least one side"),
    ({"bounds": {"x": {"p": [-1.0, 1.0, 2.0]}}}, "bounds.x.p", "at most 2"),
    ({"bounds": {"x": {"min": [-1.0]}}}, "bounds.x.min", "2 numbers"),
    ({"bounds": {"x": {"min": [-1.0, -1.0], "p": [-1, 1]}}}, "bounds.x.p", "not both"),
    ({"bounds": {"x": {"p": [-1.0, True]}}}, "bounds.x.p[1]", "booleans"),
    ({"bounds": {"y": {}}}, "bounds.y", "one of the keys"),
    ({"bounds": None}, "Z", "constraints"),
    ({"W": {"box": [0.1, 0.0]}}, "W.box[1]", "half-width > 0"),
    ({"W": {"box": [0.1, 0.5e-9]}}, "W.box[1]", "at least 1e-09"),
    ({"bounds": {"x": {"p": [-0.5e-9, 1.0]}}}, "bounds.x.p[0]", "at least 1e-09"),
    ({"W": {"box": [0.1]}}, "W.box", "length 2"),
    ({"W": {"box": [0.1, 0.1], "H": [[1.0, 0.0]]}}, "W", "exactly one"),
    ({"Theta": {"box": [[1.0, -1.0]]}}, "Theta.box[0]", "lo < hi"),
    ({"Theta": {"box": [[-1.0, 1.0], [-1.0, 1.0]]}}, "Theta.box", "1 intervals"),
    ({"Theta": {"box": [[-1.0, 1.0]], "h": [1.0]}}, "Theta", "not both"),
    ({"Theta": {"H": [[1.0], [-1.0]], "h": [1.0, 1.0]}}, "theta_hat0", "required unless"),
    ({"states": [{"name": "p<b>"}, {"name": "v"}]}, "states[0].name", "a letter"),
    ({"states": [{"name": "p"}, {"name": "p"}]}, "states[1].name", "not used before"),
    ({"states": [{"name": "max"}, {"name": "v"}]}, "states[0].name", "reserved"),
    ({"states": [{"name": "p", "unit": "m\u001b[31m"}, {"name": "v"}]}, "states[0].unit", "a unit"),
    ({"states": [{"name": "p" * 25}, {"name": "v"}]}, "states[0].name", "1 to 24"),
    ({"states": [{"name": "p"}]}, "states", "2 entries"),
    ({"inputs": [{"name": "F", "colour": "red"}]}, "inputs[0].colour", "one of the keys"),
    ({"dt": 0}, "dt", "> 0"),
    ({"dt": "fast"}, "dt", "a number"),
]


@pytest.mark.parametrize("change,field,words", BAD, ids=[b[1] + ":" + b[2] for b in BAD])
def test_bad_engineering_forms_are_named(change, field, words):
    data = _data(**{k: v for k, v in change.items() if v is not None})
    for key, value in change.items():
        if value is None:
            data.pop(key)
    with pytest.raises(ProblemError) as info:
        spec_from_dict(data)
    assert info.value.field == field
    assert words in str(info.value)


def test_a_bad_bound_in_a_file_exits_2_naming_the_path(tmp_path):
    from click.testing import CliRunner

    from amcp_drake.cli import main

    path = tmp_path / "bad.json"
    path.write_text(json.dumps(_data(bounds={"x": {"p": [0.2, 1.0]}})))
    result = CliRunner().invoke(main, ["design", str(path)])
    assert result.exit_code == 2
    assert "bounds.x.p[0]: expected a lower bound < 0" in result.output
    assert "Traceback" not in result.output


# -- families of systems: Drake and python-control -----------------------------------------------------------
def _family():
    """(A, B) at θ = 0 and θ = e_1 of HAND's system (A_1 = [[0, 0], [0, 0.1]], B_1 = [[0], [0.02]])."""
    return [(np.array([[1.0, 0.1], [0.0, 1.0]]), np.array([[0.0], [0.1]])),
            (np.array([[1.0, 0.1], [0.0, 1.1]]), np.array([[0.0], [0.12]]))]


_FORMS = dict(W_box=[0.05, 0.25], Theta_box=[[-1.0, 3.0]], x_bounds={"p": (-0.5, 2.0), "v": (None, 4.0)},
              u_bounds={"F": (-10.0, 5.0)}, Q=np.eye(2), R=[[1.0]], N=5, states=["p", "v"], inputs=["F"])


def test_from_drake_linear_systems_one_per_vertex():
    from pydrake.systems.primitives import AffineSystem, LinearSystem

    systems = [LinearSystem(A, B, np.eye(2), np.zeros((2, 1)), 0.1) for A, B in _family()]
    problem = Problem.from_drake_systems(systems, **_FORMS)
    _same_rows(problem, spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem)
    assert problem.dt == 0.1
    affine = [AffineSystem(A, B, np.zeros(2), np.eye(2), np.zeros((2, 1)), np.zeros(2), 0.1) for A, B in _family()]
    _same_rows(Problem.from_drake_systems(affine, **_FORMS), problem)
    offset = [AffineSystem(A, B, np.array([0.0, 0.3]), np.eye(2), np.zeros((2, 1)), np.zeros(2), 0.1)
              for A, B in _family()]
    with pytest.raises(ProblemError) as info:
        Problem.from_drake_systems(offset, **_FORMS)
    assert info.value.field == "systems[0].f0"
    mixed = [LinearSystem(A, B, np.eye(2), np.zeros((2, 1)), period) for (A, B), period in zip(_family(), (0.1, 0.2))]
    with pytest.raises(ProblemError) as info:
        Problem.from_drake_systems(mixed, **_FORMS)
    assert info.value.field == "systems"


def test_from_drake_continuous_systems_are_discretised_by_zoh():
    from pydrake.systems.primitives import LinearSystem

    # p' = v, v' = (1 + 0.5 θ) F at θ = 0 and θ = 1: the closed form of the double integrator
    family = [(np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([[0.0], [b]])) for b in (1.0, 1.5)]
    systems = [LinearSystem(A, B, np.eye(2), np.zeros((2, 1)), 0.0) for A, B in family]
    problem = Problem.from_drake_systems(systems, dt=0.2, **{k: v for k, v in _FORMS.items()})
    np.testing.assert_allclose(problem.A0, [[1.0, 0.2], [0.0, 1.0]], atol=1e-15)
    np.testing.assert_allclose(problem.B[0], [[0.01], [0.1]], rtol=1e-13)


class _StateSpaceLike:
    """The attributes of a python-control StateSpace that the conversion reads (A, B, dt)."""

    def __init__(self, A, B, dt):
        self.A, self.B, self.dt = A, B, dt


def test_from_control_state_space_attributes():
    problem = Problem.from_control([_StateSpaceLike(A, B, 0.1) for A, B in _family()], **_FORMS)
    _same_rows(problem, spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem)
    with pytest.raises(ProblemError) as info:
        Problem.from_control([_StateSpaceLike(A, B, True) for A, B in _family()], **_FORMS)
    assert info.value.field == "systems[0].dt"


def test_from_control_with_python_control_installed():
    control = pytest.importorskip("control", reason="python-control is not installed (optional)")
    systems = [control.ss(A, B, np.eye(2), np.zeros((2, 1)), 0.1) for A, B in _family()]
    _same_rows(Problem.from_control(systems, **_FORMS), spec_from_dict(copy.deepcopy(HAND), reduce_rows=False).problem)


# -- names in tables and plots ------------------------------------------------------------------------------
def test_names_and_units_head_the_run_table_and_label_the_report_axes():
    from amcp_drake.certificate.plots import signal_label
    from amcp_drake.cli.summary import signals_header

    problem = spec_from_dict(_data()).problem
    assert signals_header(problem) == ["x_k = (p [m], v [m/s]), u_k = (F [N]), sample time dt = 0.1 s"]
    assert signal_label(problem, 1) == "v [m/s]" and signal_label(problem, 0, on_state=False) == "F [N]"
    unnamed = spec_from_dict(copy.deepcopy(HAND)).problem
    assert signals_header(unnamed) == [] and signal_label(unnamed, 1) == "$x_{2}$"


def test_the_cartpole_example_loads_with_names_bounds_and_sample_time():
    spec = load_spec(ROOT / "examples" / "own-system" / "cartpole.json")
    pr = spec.problem
    assert (pr.n, pr.m, pr.p) == (4, 1, 1) and pr.dt == 0.1
    assert pr.state_names == ("p", "phi", "v", "omega") and pr.input_label(0) == "F [N]"
    # every state and the input bounded on both sides: 10 rows; |phi| <= 0.2 is the row ±5 on phi
    assert pr.F.shape == (10, 4)
    assert pr.in_Z(np.array([0.0, 0.199, 0.0, 0.0]), np.zeros(1)) < 0 < pr.in_Z(np.array([0.0, 0.201, 0.0, 0.0]),
                                                                                  np.zeros(1))
    assert spec_to_dict(spec)["states"][1] == {"name": "phi", "unit": "rad"}


def test_amcp_design_runs_on_the_cartpole_example(tmp_path):
    """The example as written (bounds by name, continuous time) goes through `amcp design`; the X0 template
    is fixed here (contractive, λ = 0.98) to keep the test short: the automatic choice is tested with the
    design itself."""
    from click.testing import CliRunner

    from amcp_drake.cli import main

    data = json.loads((ROOT / "examples" / "own-system" / "cartpole.json").read_text())
    data["design"] = {"x0_template": "contractive", "x0_lambda": 0.98}
    path = tmp_path / "cartpole.json"
    path.write_text(json.dumps(data))
    result = CliRunner().invoke(main, ["design", str(path)])
    assert result.exit_code == 0, result.output
    assert "states (p [m], phi [rad], v [m/s], omega [rad/s]); inputs (F [N]); sample time dt = 0.1 s" in result.output
    assert "all design checks pass" in result.output


def test_certify_lists_names_units_and_sample_time_in_its_output_certificate_and_report(tmp_path):
    from click.testing import CliRunner

    from amcp_drake.cli import main

    data = {"format": "amcp-problem", "version": 1, "name": "first-order",
            "states": [{"name": "x", "unit": "m"}], "inputs": [{"name": "u", "unit": "N"}], "dt": 0.5,
            "system": {"A0": [[1.0]], "B0": [[1.0]], "A": [[[0.2]]], "B": [[[0.0]]]},
            "W": {"box": [0.05]}, "Theta": {"box": [[-1, 1]]},
            "bounds": {"x": {"x": [-1, 1]}, "u": {"u": [-1, 1]}},
            "cost": {"Q": [[1.0]], "R": [[1.0]], "N": 5},
            "scenario": {"x0": [0.5], "theta_star": [0.5], "steps": 5, "disturbance": "uniform", "seed": 0}}
    path = tmp_path / "named.json"
    path.write_text(json.dumps(data))
    result = CliRunner().invoke(main, ["certify", str(path), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    assert "first-order: x_k = (x [m]), u_k = (u [N]), sample time dt = 0.5 s" in result.output
    cert = json.loads((tmp_path / "out" / "certificate.json").read_text())
    assert cert["problem"]["states"] == ["x [m]"] and cert["problem"]["inputs"] == ["u [N]"]
    assert cert["problem"]["dt"] == 0.5
    html = (tmp_path / "out" / "report.html").read_text()
    assert '<dd id="signals">states x [m]; inputs u [N]; sample time dt = 0.5 s</dd>' in html


def _fenced(text: str, language: str) -> list[str]:
    import re

    return re.findall(rf"```{language}\n(.*?)```", text, flags=re.S)


def test_the_how_to_starts_from_the_cartpole_file_and_its_python_builds_the_same_problem():
    """docs/how-to/own-system.md: its first JSON block is examples/own-system/cartpole.json, and its Python
    blocks that build the problem (from matrices, from Drake systems) give the file's problem."""
    text = (ROOT / "docs" / "how-to" / "own-system.md").read_text()
    path = ROOT / "examples" / "own-system" / "cartpole.json"
    assert json.loads(_fenced(text, "json")[0]) == json.loads(path.read_text())
    namespace: dict = {}
    blocks = [b for b in _fenced(text, "python") if "amcp.design(" not in b]
    assert len(blocks) == 2
    for block in blocks:
        exec(compile(block, "own-system.md", "exec"), namespace)
    from_file = load_spec(path).problem
    for built in (namespace["problem"], namespace["same"]):
        for name in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "Q", "R", "theta_hat0"):
            np.testing.assert_allclose(getattr(built, name), getattr(from_file, name), rtol=1e-12, atol=1e-15,
                                       err_msg=name)
        assert built.states == from_file.states and built.inputs == from_file.inputs and built.dt == from_file.dt


def test_with_changes_keeps_names_at_the_same_size_and_drops_them_when_n_changes():
    problem = spec_from_dict(_data()).problem
    assert problem.with_changes(N=7).states == problem.states
    bigger = problem.with_changes(A0=np.eye(3), B0=np.zeros((3, 1)) + 0.1, A=np.zeros((1, 3, 3)),
                                  B=np.full((1, 3, 1), 0.01), H_w=np.vstack([np.eye(3), -np.eye(3)]),
                                  F=np.vstack([np.eye(3), -np.eye(3)]), G=np.zeros((6, 1)), Q=np.eye(3))
    assert bigger.states == () and bigger.state_names == ("x1", "x2", "x3") and bigger.inputs == problem.inputs
    with pytest.raises(ProblemError) as info:
        problem.with_changes(states=["p"])
    assert info.value.field == "states"


def test_the_smallest_bound_is_1e_9_just_inside_and_just_outside():
    inside = spec_from_dict(_data(bounds={"x": {"p": [-2e-9, 1.0]}}, W={"box": [2e-9, 0.25]}), reduce_rows=False)
    assert inside.problem.F[1][0] == pytest.approx(-5e8) and inside.problem.H_w[0][0] == pytest.approx(5e8)
    with pytest.raises(ProblemError) as info:
        spec_from_dict(_data(bounds={"x": {"p": [-0.5e-9, 1.0]}}))
    assert info.value.field == "bounds.x.p[0]"


def test_a_continuous_time_problem_is_written_back_in_discrete_time_and_not_discretised_twice(tmp_path):
    spec = load_spec(ROOT / "examples" / "own-system" / "cartpole.json")
    written = json.loads(save_spec(spec, tmp_path / "p.json").read_text())
    assert "continuous" not in written["system"] and written["dt"] == 0.1
    again = load_spec(tmp_path / "p.json")
    _same_rows(again.problem, spec.problem)
    assert again.notes == ()
