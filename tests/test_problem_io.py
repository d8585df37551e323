"""Problem files: round trip, the shipped Example 1 file, and malformed files."""

from __future__ import annotations

import json

import numpy as np
import pytest

from amcp_drake.model.errors import ProblemError, ProblemFileError
from amcp_drake.model.problem_io import jsonable, load_spec, save_spec, spec_to_dict


def test_example_file_in_the_repository_equals_the_builtin(example_spec):
    from pathlib import Path

    repo_file = Path(__file__).resolve().parents[1] / "examples" / "lorenzen2019.json"
    assert spec_to_dict(load_spec(repo_file)) == spec_to_dict(example_spec)


def test_example_1_data_is_the_papers(example_spec):
    pr = example_spec.problem
    np.testing.assert_array_equal(pr.A0, [[0.5, 0.2], [-0.1, 0.6]])
    np.testing.assert_array_equal(pr.B0, [[0.0], [0.5]])
    np.testing.assert_array_equal(pr.A[0], [[0.042, 0.0], [0.072, 0.03]])
    np.testing.assert_array_equal(pr.A[1], [[0.015, 0.019], [0.009, 0.035]])
    np.testing.assert_array_equal(pr.B[2], [[0.040], [0.054]])
    assert pr.N == 10
    # constraints x2 >= -0.3 and |u| <= 1 (docs/explanation/paper.md §9: from a public re-implementation)
    assert pr.in_Z(np.array([0.0, -0.3]), np.array([1.0])) == pytest.approx(0.0, abs=1e-12)
    assert pr.in_Z(np.array([0.0, -0.31]), np.array([0.0])) > 0
    assert pr.in_Z(np.array([100.0, 50.0]), np.array([-1.01])) > 0
    np.testing.assert_array_equal(example_spec.scenario.x0, [2.0, 3.0])
    np.testing.assert_array_equal(example_spec.scenario.theta_star, [0.8, 0.2, -0.5])


def test_round_trip(tmp_path, example_spec):
    path = save_spec(example_spec, tmp_path / "p.json")
    assert spec_to_dict(load_spec(path)) == spec_to_dict(example_spec)


@pytest.mark.parametrize("content,fragment", [
    ("{not json", "valid JSON"),
    ("[]", "JSON object"),
    ('{"format": "other", "version": 1}', "format"),
    ('{"format": "amcp-problem", "version": 7}', "version"),
    ('{"format": "amcp-problem", "version": 1}', "system"),
])
def test_malformed_files_raise_problem_file_error(tmp_path, content, fragment):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ProblemFileError, match=fragment):
        load_spec(path)


def test_missing_file_and_bad_field_inside_file(tmp_path, example_spec):
    with pytest.raises(ProblemFileError, match="readable"):
        load_spec(tmp_path / "nope.json")
    data = spec_to_dict(example_spec)
    data["cost"]["N"] = -3
    data["design"]["banana"] = 1
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ProblemError, match="cost.N"):
        load_spec(path)
    data["cost"]["N"] = 3
    path.write_text(json.dumps(data))
    with pytest.raises(ProblemFileError, match="banana"):
        load_spec(path)


def test_jsonable_turns_numpy_data_into_strict_json():
    """One helper for the certificate and the bench output: numpy scalars/arrays to Python, tuples to
    lists, keys to strings, NaN/inf to None (strict JSON has no non-finite numbers)."""
    out = jsonable({1: (np.float64(np.nan), np.int64(3), np.bool_(True), np.array([1.5, -np.inf]), "x")})
    assert out == {"1": [None, 3, True, [1.5, None], "x"]}
    assert [type(v) for v in out["1"][:3]] == [type(None), int, bool]
    assert json.loads(json.dumps(out, allow_nan=False)) == out
