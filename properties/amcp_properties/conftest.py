"""pytest configuration of the property suite: profiles, the backend parameter, shared runs,
coverage summary.

* The Hypothesis profile is loaded from ``AMCP_PROFILE`` (:mod:`amcp_properties.profiles`).
* ``backend``: a session-scoped parameter over ``AMCP_BACKENDS`` (default ``drake,cvxpy``), so
  pytest groups the tests by backend and the memoised runs are reused. A backend that cannot
  be imported is skipped with the reason (visible in the ``-ra`` summary).
* ``runner``: the session's :class:`~amcp_properties.cases.Runner`; ``coverage``: its
  :class:`~amcp_properties.coverage.CoverageRecorder`, printed at the end of the session and
  written as JSON to ``AMCP_COVERAGE_FILE`` when set.
"""

from __future__ import annotations

import os

import pytest

from amcp_properties import profiles

PROFILE = profiles.load()
BACKENDS_ENV = "AMCP_BACKENDS"
COVERAGE_FILE_ENV = "AMCP_COVERAGE_FILE"
_RECORDER = pytest.StashKey()
_RUNNER = pytest.StashKey()


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


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    from amcp_properties.strategies import GENERATOR_STATS

    if _RECORDER not in config.stash:
        return
    recorder = config.stash[_RECORDER]
    summary = recorder.summary()
    if not summary:
        return
    tr = terminalreporter
    tr.section(f"amcp property coverage (profile {PROFILE})")
    tr.write_line(f"{'test':70s} {'examples':>8s}  {'Z act':>6s} {'Θ shr':>6s} {'θ*∂':>6s} {'θ*≈∂':>6s} {'done':>6s}"
                  f" {'Θk↓d':>6s} {'θ*vx':>6s} {'θ*fc':>6s} {'scaled':>6s}")
    for test, data in sorted(summary.items()):
        fr = data["fractions"]
        cells = " ".join(f"{fr[k]:6.2f}" if k in fr else f"{'-':>6s}" for k in
                         ("constraints_active", "theta_shrank", "theta_star_on_boundary", "theta_star_near_boundary",
                          "completed", "theta_k_lower_dim", "theta_star_vertex", "theta_star_facet", "scaled_units"))
        tr.write_line(f"{test[-70:]:70s} {data['examples']:8d}  {cells}")
    stats = GENERATOR_STATS
    rate = stats.rejection_rate()
    distinct = stats.distinct_rejection_rate()
    tr.write_line(f"generator: {len(stats.distinct)} distinct problems, {distinct:.1%} rejected by the design "
                  f"({stats.attempts} draws, {rate:.1%} rejected); by reason: "
                  + ", ".join(f"{k[10:]}={v}" for k, v in sorted(stats.counts.items()) if k.startswith("rejected:")))
    from amcp_properties.coverage import dimension_line

    tr.write_line(dimension_line(stats.by_dimension(), summary))
    tr.write_line("Θk↓d = some Θ_k lower-dimensional (Chebyshev radius <= 1e-5); θ*vx / θ*fc = θ* at a vertex / "
                  "elsewhere on ∂Θ; scaled = in badly scaled state units (fractions of the runs)")
    run_cache = config.stash[_RUNNER]
    tr.write_line(f"closed-loop runs: {run_cache.misses} simulated, {run_cache.hits} reused from the cache")
    path = os.environ.get(COVERAGE_FILE_ENV)
    if path:
        recorder.write_json(path, {"profile": PROFILE, "generator": dict(stats.counts),
                                   "rejection_rate": rate, "distinct_problems": len(stats.distinct),
                                   "distinct_rejection_rate": distinct, "runs": {"simulated": run_cache.misses,
                                                                    "reused": run_cache.hits},
                                   "by_dimension": {str(n): {"draws": d, "accepted": a}
                                                    for n, (d, a) in stats.by_dimension().items()}})

