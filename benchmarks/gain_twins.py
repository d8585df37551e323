"""The gain LMI (16) alone on the generator's problems and their unscaled twins: every solve of the ladder.

The draws of ``benchmarks/units_twins.py`` (``random_shape`` then ``random_problem`` from
``default_rng([seed, k])``, once with ``scaled_states`` forced on and once off), each put into the
state units normalised by W as ``design()`` does (``offline/units.py``), then only the gain LMI that
the design would solve there (``gain_R_scale`` and ``lmi_margin`` of the draw's options), on each
backend. Per draw and backend the line lists each solve of the shared ladder
(``gain_scaling.solve_scaled``), ``T`` the tight first try, ``D`` the backend's own options, with the
solver's status (``ok`` optimal, ``inacc`` inaccurate; an "optimal" that fails the (16) re-check is
still listed as ``ok`` and followed by the next solve), and, when both twins give a gain,
max |K̃T − K| / max |K| in the user's units (the twins are the same system in x̃ = T x, and their
normalised problems differ by a common factor only, so this is 0 up to the solves' accuracy). A
summary per backend follows: gains rejected, accepted at the first try, solves, outcome differing
from the twin, and the largest and median relative difference.

    PYTHONPATH=.:reference:properties python benchmarks/gain_twins.py SEED START COUNT [BACKENDS] > out.txt

Seconds per draw, against ~1 s for a design (no templates, no terminal set). Used for docs/decisions.md,
"The cvxpy gain LMI in Drake's form".
"""

from __future__ import annotations

import sys

import numpy as np
from units_twins import twin_draw  # noqa: E402 - benchmarks/ is sys.path[0] when run as a script

from amcp_drake.backends import get_backend
from amcp_drake.offline import units

_LABELS = {"optimal": "ok", "optimal_inaccurate": "inacc"}


def normalised_gain_data(spec):
    """(A_v, B_v, Q, c R, margin, s) of the gain LMI ``design()`` solves for ``spec`` (ξ = diag(s) x)."""
    options = spec.design.validate_for(spec.problem)
    s = units.normalising_scales(spec.problem, options)
    problem = spec.problem
    if not units.is_identity(s):
        problem, options = units.to_normalised(spec.problem, options, s)
    theta = problem.theta_vertices()
    return (np.array([problem.A_of(t) for t in theta]), np.array([problem.B_of(t) for t in theta]),
            np.asarray(problem.Q, float), float(options.gain_R_scale) * np.asarray(problem.R, float),
            options.lmi_margin, s)


def logged_gain(backend: str, data, monkeypatch_target):
    """robust_gain of ``backend`` on ``data`` with each solve of the ladder logged: (GainResult, log)."""
    module, name = monkeypatch_target
    original = getattr(module, name)
    log = []

    def spy(*args):
        options = args[-1]
        result = original(*args)
        log.append(("T" if options else "D") + ":" + _LABELS.get(result[0].value, result[0].value))
        return result

    setattr(module, name, spy)
    try:
        A, B, Q, R, margin, _ = data
        return get_backend(backend).robust_gain(A, B, Q, R, margin), log
    finally:
        setattr(module, name, original)


def _target(backend: str):
    if backend == "drake":
        from amcp_drake.backends.drake_ import DrakeBackend
        return DrakeBackend, "_gain_lmi"
    import amcp_reference.offline as offline
    return offline, "_gain_lmi"


def main(seed: int, start: int, count: int, backends: tuple[str, ...]) -> None:
    summary = {b: {"rejected": 0, "first": 0, "solves": 0, "differ": 0, "dK": []} for b in backends}
    for k in range(start, start + count):
        scaled, plain, T, labels = twin_draw(seed, k)
        data = {"scaled": normalised_gain_data(scaled), "twin": normalised_gain_data(plain)}
        for b in backends:
            tally, K, logs = summary[b], {}, {}
            for which, d in data.items():
                gain, logs[which] = logged_gain(b, d, _target(b))
                tally["solves"] += len(logs[which])
                if gain.status.value == "optimal":
                    K[which] = gain.K @ np.diag(d[5])  # back to the user's units
                    tally["first"] += len(logs[which]) == 1
                else:
                    tally["rejected"] += 1
            dK = ""
            if len(K) == 2:
                rel = float(np.max(np.abs(K["scaled"] * T[None, :] - K["twin"])) / np.max(np.abs(K["twin"])))
                tally["dK"].append(rel)
                dK = f"dK {rel:.1e}"
            elif len(K) == 1:
                tally["differ"] += 1
            print(k, b, f"n={plain.problem.n}", labels["state scaling"], "| scaled:", " ".join(logs["scaled"]),
                  "| twin:", " ".join(logs["twin"]), dK, flush=True)
    for b in backends:
        t, dk = summary[b], np.array(summary[b]["dK"] or [np.nan])
        print(f"== {b}: {count} draws, {2 * count} gains: rejected {t['rejected']}, accepted at the first try "
              f"{t['first']}, solves {t['solves']}, outcome differs from the twin {t['differ']}; both give a gain "
              f"{len(t['dK'])}: max dK {np.max(dk):.1e}, median {np.median(dk):.1e}, above 1e-6 {int(np.sum(dk > 1e-6))}")


if __name__ == "__main__":
    args = sys.argv[1:]
    main(int(args[0]), int(args[1]), int(args[2]), tuple(args[3].split(",")) if len(args) > 3 else ("drake", "cvxpy"))
