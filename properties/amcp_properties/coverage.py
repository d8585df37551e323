"""Coverage of the generated runs: did the suite reach the interesting cases?

For every run the suite records whether a constraint of Z was active (max_k max_i of
F x_k + G u_k within :data:`ACTIVE_TOL` of 1), whether Θ_k shrank, how close θ* came to the
boundary of Θ_k, and the generator's labels (Θ and W kind, θ* kind, x0 kind, disturbance, ...).
The hard cases are measured from the run, not taken from the labels: whether some Θ_k
is lower-dimensional (the Chebyshev radius of the last Θ_k, k >= 1, with rows of unit norm, is at
most :data:`amcp_drake.studies.random_problems.LOWER_DIM_TOL` = 1e-5, ten times the controller's 1e-6
widening of Δ_k; the sets are nested by Lemma 3, so
the last is the thinnest), and whether θ* sits on a vertex of Θ (the rows of H_θ active at θ*,
normalised slack <= 1e-9, span R^p) or on ∂Θ elsewhere ("facet": a face of dimension >= 1).
Each feature is reported with ``hypothesis.event`` (see ``--hypothesis-show-statistics``) and
collected by a :class:`CoverageRecorder`, whose summary the suite prints and writes as JSON
(``AMCP_COVERAGE_FILE``) for ``amcp verify``.
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hypothesis import event

from amcp_drake.online.answers import counts as answer_counts
from amcp_drake.studies.random_problems import (
    LOWER_DIM_TOL,
    SHRINK_TOL,
    built_scaled,
    last_theta_k_radius,
    theta_shrank,
    theta_star_face,
)

#: A constraint row of Z is "active" when F x + G u >= 1 − ACTIVE_TOL at some step.
ACTIVE_TOL = 1e-3
#: θ* is "on the boundary" of Θ_k when its distance to it is below this, "near" below NEAR_TOL.
ON_BOUNDARY_TOL = 1e-6
NEAR_TOL = 1e-2

#: Coverage fractions reported per test (feature name -> description).
FEATURES = {
    "constraints_active": f"a row of Z active (F x + G u >= 1 - {ACTIVE_TOL:g})",
    "theta_shrank": f"Θ_k shrank below Θ_0 (a vertex of Θ_0 cut off by > {SHRINK_TOL:g})",
    "theta_star_on_boundary": f"θ* within {ON_BOUNDARY_TOL:g} of ∂Θ_k",
    "theta_star_near_boundary": f"θ* within {NEAR_TOL:g} of ∂Θ_k",
    "completed": "the run completed every step",
    "theta_k_lower_dim": f"some Θ_k lower-dimensional (Chebyshev radius <= {LOWER_DIM_TOL:g})",
    "theta_star_vertex": "θ* at a vertex of Θ",
    "theta_star_facet": "θ* on ∂Θ, not at a vertex",
    "scaled_units": "the problem in badly scaled state units (generator flag scaled_states, by construction)",
}


@dataclass
class RunFeatures:
    """What one closed-loop run covered."""

    constraints_active: bool
    max_constraint: float
    theta_shrank: bool
    theta_star_distance: float
    completed: bool
    labels: dict = field(default_factory=dict)
    #: Chebyshev radius of the last Θ_k (nan: not measured, e.g. no update recorded)
    theta_k_radius: float = float("nan")
    #: "vertex", "facet", "interior" ("" : not measured)
    theta_star_face: str = ""
    #: how the run's solver answers were obtained (amcp_drake.online.answers.counts)
    answers: dict = field(default_factory=dict)

    def flags(self) -> dict[str, bool]:
        """Feature -> covered; features that were not measured for this run are left out."""
        out = {"constraints_active": self.constraints_active, "theta_shrank": self.theta_shrank,
               "theta_star_on_boundary": self.theta_star_distance <= ON_BOUNDARY_TOL,
               "theta_star_near_boundary": self.theta_star_distance <= NEAR_TOL,
               "completed": self.completed}
        if not np.isnan(self.theta_k_radius):
            out["theta_k_lower_dim"] = bool(self.theta_k_radius <= LOWER_DIM_TOL)
        if built_scaled(self.labels) is not None:
            out["scaled_units"] = built_scaled(self.labels)
        if self.theta_star_face in ("vertex", "facet", "interior"):
            out["theta_star_vertex"] = self.theta_star_face == "vertex"
            out["theta_star_facet"] = self.theta_star_face == "facet"
        return out


def features(traj, labels: dict | None = None) -> RunFeatures:
    """The coverage features of a trajectory (numpy only)."""
    pr = traj.problem
    steps = len(traj.u)
    if steps:
        values = traj.x[:steps] @ pr.F.T + traj.u @ pr.G.T
        max_constraint = float(np.max(values))
    else:
        max_constraint = float("nan")
    distance = np.inf
    for r in traj.records:
        norms = np.linalg.norm(r.H_theta, axis=1)
        distance = min(distance, float(np.min((r.h_theta - r.H_theta @ traj.theta_star) / norms)))
    return RunFeatures(constraints_active=bool(max_constraint >= 1.0 - ACTIVE_TOL), max_constraint=max_constraint,
                       theta_shrank=theta_shrank(traj), theta_star_distance=max(distance, 0.0),
                       completed=traj.stop_reason == "completed", labels=dict(labels or {}),
                       theta_k_radius=last_theta_k_radius(traj), theta_star_face=theta_star_face(pr, traj.theta_star),
                       answers=answer_counts(traj.records))


def _bucket(distance: float) -> str:
    for limit in (ON_BOUNDARY_TOL, 1e-3, NEAR_TOL, 1e-1):
        if distance <= limit:
            return f"<= {limit:g}"
    return "> 0.1"


def emit_events(f: RunFeatures) -> None:
    """Report the features as Hypothesis events (call inside a test)."""
    event(f"Z active: {f.constraints_active}")
    event(f"Theta_k shrank: {f.theta_shrank}")
    event(f"theta* distance to boundary of Theta_k: {_bucket(f.theta_star_distance)}")
    flags = f.flags()
    if "theta_k_lower_dim" in flags:
        event(f"Theta_k lower-dimensional: {flags['theta_k_lower_dim']}")
    if f.theta_star_face:
        event(f"theta* in Theta: {f.theta_star_face}")
    for key in ("Theta", "W", "theta_star", "x0", "disturbance", "pin"):
        if key in f.labels:
            event(f"{key}: {f.labels[key]}")


class CoverageRecorder:
    """Per-test counts of examples and covered features (one instance per pytest session)."""

    def __init__(self) -> None:
        self.examples: Counter[str] = Counter()
        self.flags: dict[str, Counter[str]] = defaultdict(Counter)
        self.measured: dict[str, Counter[str]] = defaultdict(Counter)  # runs on which a feature was measured
        self.labels: dict[str, Counter[str]] = defaultdict(Counter)
        #: backend -> problem -> Counter of answers per outcome and kind, over every recorded run
        self.answers: dict[str, dict[str, Counter[str]]] = defaultdict(lambda: defaultdict(Counter))

    def record(self, test: str, f: RunFeatures) -> None:
        self.examples[test] += 1
        backend = test.rpartition("[")[2].rstrip("]") if "[" in test else "?"
        for problem, per in f.answers.items():
            self.answers[backend][problem].update(per)
        for name, value in f.flags().items():
            self.flags[test][name] += int(value)
            self.measured[test][name] += 1
        for key, value in f.labels.items():
            self.labels[test][f"{key}={value}"] += 1

    def count(self, test: str) -> None:
        """Count an example of a test that has no closed-loop run (e.g. Assumption 11)."""
        self.examples[test] += 1

    def summary(self) -> dict[str, dict]:
        """test -> {"examples": n, "fractions": {feature: fraction}, "labels": {label: count}}; a
        feature's fraction is over the runs on which it was measured (absent when none)."""
        out = {}
        for test, n in self.examples.items():
            measured = self.measured.get(test, {})
            fractions = {k: self.flags[test][k] / measured[k] for k in FEATURES if measured.get(k)}
            out[test] = {"examples": n, "fractions": fractions, "labels": dict(self.labels.get(test, {}))}
        return out

    def to_state(self) -> dict:
        """Every count as plain JSON data (sent from a pytest-xdist worker to the controller)."""
        return {"examples": dict(self.examples),
                "flags": {t: dict(c) for t, c in self.flags.items()},
                "measured": {t: dict(c) for t, c in self.measured.items()},
                "labels": {t: dict(c) for t, c in self.labels.items()},
                "answers": {b: {p: dict(c) for p, c in per.items()} for b, per in self.answers.items()}}

    def add_state(self, state: dict) -> None:
        """Add the counts of another recorder's :meth:`to_state` (every count is a sum)."""
        self.examples.update(state["examples"])
        for name in ("flags", "measured", "labels"):
            mine = getattr(self, name)
            for test, counts in state[name].items():
                mine[test].update(counts)
        for backend, per in state["answers"].items():
            for problem, counts in per.items():
                self.answers[backend][problem].update(counts)

    def write_json(self, path: str | Path, extra: dict | None = None) -> None:
        data = {"tests": self.summary(), "features": FEATURES,
                "answers": {b: {p: dict(c) for p, c in per.items()} for b, per in self.answers.items()}}
        data.update(extra or {})
        Path(path).write_text(json.dumps(data, indent=1, sort_keys=True))


