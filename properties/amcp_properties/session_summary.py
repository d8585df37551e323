"""The property suite's end-of-session summary, in one process or across pytest-xdist workers.

The suite's coverage (:class:`~amcp_properties.coverage.CoverageRecorder`), the generator's statistics
(:data:`~amcp_properties.strategies.GENERATOR_STATS`) and the closed-loop run cache's counts live in
the process that runs the tests. Run with pytest-xdist (``make test`` runs ``pytest -n 2``), each
worker sends them to the controller as plain JSON data in ``workeroutput`` (:func:`local_state`), the
controller adds them up (:func:`merged`) and prints one summary (:func:`write_summary`); run in one
process, the same summary is printed from the local counts.
"""

from __future__ import annotations

import os

import pytest

#: Key of the worker's data in pytest-xdist's ``workeroutput``.
WORKER_OUTPUT_KEY = "amcp_property_coverage"
#: ``AMCP_COVERAGE_FILE``: where the summary is also written as JSON (``amcp verify`` reads it).
COVERAGE_FILE_ENV = "AMCP_COVERAGE_FILE"
RECORDER = pytest.StashKey()
RUNNER = pytest.StashKey()


def local_state(config: pytest.Config) -> dict | None:
    """This process's counts as JSON data, or None when it ran no property test."""
    from amcp_properties.strategies import GENERATOR_STATS

    if RECORDER not in config.stash or not config.stash[RECORDER].examples:
        return None
    runner = config.stash[RUNNER]
    return {"recorder": config.stash[RECORDER].to_state(), "generator": GENERATOR_STATS.to_state(),
            "runs": {"simulated": runner.misses, "reused": runner.hits}}


def merged(states: list[dict]):
    """(recorder, generator statistics, simulated runs, reused runs) summed over ``states``."""
    from amcp_properties.coverage import CoverageRecorder
    from amcp_properties.strategies import GeneratorStats

    recorder, stats, simulated, reused = CoverageRecorder(), GeneratorStats(), 0, 0
    for state in states:
        recorder.add_state(state["recorder"])
        stats.add_state(state["generator"])
        simulated += state["runs"]["simulated"]
        reused += state["runs"]["reused"]
    return recorder, stats, simulated, reused


def write_summary(terminalreporter, profile: str, states: list[dict]) -> None:
    """Print the coverage table, the generator's statistics and the run counts of ``states`` (and
    write them as JSON to ``AMCP_COVERAGE_FILE`` when set)."""
    from amcp_properties.cases import RUN_MEMORY_MB
    from amcp_properties.coverage import dimension_line, refusal_line

    recorder, stats, simulated, reused = merged(states)
    summary = recorder.summary()
    if not summary:
        return
    tr = terminalreporter
    tr.section(f"amcp property coverage (profile {profile})")
    tr.write_line(f"{'test':70s} {'examples':>8s}  {'Z act':>6s} {'Θ shr':>6s} {'θ*∂':>6s} {'θ*≈∂':>6s} {'done':>6s}"
                  f" {'Θk↓d':>6s} {'θ*vx':>6s} {'θ*fc':>6s} {'scaled':>6s}")
    for test, data in sorted(summary.items()):
        fr = data["fractions"]
        cells = " ".join(f"{fr[k]:6.2f}" if k in fr else f"{'-':>6s}" for k in
                         ("constraints_active", "theta_shrank", "theta_star_on_boundary", "theta_star_near_boundary",
                          "completed", "theta_k_lower_dim", "theta_star_vertex", "theta_star_facet", "scaled_units"))
        tr.write_line(f"{test[-70:]:70s} {data['examples']:8d}  {cells}")
    rate = stats.rejection_rate()
    distinct = stats.distinct_rejection_rate()
    tr.write_line(f"generator: {len(stats.distinct)} distinct problems, {distinct:.1%} rejected by the design "
                  f"({stats.attempts} draws, {rate:.1%} rejected); by reason: "
                  + ", ".join(f"{k[10:]}={v}" for k, v in sorted(stats.counts.items()) if k.startswith("rejected:")))
    refused = stats.refused_by_dimension()
    tr.write_line(dimension_line(stats.by_dimension(), summary, refused))
    tr.write_line(refusal_line(refused, RUN_MEMORY_MB))
    tr.write_line("Θk↓d = some Θ_k lower-dimensional (Chebyshev radius <= 1e-5); θ*vx / θ*fc = θ* at a vertex / "
                  "elsewhere on ∂Θ; scaled = in badly scaled state units (fractions of the runs)")
    workers = f" in {len(states)} worker processes" if len(states) > 1 else ""
    tr.write_line(f"closed-loop runs: {simulated} simulated, {reused} reused from the cache{workers}")
    path = os.environ.get(COVERAGE_FILE_ENV)
    if path:
        recorder.write_json(path, {"profile": profile, "generator": dict(stats.counts),
                                   "rejection_rate": rate, "distinct_problems": len(stats.distinct),
                                   "distinct_rejection_rate": distinct,
                                   "runs": {"simulated": simulated, "reused": reused},
                                   "refusal_rate": stats.refusal_rate(), "run_memory_mb": RUN_MEMORY_MB,
                                   "by_dimension": {str(n): {"draws": d, "accepted": a,
                                                             "cases": refused.get(n, (0, 0))[0],
                                                             "refused": refused.get(n, (0, 0))[1]}
                                                    for n, (d, a) in stats.by_dimension().items()}})
