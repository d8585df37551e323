"""pytest configuration of the property suite: profiles, the backend parameter, shared runs,
coverage summary.

* The Hypothesis profile is loaded from ``AMCP_PROFILE`` (:mod:`amcp_properties.profiles`).
* ``backend``: a session-scoped parameter over ``AMCP_BACKENDS`` (default ``drake,cvxpy``), so
  pytest groups the tests by backend and the memoised runs are reused. A backend that cannot
  be imported is skipped with the reason (visible in the ``-ra`` summary).
* ``runner``: the session's :class:`~amcp_properties.cases.Runner`; ``coverage``: its
  :class:`~amcp_properties.coverage.CoverageRecorder`, printed at the end of the session and
  written as JSON to ``AMCP_COVERAGE_FILE`` when set (:mod:`amcp_properties.session_summary`; under
  pytest-xdist the workers send their counts to the controller, which prints them: properties/conftest.py).
* Under pytest-xdist one worker runs every property test, so that they reuse their closed-loop runs
  (the scheduler of properties/conftest.py).
"""

from __future__ import annotations

import os

import pytest

from amcp_properties import profiles
from amcp_properties.session_summary import RECORDER as _RECORDER
from amcp_properties.session_summary import RUNNER as _RUNNER
from amcp_properties.session_summary import WORKER_OUTPUT_KEY, local_state, write_summary

PROFILE = profiles.load()
BACKENDS_ENV = "AMCP_BACKENDS"


def _backend_names() -> list[str]:
    names = [b.strip() for b in os.environ.get(BACKENDS_ENV, "drake,cvxpy").split(",") if b.strip()]
    return names or ["drake"]


def pytest_configure(config: pytest.Config) -> None:
    from amcp_properties.cases import Runner
    from amcp_properties.coverage import CoverageRecorder

    config.stash[_RECORDER] = CoverageRecorder()
    config.stash[_RUNNER] = Runner()


@pytest.fixture(scope="session", params=_backend_names())
def backend(request) -> str:
    """An online backend that can be imported, or a visible skip saying why not."""
    from amcp_drake.backends import get_backend
    from amcp_drake.model.errors import BackendNotFound

    try:
        get_backend(request.param)
    except (BackendNotFound, ImportError) as exc:
        pytest.skip(f"backend {request.param!r} is not importable yet: {exc}")
    return request.param


@pytest.fixture(scope="session")
def both_backends() -> tuple[str, str]:
    """Both backends for the lockstep comparison (skipped visibly unless both are selected and importable)."""
    from amcp_drake.backends import get_backend
    from amcp_drake.model.errors import BackendNotFound

    names = _backend_names()
    if not {"drake", "cvxpy"} <= set(names):
        pytest.skip(f"the lockstep comparison needs both backends; {BACKENDS_ENV} selects {names}")
    for name in ("drake", "cvxpy"):
        try:
            get_backend(name)
        except (BackendNotFound, ImportError) as exc:
            pytest.skip(f"backend {name!r} is not importable yet: {exc}")
    return ("drake", "cvxpy")


@pytest.fixture(scope="session")
def runner(request):
    return request.config.stash[_RUNNER]


@pytest.fixture(scope="session")
def coverage(request):
    return request.config.stash[_RECORDER]


def pytest_sessionfinish(session) -> None:
    """On a pytest-xdist worker: send this worker's counts to the controller."""
    workeroutput = getattr(session.config, "workeroutput", None)
    state = local_state(session.config)
    if workeroutput is not None and state is not None:
        import json

        workeroutput[WORKER_OUTPUT_KEY] = json.dumps(state)


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """The summary of a run in one process (a worker's terminal is not shown; the controller prints
    the workers' counts)."""
    if hasattr(config, "workeroutput"):
        return
    state = local_state(config)
    if state is not None:
        write_summary(terminalreporter, PROFILE, [state])
