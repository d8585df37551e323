"""The 5-mass chain (n = 10, m = 5, p = 4; the generator of the built-in mass_chain3/4) designs at default
settings (the automatic mode, no design section) and its design passes every independent check."""

from __future__ import annotations

import pytest

from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.offline.checks import verify_design
from amcp_drake.offline.design import design
from amcp_drake.studies.chains import mass_chain


@pytest.mark.slow
def test_the_five_mass_chain_designs_at_default_settings_and_passes_every_design_check():
    data = mass_chain(5, steps=10)
    assert "design" not in data
    spec = spec_from_dict(data)
    d = design(spec.problem, spec.design, backend="drake")
    assert [c.name for c in verify_design(spec.problem, d, spec.design.mu_state_bound) if not c.passed] == []
    assert d.H_x.shape == (20, 10) and len(d.X0_vertices) == 2 ** 10
