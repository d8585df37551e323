"""The property suite's summary on the pytest-xdist controller.

The controller runs no test and does not load ``amcp_properties/conftest.py``; this conftest (an
initial conftest of the ``properties`` test path) collects the counts each worker sends at its end and
prints the one summary of :mod:`amcp_properties.session_summary`. Without xdist it does nothing.
"""

from __future__ import annotations

import json

import pytest

_STATES = pytest.StashKey[list]()


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error) -> None:
    from amcp_properties.session_summary import WORKER_OUTPUT_KEY

    data = getattr(node, "workeroutput", {}).get(WORKER_OUTPUT_KEY)
    if data:
        node.config.stash.setdefault(_STATES, []).append(json.loads(data))


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    states = config.stash.get(_STATES, None)
    if states:
        from amcp_properties import profiles
        from amcp_properties.session_summary import write_summary

        write_summary(terminalreporter, profiles.name(), states)
