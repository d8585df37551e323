"""Design outcome of the generator's problems in badly scaled state units and of their unscaled twins.

Draw ``k`` of a seed: ``random_shape`` then ``random_problem`` from ``default_rng([seed, k])`` (the
generator's probabilities, its fixed mrpi template and facet count), once with ``scaled_states``
forced on and once forced off from the same generator state: ``random_problem`` draws the unit
exponents last, so the two are the same system in units x̃ = T x and x (``scale_states``). Both are
designed with ``design()`` (what ``random_case`` and the campaign call) on each backend; the line
per draw gives the outcome (pass, or the error class and the template's reason) and, when both
design, max |K̃T − K| / max |K| (0 up to the solvers' accuracy when the design is covariant).

    PYTHONPATH=.:reference:properties python benchmarks/units_twins.py SEED START COUNT [BACKENDS] > out.txt

Run it on two trees (before/after) and compare the summaries printed at the end. Designs only, no
closed loop.
"""

from __future__ import annotations

import collections
import copy
import sys
import time
from dataclasses import replace

import numpy as np

from amcp_drake.model.errors import DesignError
from amcp_drake.offline.design import design
from amcp_drake.studies.random_problems import random_problem, random_shape


def outcome(spec, backend: str):
    """(label, design or None, CPU seconds)."""
    start = time.process_time()
    try:
        return "pass", design(spec.problem, spec.design, backend=backend), time.process_time() - start
    except DesignError as exc:
        reason = getattr(exc, "reason", "")
        return f"{type(exc).__name__}" + (f" ({reason})" if reason else ""), None, time.process_time() - start


def twin_draw(seed: int, k: int):
    """Draw k of ``seed``: (the problem in badly scaled units, its unscaled twin, T, labels); the twins
    come from the same generator state, so they are the same system in units x̃ = diag(T) x."""
    rng = np.random.default_rng([seed, k])
    shape = random_shape(rng)
    twin_rng = copy.deepcopy(rng)
    scaled, labels = random_problem(rng, replace(shape, scaled_states=True))
    plain, _ = random_problem(twin_rng, replace(shape, scaled_states=False))
    T = np.array([10.0 ** int(e[2:]) for e in labels["state scaling"].split(", ")])
    return scaled, plain, T, labels


def main(seed: int, start: int, count: int, backends: tuple[str, ...]) -> None:
    tally = {b: collections.Counter() for b in backends}
    for k in range(start, start + count):
        scaled, plain, T, labels = twin_draw(seed, k)
        for b in backends:
            o_s, d_s, t_s = outcome(scaled, b)
            o_u, d_u, t_u = outcome(plain, b)
            tally[b][("scaled", o_s)] += 1
            tally[b][("twin", o_u)] += 1
            dK = ""
            if d_s is not None and d_u is not None:
                dK = f"dK {np.max(np.abs(d_s.K * T[None, :] - d_u.K)) / np.max(np.abs(d_u.K)):.1e}"
            print(k, b, f"n={plain.problem.n}", labels["state scaling"], "| scaled:", o_s, f"{t_s:.1f}s", "| twin:", o_u,
                  f"{t_u:.1f}s", dK, flush=True)
    for b in backends:
        print(f"== {b}: {count} draws")
        for (which, o), c in sorted(tally[b].items()):
            print(f"  {which:6s} {o:40s} {c}")


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]), int(args[1]), int(args[2]), tuple(args[3].split(",")) if len(args) > 3 else ("drake",))
