"""Size checks that belong to the command (online/run_size.py): ``amcp design`` is never refused for the
size of a run it does not build; the run commands check the run in the form of (20) they will use.

The 10-state actuated chain (studies/chains.py, no design section) is the case: its plain-form run (15)
with the parallelotope the automatic design starts from (20 facets, 1024 vertices) is estimated at about
2.7 GiB, its vertex-form run at a few MiB. The design itself is replaced by a stub that records the call
(the size refusal, if any, happens before it), so that these tests do not depend on how long the design
of a 10-state system takes."""

from __future__ import annotations

import json

import pytest
from click.testing import CliRunner

from amcp_drake.cli import main
from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.model.limits import estimate_for
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.online.run_size import check_run_size, run_formulation
from amcp_drake.studies.chains import actuated_chain

#: The limit of these tests, in MiB: between the vertex-form and the plain-form estimate of the chain.
LIMIT_MB = 1024


class DesignReached(DesignError):
    """Raised by the stub design: the command got past every size check before the design."""


@pytest.fixture
def chain10(tmp_path):
    path = tmp_path / "chain10.json"
    path.write_text(json.dumps(actuated_chain(10)))
    return path


@pytest.fixture
def design_calls(monkeypatch):
    """Replace the offline design by a stub that records its calls and stops the command (exit 1)."""
    import amcp_drake.offline.design as module

    calls = []

    def stub(problem, options=None, backend="drake", budget=None):
        calls.append((problem.n, None if budget is None else budget.max_memory_mb))
        raise DesignReached("stub design reached")

    monkeypatch.setattr(module, "design", stub)
    return calls


def test_the_chain_is_a_case_where_the_plain_form_run_exceeds_the_limit(chain10):
    """The premise of the tests below: plain form above LIMIT_MB, vertex form below it (by more than 2x each)."""
    spec = spec_from_dict(actuated_chain(10))
    plain = estimate_for(spec.problem, spec.design, 1, None, formulation="plain").memory_bytes / 2**20
    vertex = estimate_for(spec.problem, spec.design, 1, None, formulation="vertex").memory_bytes / 2**20
    assert plain > 2 * LIMIT_MB and vertex < LIMIT_MB / 2


def test_design_of_a_10_state_file_is_not_refused_for_the_size_of_a_plain_form_run(chain10, design_calls):
    """`amcp design FILE --max-memory 1024` reaches the design, with the limit handed to the design's own
    budget; no "problem size" refusal (the former check refused it with exit 2 at 2.7 GiB)."""
    result = CliRunner().invoke(main, ["design", str(chain10), "--max-memory", str(LIMIT_MB)])
    assert design_calls == [(10, LIMIT_MB)], result.output
    assert result.exit_code == 1, result.output  # the stub's DesignError, not exit 2 (bad input)
    assert "problem size" not in result.output and "estimated memory" not in result.output


def test_run_in_the_plain_form_is_refused_at_that_limit_before_the_design(chain10, design_calls):
    """The same limit refuses `amcp run --formulation plain` (exit 2, naming the plain form's size and the
    option) before the design starts."""
    result = CliRunner().invoke(main, ["run", str(chain10), "--formulation", "plain", "--max-memory", str(LIMIT_MB)])
    assert result.exit_code == 2, result.output
    assert "problem size" in result.output and "tube QP (15)" in result.output and "--max-memory" in result.output
    assert design_calls == []


@pytest.mark.parametrize("command", [["run"], ["certify", "--out", "{tmp}/out"], ["coverage", "--no-progress", "--grid", "1",
                                                                                  "--out", "{tmp}/cov"]])
def test_run_commands_in_the_vertex_or_auto_form_pass_the_check_before_the_design(chain10, design_calls, tmp_path,
                                                                                 command):
    """run and certify with --formulation auto, coverage with its vertex default: the check before the design
    takes the form they will use, so they reach the design at the limit that refuses the plain form."""
    args = [a.replace("{tmp}", str(tmp_path)) for a in command]
    form = ["--formulation", "auto"] if command[0] != "coverage" else []
    result = CliRunner().invoke(main, [args[0], str(chain10), *form, "--max-memory", str(LIMIT_MB), *args[1:]])
    assert design_calls == [(10, LIMIT_MB)], result.output
    assert result.exit_code == 1 and "problem size" not in result.output, result.output


def test_auto_before_the_design_is_the_plain_form_when_an_option_needs_it():
    """Before the design, "auto" is the smaller estimate, except when an online option (min-max cost (19),
    d_θ > 0, PE) needs the plain form: then the plain form's size is checked, and refused at the limit."""
    spec = spec_from_dict(actuated_chain(10))
    pr = spec.problem
    assert run_formulation("auto", pr, None, OnlineOptions()) == "auto"
    assert run_formulation("auto", pr, None, OnlineOptions(cost="minmax")) == "plain"
    assert run_formulation("vertex", pr, None, OnlineOptions(cost="minmax")) == "vertex"  # as asked
    est = check_run_size(pr, spec.design, 1, OnlineOptions(), LIMIT_MB, formulation="auto")
    assert est.formulation == "vertex"
    with pytest.raises(ProblemError, match=r"tube QP \(15\)"):
        check_run_size(pr, spec.design, 1, OnlineOptions(cost="minmax"), LIMIT_MB, formulation="auto")


def test_auto_with_a_design_checks_the_form_the_controller_chooses(example_spec, example_design):
    """With a design, "auto" is resolved by the controller's own rule (formulation_choice.choose_formulation):
    Example 1's design runs in the vertex form, and the estimate is that form's."""
    from amcp_drake.online.formulation_choice import choose_formulation

    chosen = choose_formulation(example_spec.problem, example_design, example_spec.online).formulation
    assert run_formulation("auto", example_spec.problem, example_design, example_spec.online) == chosen
    est = check_run_size(example_spec.problem, example_spec.design, 10, example_spec.online, 2048,
                         design=example_design, formulation="auto")
    assert est.formulation == chosen and est.designed


@pytest.mark.parametrize(("factor", "refused"), [(0.5, True), (2.0, False)])
def test_the_design_is_refused_only_for_its_own_size(factor, refused):
    """`amcp design`'s own check (model/limits.check_design_size): X0's rows for design.x0_facets facets,
    8·u·n·(2 + t) bytes with t = 4 vertices of the chain's Θ (counted here from the box Θ = [-0.1, 0.1]²).
    A limit of half that estimate refuses (naming design.x0_facets and --max-memory), twice it passes."""
    from amcp_drake.model.limits import check_design_size

    facets = 200_000
    spec = spec_from_dict(actuated_chain(10, design_section={"x0_template": "mrpi", "x0_facets": facets}))
    nbytes = 8 * facets * 10 * (2 + 4)
    limit_mb = factor * nbytes / 2**20
    if refused:
        with pytest.raises(ProblemError, match=r"design size.*design\.x0_facets = 200000 facets.*--max-memory"):
            check_design_size(spec.problem, spec.design, limit_mb)
    else:
        assert check_design_size(spec.problem, spec.design, limit_mb) == nbytes
