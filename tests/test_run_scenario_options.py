"""``run_scenario(..., backend_options=...)``: the backend's constructor options reach every solve of the run
(the hook of the shipped-answers property under other Clarabel settings), and ``formulation`` is refused there
(it is its own argument)."""

from __future__ import annotations

import pytest

from amcp_drake.model.errors import ProblemError
from amcp_drake.online import answers
from amcp_drake.online.replay import run_scenario


def _tube_outcomes(traj) -> list[str]:
    return [(answers.of(r, "tube_qp") or {"outcome": "none"})["outcome"] for r in traj.records]


def test_solver_options_reach_the_tube_qp(example_spec, example_design):
    """One Clarabel iteration answers no tube QP (20) of either form (every retry keeps the user's
    max_iter); without options the same step is the backend's first answer: the options were passed."""
    plain = run_scenario(example_spec, "drake", offline=example_design, steps=1)
    assert _tube_outcomes(plain) == ["first"] * len(plain.records)
    starved = run_scenario(example_spec, "drake", offline=example_design, steps=1,
                           backend_options={"solver_options": {"max_iter": 1}})
    assert "first" not in _tube_outcomes(starved)[:1]


def test_formulation_in_backend_options_is_refused(example_spec, example_design):
    with pytest.raises(ProblemError) as err:
        run_scenario(example_spec, "drake", offline=example_design, steps=1,
                     backend_options={"formulation": "vertex"})
    assert err.value.field == "backend_options"
    assert "'vertex'" in err.value.received