def dimension_line(by_dimension: dict[int, tuple[int, int]], summary: dict[str, dict],
                   refused: dict[int, tuple[int, int]] | None = None) -> str:
    """"state dimension n: draws (accepted) / refused / runs" for every n drawn: the generator's design
    attempts and accepted problems, the closed-loop cases refused before their run by the memory
    estimate (``refused``: n -> (cases sized, refused)), and the examples of every test whose problem had
    n states (labels "n=...")."""
    runs: dict[int, int] = {}
    for data in summary.values():
        for label, count in data.get("labels", {}).items():
            if label.startswith("n="):
                runs[int(label[2:])] = runs.get(int(label[2:]), 0) + count
    refused = refused or {}
    dims = sorted(set(by_dimension) | set(runs) | set(refused))
    cells = [f"n={n}: {by_dimension.get(n, (0, 0))[0]} ({by_dimension.get(n, (0, 0))[1]}) / "
             f"{refused.get(n, (0, 0))[1]} / {runs.get(n, 0)}" for n in dims]
    return ("state dimension n: draws (accepted) / refused by the run's memory estimate / runs of all tests: "
            + (", ".join(cells) or "none"))


def refusal_line(refused: dict[int, tuple[int, int]], limit_mb: float) -> str:
    """The closed-loop cases refused before their run (``refused``: n -> (cases sized, refused)), in total
    and per n, with the rate."""
    sized = sum(s for s, _ in refused.values())
    count = sum(r for _, r in refused.values())
    rate = f"{count / sized:.1%}" if sized else "-"
    per_n = ", ".join(f"n={n}: {r} of {s}" for n, (s, r) in sorted(refused.items()))
    return (f"runs refused before they started (estimated memory above {limit_mb:g} MiB): {count} of {sized} "
            f"closed-loop cases ({rate}); by n: {per_n or 'none'}")
