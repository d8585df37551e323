"""Failing examples as replayable files.

When a claim fails on the final (shrunk) example, :func:`require` writes into
``$AMCP_FAILURE_DIR/<test>-<backend>-<hash>/`` (default ``./amcp-failures``):

* ``problem.json``: the problem, design options and scenario (:func:`amcp_drake.model.problem_io.save_spec`);
* ``trajectory.json.gz``: the recorded run with the design and the exact disturbance sequence
  (:meth:`amcp_drake.online.simulate.Trajectory.save`; ``amcp certify --trajectory`` re-checks it);
* ``design.json``: the offline design, for a failure without a run (Assumption 11);
* ``claim.txt``: the claim, its margin, tolerance and where it failed, and how to replay.

:func:`replay` re-runs a saved failure on a backend: ``python -m amcp_properties.failures DIR``.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np

from amcp_drake.model.check_result import CheckResult
from amcp_drake.model.problem_io import load_spec, save_spec, spec_to_dict, write_json_atomic
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate

FAILURE_DIR_ENV = "AMCP_FAILURE_DIR"
DEFAULT_FAILURE_DIR = "amcp-failures"


def failure_dir() -> Path:
    return Path(os.environ.get(FAILURE_DIR_ENV, DEFAULT_FAILURE_DIR))


def _is_final() -> bool:
    """True while Hypothesis replays the final (minimal) failing example (or outside Hypothesis)."""
    try:
        from hypothesis.control import current_build_context

        return bool(current_build_context().is_final)
    except Exception:  # noqa: BLE001 - no build context: not inside a Hypothesis test
        return True


def save_failure(test: str, backend: str, result: CheckResult, case=None, traj: Trajectory | None = None,
                 spec=None, design=None) -> Path:
    """Write the files of a failing example (see module docstring); returns the directory.

    ``case`` (a closed-loop :class:`~amcp_properties.cases.Case`) or ``spec`` (a problem without a
    run) names the problem; ``design`` (an OfflineDesign) is written as ``design.json`` when given."""
    spec = case.to_spec() if case is not None else spec
    key = case.key() if case is not None else json.dumps(spec_to_dict(spec), sort_keys=True)
    folder = failure_dir() / f"{test}-{backend}-{hashlib.sha1(key.encode()).hexdigest()[:10]}"
    folder.mkdir(parents=True, exist_ok=True)
    save_spec(spec, folder / "problem.json")
    labels = case.labels if case is not None else {}
    if traj is not None:
        traj.meta = dict(traj.meta, property=test, claim=result.name, labels=labels)
        traj.save(folder / "trajectory.json.gz")
    if design is not None:
        write_json_atomic(design.to_dict(), folder / "design.json")
    replay_line = (f"replay: python -m amcp_properties.failures {folder} [--backend {backend}]" if traj is not None
                   else f"replay: amcp design {folder / 'problem.json'} --backend {backend}")
    (folder / "claim.txt").write_text(
        f"test: {test}\nbackend: {backend}\nclaim: {result.claim}\nstatus: {result.status}\n"
        f"margin: {result.margin}\ntolerance: {result.tolerance}\ndetail: {result.detail}\n"
        f"labels: {labels}\n\n{replay_line}\n")
    return folder


def require(result: CheckResult, *, test: str, backend: str, case=None, traj: Trajectory | None = None,
            spec=None, design=None) -> None:
    """Assert that a claim holds; on the final failing example save it (see :func:`save_failure`)."""
    if result.passed:
        return
    where = ""
    if _is_final():
        where = f"\nreplayable files: {save_failure(test, backend, result, case, traj, spec, design)}"
    raise AssertionError(f"{result.claim}\n  status {result.status}, margin {result.margin} "
                         f"(tolerance {result.tolerance}): {result.detail}{where}")


def replay(folder: str | os.PathLike, backend: str | None = None) -> Trajectory:
    """Re-run a saved failure: the recorded design, options, formulation of (20), x0, θ* and disturbance sequence."""
    folder = Path(folder)
    spec = load_spec(folder / "problem.json")
    recorded = Trajectory.load(folder / "trajectory.json.gz")
    formulation = recorded.meta.get("formulation")
    ctrl = AdaptiveMPC(spec.problem, recorded.design, backend or recorded.backend, recorded.options,
                       **({"formulation": formulation} if formulation else {}))
    return simulate(ctrl, recorded.x[0], recorded.theta_star, len(recorded.w), disturbance=np.asarray(recorded.w))


def main(argv: list[str] | None = None) -> int:
    """``python -m amcp_properties.failures DIR [--backend NAME]``: replay and re-check."""
    from . import claims

    args = list(sys.argv[1:] if argv is None else argv)
    backend = None
    if "--backend" in args:
        i = args.index("--backend")
        backend = args[i + 1]
        del args[i:i + 2]
    traj = replay(args[0], backend)
    results = [claims.recursive_feasibility(traj), claims.theta_star_in_sets(traj), claims.theta_hat_in_prior(traj),
               claims.constraints_satisfied(traj), claims.set_inclusions(traj), claims.lms_precondition(traj),
               claims.lms_inequality(traj), claims.prediction_tube(traj),
               claims.terminal_set_invariance(traj.problem, traj.design)]
    for r in results:
        print(f"{r.name:22s} {r.status:8s} margin {r.margin}  {r.detail}")
    return 0 if all(r.passed for r in results) else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
