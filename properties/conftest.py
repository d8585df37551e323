"""The property suite under pytest-xdist: one worker for all of it, and its summary on the controller.

The controller runs no test and does not load ``amcp_properties/conftest.py``; this conftest (an
initial conftest of the ``properties`` test path) gives the controller

* a scheduler for ``--dist loadgroup`` that puts every test below ``properties/`` in one work unit, so
  that one worker runs them in order and they share their closed-loop runs and coverage counts (the
  tests below ``tests/`` are spread one by one). It does not rely on ``xdist_group`` marks: pytest-xdist
  3.8 applies them by rewriting ``item._nodeid``, which pytest 9.2 no longer reads;
* the one summary of :mod:`amcp_properties.session_summary`, from the counts each worker sends at its end.

Without xdist it does nothing.
"""

from __future__ import annotations

import json

import pytest

_STATES = pytest.StashKey[list]()
#: The work unit of every property test under ``--dist loadgroup``.
PROPERTY_GROUP = "amcp-properties"


def property_scope(nodeid: str) -> str | None:
    """The work unit of a node id below ``properties/`` (None for any other test)."""
    return PROPERTY_GROUP if nodeid.startswith("properties/") else None


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    if config.getvalue("dist") != "loadgroup":
        return None
    from xdist.scheduler import LoadGroupScheduling

    class PropertySuiteInOneWorker(LoadGroupScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return property_scope(nodeid) or super()._split_scope(nodeid)

    return PropertySuiteInOneWorker(config, log)


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
