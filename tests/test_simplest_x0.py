"""The automatic design prefers the simplest X0 that passes (offline/auto.py, docs/decisions.md "X0
templates and the automatic design"): the rounds and their caps, the order within and across rounds
(with stand-ins for the design and its checks, so that each outcome is chosen by the test), the facet cap
of a template at its edge, ``design.x0_max_facets`` in a problem file, and the 4-state cart-pole of
examples/own-system designing within 64 facets with every check passing."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest

from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.model.problem_io import load_spec, spec_from_dict
from amcp_drake.offline.auto import AutoDesignError, candidate_options, design_auto, round_caps, template_label
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design, design_fixed
from amcp_drake.offline.templates import TemplateError
from amcp_drake.studies.chains import actuated_chain

ROOT = Path(__file__).resolve().parents[1]
CARTPOLE = ROOT / "examples" / "own-system" / "cartpole.json"


def _spec(n: int, design_section: dict | None = None):
    return spec_from_dict(actuated_chain(n, design_section=design_section))


# -- the rounds ------------------------------------------------------------------------------------
@pytest.mark.parametrize(("n", "user", "caps"), [
    (2, None, [None]), (3, None, [None]), (3, 20, [20]),      # below n = 4: one round
    (4, None, [64, None]), (5, None, [80, None]),              # 16 n, then each template's own cap
    (4, 64, [64]), (4, 30, [30]),                              # a user cap at or below 16 n: one round
    (4, 65, [64, 65]),                                         # just above: the user's cap is the second round
])
def test_round_caps(n, user, caps):
    spec = _spec(n)
    assert round_caps(spec.problem, replace(spec.design, x0_max_facets=user)) == caps


# -- the order, with stand-ins for the design and its checks --------------------------------------
@dataclass(frozen=True)
class _Designed:
    """What design_auto reads of a design: the rows and vertices of X0 and its info."""

    H_x: np.ndarray
    X0_vertices: np.ndarray
    info: dict = field(default_factory=dict)


def _run(spec, sizes: dict, passes: set):
    """design_auto with a stand-in design: a candidate builds an X0 of ``sizes[label]`` or else
    ``sizes[kind]`` rows (absent or None: the template fails), refused as "too complex" when that is above its
    ``x0_max_facets``; its checks pass when ``k`` is in ``passes``. Returns (design, attempts' labels)."""
    n = spec.problem.n

    def design_fixed_stand_in(problem, options, backend=None, gain=None, budget=None):
        kind = options.x0_template
        label = template_label(options, dimension=n)
        rows = sizes.get(label, sizes.get(kind))  # by label first, then by kind
        if rows is None:
            raise TemplateError(kind, "diverged", "stand-in")
        if options.x0_max_facets is not None and rows > options.x0_max_facets:
            raise TemplateError(kind, "too complex", f"{rows} rows (cap {options.x0_max_facets})")
        return _Designed(np.ones((rows, n)), np.ones((3 * rows, n)), {"kind": kind})

    @dataclass
    class _Check:
        name: str
        passed: bool
        status: str = "pass"
        margin: float | None = None

    def verify(problem, d, bound):
        return [_Check("X0 contractive", d.info["kind"] in passes)]

    try:
        d = design_auto(spec.problem, spec.design, "drake", design_fixed_stand_in,
                        lambda *_: (None, None, "stand-in"), verify)
    except AutoDesignError as err:
        return None, [a.label for a in err.attempts]
    return d, [a["label"] for a in d.info["attempts"]]


def test_a_simple_candidate_later_in_the_order_beats_a_complex_one_earlier():
    """n = 4: the contractive candidates come before the preimage ones; a 100-row contractive X0 would
    pass, a 58-row preimage X0 passes too: the first round (cap 64) stops every contractive candidate
    and keeps the first preimage design."""
    spec = _spec(4)
    d, labels = _run(spec, {"contractive": 100, "preimage": 58}, passes={"contractive", "preimage"})
    assert len(d.H_x) == 58 and d.info["options"]["x0_template"] == "preimage"
    assert all(", at most 64 facets" in label for label in labels if label.startswith(("contractive", "preimage")))
    assert not any(label.startswith("contractive") and "at most" not in label for label in labels)  # no round 2


def test_cap_edge_64_rows_pass_in_the_first_round_65_wait_for_the_second():
    spec = _spec(4)
    d64, _ = _run(spec, {"contractive": 64, "preimage": 58}, passes={"contractive", "preimage"})
    assert d64.info["options"]["x0_template"] == "contractive" and len(d64.H_x) == 64
    d65, _ = _run(spec, {"contractive": 65, "preimage": 58}, passes={"contractive", "preimage"})
    assert d65.info["options"]["x0_template"] == "preimage" and len(d65.H_x) == 58


def test_no_system_loses_its_design_the_second_round_reruns_what_the_cap_stopped():
    """Only a 100-row contractive X0 passes: the first round's contractive candidates end "too
    complex", every other candidate fails; the second round reruns exactly the stopped ones (in the
    documented order, with their own caps) and keeps the first of them."""
    spec = _spec(4)
    d, labels = _run(spec, {"contractive": 100, "preimage": 80}, passes={"contractive"})
    assert len(d.H_x) == 100 and d.info["options"]["x0_template"] == "contractive"
    order = [template_label(c, dimension=4) for c in candidate_options(spec.problem, spec.design)]
    first_round = labels[:len(order)]
    assert [label.replace(", at most 64 facets", "") for label in first_round] == order
    second_round = labels[len(order):]
    assert second_round == [order[1]]  # the first contractive candidate, uncapped, passes at once


def test_mrpi_candidates_above_the_cap_wait_for_the_second_round():
    """n = 4 has no many-facet mrpi candidates; a user's x0_facets of 72 > 64 makes the first mrpi
    candidate one: left out of the first round, run (and kept) in the second."""
    spec = _spec(4, {"x0_facets": 72})
    d, labels = _run(spec, {"mrpi": 72}, passes={"mrpi"})
    assert len(d.H_x) == 72
    assert labels.count("mrpi, 72 facets") == 1 and labels[-1] == "mrpi, 72 facets"


def test_when_nothing_passes_every_attempt_of_both_rounds_is_listed():
    spec = _spec(4)
    d, labels = _run(spec, {"contractive": 100}, passes=set())
    order = candidate_options(spec.problem, spec.design)
    contractive = [c for c in order if c.x0_template == "contractive"]
    assert d is None and len(labels) == len(order) + len(contractive)


def test_below_four_states_one_round_keeps_the_first_passing_candidate():
    """n = 3: the first mrpi candidate fails, a 100-row contractive X0 passes and is kept although the
    many-facet mrpi candidates later in the order (here 20 rows) would pass too."""
    spec = _spec(3)
    d, labels = _run(spec, {"contractive": 100, "mrpi": 20, "mrpi, 8 facets": None}, passes={"contractive", "mrpi"})
    assert d.info["options"]["x0_template"] == "contractive" and len(d.H_x) == 100
    assert not any("at most" in label for label in labels)


# -- the cap of a real template at its edge --------------------------------------------------------
@pytest.mark.slow
def test_a_template_cap_at_its_edge_on_the_cartpole():
    """The cart-pole's preimage X0 (λ₀ 0.95, the LMI gain) has m rows: x0_max_facets = m designs the same
    X0, m - 1 ends the template as "too complex" naming the cap."""
    spec = load_spec(CARTPOLE)
    options = replace(spec.design, x0_template="preimage", x0_lambda=0.95)
    m = len(design_fixed(spec.problem, options).H_x)
    assert m <= 64
    assert len(design_fixed(spec.problem, replace(options, x0_max_facets=m)).H_x) == m
    with pytest.raises(TemplateError, match=f"too complex: .*cap {m - 1}"):
        design_fixed(spec.problem, replace(options, x0_max_facets=m - 1))


# -- the problem file ------------------------------------------------------------------------------
@pytest.mark.parametrize("value", [7, 0, 2.5, True, "64"])
def test_x0_max_facets_below_2n_or_not_an_integer_is_refused_naming_the_field(value):
    with pytest.raises(ProblemError, match="design.x0_max_facets") as err:
        _spec(4, {"x0_max_facets": value}).design.validate_for(_spec(4).problem)
    if value == 7:  # an integer the schema allows, below 2n = 8 (the bound of design.x0_facets too)
        assert "expected an integer >= 8; received 7" in str(err.value)


def test_x0_max_facets_at_2n_is_accepted():
    spec = _spec(4, {"x0_max_facets": 8})
    assert spec.design.validate_for(spec.problem).x0_max_facets == 8


# -- the cart-pole ---------------------------------------------------------------------------------
@pytest.mark.slow
def test_the_cartpole_designs_within_64_facets_and_passes_every_check():
    """examples/own-system/cartpole.json (continuous time, bounds by name, 4 states): the automatic
    design's X0 has at most 64 facets, and the independent checks (numpy/scipy) pass in the file's units."""
    spec = load_spec(CARTPOLE)
    assert "design" not in json.loads(CARTPOLE.read_text())
    d = design(spec.problem, spec.design)
    assert len(d.H_x) <= 64
    assert [c.name for c in verify_design(spec.problem, d, spec.design.mu_state_bound) if not c.passed] == []
    assert d.info["attempts"][-1]["outcome"] == "pass"


def test_design_errors_of_a_stand_in_are_recorded_not_raised():
    """A DesignError of any kind ends a candidate, never the design: the next candidate runs."""
    spec = _spec(4)
    calls = []

    def failing(problem, options, backend=None, gain=None, budget=None):
        calls.append(options.x0_template)
        raise DesignError("stand-in failure")

    with pytest.raises(AutoDesignError):
        design_auto(spec.problem, spec.design, "drake", failing, lambda *_: (None, None, "x"), lambda *a: [])
    assert len(calls) == len(candidate_options(spec.problem, spec.design))
