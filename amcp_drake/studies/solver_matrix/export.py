"""Export the corpus: the problems the Drake backend solves in recorded runs of the shipped examples and
of the recorded hard cases, each verified (:mod:`.reference`) and written as one corpus file.

Sources (:func:`example_sources`, :func:`generated_sources`, :func:`hard_case_sources`):

* every shipped example (the built-in ones and every problem file of the repository's examples/,
  :func:`example_names`): the offline design (gain SDP (16), support LPs), then ``steps`` steps of the
  plain form of (20) with the set update (9) solved as an LP, and ``steps`` steps of the vertex form
  with the exact update (7) (its redundancy LPs); the projections (12) that the runs need (the examples
  with n >= 4 run :data:`LARGE_EXAMPLE_STEPS` steps; a member of a family of :data:`FAMILY_PREFIXES`
  keeps one program per kind);
* generated problems (:func:`generated_sources`): problem ``idx`` of campaign seed ``seed``, drawn by the
  library's numpy generator that the property suite's strategies build on
  (:func:`amcp_drake.studies.campaign.draw_case`, with its hard cases: θ* on a facet or at a vertex of
  Θ, w_0 pinning Θ_1 to a point or a thin slab, x0 on the boundary of the feasible set), its design,
  then the plain form with the drawn options and the vertex form with (7);
* the recorded hard cases of ``tests/data`` (when present): the Drake vertex step that stalled at
  1e-10 (``lockstep-vertex-ladder``, step 4), the plain step where cvxpy's Clarabel ended 8.2e-9 above
  the optimum (``lockstep-plain-suboptimal``, step 8), the massera2017 plain step on a 1e-4-wide Θ_k,
  the generated gain LMI that ended AlmostSolved, and the gain LMI of x⁺ = 1.5x + 0·u at margin 1e-8
  (infeasible; Clarabel panicked on it), recorded without solving (left out of the corpus: infeasible
  by less than the verdicts resolve, see :data:`.reference.REFERENCE_FEAS_TOL`); two recorded projections (12) onto
  degenerate sets and the support LPs of a window update on a sliver Θ_k;
* generated projections (12) onto Θ of every example (:func:`projection_sources`);
* the cvxpy backend's own problems (:mod:`.cvxpy_export`): Example 1 (design and the plain form with
  (9)), the plain step 8 of ``lockstep-plain-suboptimal`` and the unstabilisable gain LMI as cvxpy
  poses them.

Of the many programs of one (source, kind), :func:`select` keeps up to ``per_kind`` spread over the run,
those of distinct shape first, then the first and the last (a hard case keeps all of its). ``index.json`` lists what was recorded, kept,
left out (unsupported, unverified with the reason) and shipped.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.model.problem_io import write_bytes_atomic
from amcp_drake.studies.solver_matrix.corpus import ID_EXPECTED, is_valid_id, write_json_atomic
from amcp_drake.studies.solver_matrix.cvxpy_export import CvxpyRecorder
from amcp_drake.studies.solver_matrix.drake_export import ProgramRecorder, Recorded, SolveSkipped
from amcp_drake.studies.solver_matrix.reference import verify_reference

#: The built-in examples always exported (the other shipped examples come from the files of examples/,
#: :func:`example_names`).
DEFAULT_EXAMPLES = ("lorenzen2019", "lorenzen2019_ex2", "parsi2020_siso", "parsi2020_mimo", "bujarbaruah2022",
                    "massera2017", "kothare1996", "tranos2022")
#: Examples of one system at several parameter values (the SLS-MPC 2-D family at five ε_A): one program
#: of each kind per member.
FAMILY_PREFIXES = ("sls_mpc_2d_eps",)
#: Closed-loop steps of the examples with n >= 4 (their vertex form of (20) takes seconds and GiB per step).
LARGE_EXAMPLE_STEPS = 3
#: The generated problems exported by default: problems 0 … DEFAULT_GENERATED - 1 of campaign seed
#: :data:`DEFAULT_GENERATED_SEED`.
DEFAULT_GENERATED, DEFAULT_GENERATED_SEED = 4, 0


@dataclass
class Source:
    """One recorded computation: a name and a function that runs it (inside a recorder)."""

    name: str
    run: Callable[[ProgramRecorder], None]
    hard: bool = False
    note: str = ""
    slug: str = ""
    keep_all: bool = False
    per_kind: int | None = None   # None: the per_kind of export_corpus


def example_names(folder: Path | None = None) -> tuple[str, ...]:
    """:data:`DEFAULT_EXAMPLES`, then the name of every problem file ``<name>.json`` of ``folder`` (the
    repository's examples/, each a copy of a built-in example) not among them, sorted."""
    extra = sorted(p.name[:-len(".json")] for p in folder.glob("*.json")) if folder is not None and folder.is_dir() else []
    return DEFAULT_EXAMPLES + tuple(name for name in extra if name not in DEFAULT_EXAMPLES)


def example_sources(examples=DEFAULT_EXAMPLES, steps: int = 6, backend: str = "drake",
                    folder: Path | None = None) -> Iterator[Source]:
    """The runs of the examples on ``backend`` (Drake: plain + (9) LP, vertex + (7); cvxpy: the plain form
    with (9) only, its vertex form being solved by a compiled Clarabel outside the recorded calls). An
    example is read from ``folder/<name>.json`` when that file exists, else it is the built-in one; one with
    n >= 4 runs min(steps, :data:`LARGE_EXAMPLE_STEPS`) steps."""
    runs = ((("plain", "fixed", {"set_update_method": "lp"}), ("vertex", "exact", {})) if backend == "drake"
            else (("plain", "fixed", {"set_update_method": "lp"}),))

    def make(name: str) -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from amcp_drake.model.examples import get_example
            from amcp_drake.model.options import OnlineOptions
            from amcp_drake.model.problem_io import load_spec
            from amcp_drake.offline.design import design
            from amcp_drake.online.controller import AdaptiveMPC
            from amcp_drake.online.simulate import simulate

            file = folder / f"{name}.json" if folder is not None else None
            spec = load_spec(file) if file is not None and file.is_file() else get_example(name)
            n_steps = steps if spec.problem.n < 4 else min(steps, LARGE_EXAMPLE_STEPS)
            rec.context.update(stage="design", example=name)
            d = design(spec.problem, spec.design, backend=backend)
            base = spec.online or OnlineOptions()
            sc = spec.scenario
            for formulation, update, extra in runs:
                rec.context.update(stage=f"closed loop, {formulation} form, update {update}", steps=n_steps)
                options = dataclasses.replace(base, update=update, d_theta=0.0, pe_window=None,
                                              cost="certainty_equivalence")
                ctrl = AdaptiveMPC(spec.problem, d, backend=backend, options=options, formulation=formulation, **extra)
                theta = np.asarray(sc.theta_star_for(n_steps), float)
                theta = theta if theta.ndim == 1 else theta[0]
                simulate(ctrl, sc.x0, theta, n_steps, "uniform", seed=sc.seed)

        return run

    for name in examples:
        yield Source(f"example {name} ({backend})", make(name), slug=name if backend == "drake" else f"{name}-{backend}",
                     per_kind=1 if name.startswith(FAMILY_PREFIXES) else None)


def generated_sources(count: int = DEFAULT_GENERATED, seed: int = DEFAULT_GENERATED_SEED, steps: int = 6,
                      start: int = 0) -> Iterator[Source]:
    """Problems ``start`` … ``start + count - 1`` of campaign seed ``seed``
    (:func:`amcp_drake.studies.campaign.draw_case`: the numpy generator under the property suite's
    strategies, seeded per problem, so the draw is reproducible), each: its offline design (Drake, with
    the designs of the draws it rejected), ``steps`` steps of the plain form of (20) with the drawn online
    options (the set update (9) as an LP) and of the vertex form with the exact update (7), under the drawn
    θ*, x0 and disturbance sequence (w_0 pinning Θ_1 where drawn). Every problem's provenance holds the
    campaign seed and index; those of the closed loops also the generator's labels (θ* on a facet/vertex,
    pinning, x0 on the boundary, ...)."""

    def make(idx: int) -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from amcp_drake.model.options import OnlineOptions
            from amcp_drake.online.controller import AdaptiveMPC
            from amcp_drake.online.simulate import simulate
            from amcp_drake.studies.campaign import draw_case

            rec.context.update(stage="design of the drawn problem", campaign_seed=seed, idx=idx)
            case = draw_case(seed, idx, steps)
            rec.context.update(labels={k: str(v) for k, v in case.labels.items()})
            base = case.options or OnlineOptions()
            runs = (("plain", base, {"set_update_method": "lp"}),
                    ("vertex", dataclasses.replace(base, update="exact", d_theta=0.0, pe_window=None,
                                                   cost="certainty_equivalence"), {}))
            for formulation, options, extra in runs:
                rec.context.update(stage=f"closed loop, {formulation} form, update {options.update}", steps=steps)
                ctrl = AdaptiveMPC(case.problem, case.design, backend="drake", options=options,
                                   formulation=formulation, **extra)
                simulate(ctrl, case.x0, case.theta_star, steps, case.w)

        return run

    for idx in range(start, start + count):
        yield Source(f"generated problem {idx} of campaign seed {seed}", make(idx), slug=f"generated-{seed}-{idx}",
                     note="generated: amcp_drake.studies.campaign.draw_case (the property suite's generator), seeded")


def projection_sources(examples=DEFAULT_EXAMPLES, points: int = 2, seed: int = 0) -> Iterator[Source]:
    """Generated projections (12) onto Θ of each example (the controller's default target): ``points``
    points outside Θ along seeded random directions from its Chebyshev centre, 1 % and 50 % beyond the
    boundary. The closed loops of :func:`example_sources` rarely leave Θ in a few steps, so these stand in
    for the projections of longer runs."""

    def make(name: str, index: int) -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from scipy.optimize import linprog

            from amcp_drake.backends.drake_ import DrakeBackend
            from amcp_drake.model.examples import get_example

            problem = get_example(name).problem
            H, h = np.asarray(problem.H_theta, float), np.asarray(problem.h_theta, float)
            p = H.shape[1]
            norms = np.linalg.norm(H, axis=1)
            lp = linprog(np.r_[np.zeros(p), -1.0], A_ub=np.c_[H, norms], b_ub=h, bounds=[(None, None)] * p + [(0, None)])
            centre = lp.x[:p]
            rng = np.random.default_rng([seed, index])
            backend = DrakeBackend()
            for j in range(points):
                u = rng.standard_normal(p)
                u /= np.linalg.norm(u)
                Hu = H @ u
                t_max = float(np.min((h - H @ centre)[Hu > 0] / Hu[Hu > 0]))
                rec.context.update(stage=f"projection (12) onto Θ of a point {(0.01, 0.5)[j % 2]:g} beyond it")
                backend.project(centre + t_max * (1.0 + (0.01, 0.5)[j % 2]) * u, H, h)

        return run

    for index, name in enumerate(examples):
        yield Source(f"projections onto Θ of {name}", make(name, index), slug=f"{name}-projection", keep_all=True,
                     note="generated: points outside Θ along seeded random directions")


def hard_case_sources(data_dir: Path) -> Iterator[Source]:
    """The recorded hard cases found under ``data_dir`` (the repository's tests/data)."""

    def replay_step(folder: str, k: int, formulation: str, tight: bool, backend: str = "drake") -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from amcp_drake.comparison.compare import ACCURATE_CLARABEL
            from amcp_drake.model.problem_io import load_spec
            from amcp_drake.online.controller import AdaptiveMPC
            from amcp_drake.online.simulate import Trajectory

            spec = load_spec(data_dir / folder / "problem.json")
            traj = Trajectory.load(data_dir / folder / "trajectory.json.gz")
            step = traj.records[k]
            ctrl = AdaptiveMPC(spec.problem, traj.design, backend=backend, formulation=formulation, options=traj.options,
                               **({"solver_options": ACCURATE_CLARABEL} if tight else {}))
            rec.context.update(stage=f"step {k} replayed, {backend} {formulation} form")
            ctrl.mpc.solve(np.asarray(traj.x[k], float), step.h_theta, step.theta_hat, step.H_theta)

        return run

    def tube_step(file: str) -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from amcp_drake.backends.base import TubeMPCData
            from amcp_drake.backends.drake_ import DrakeBackend

            step = json.loads((data_dir / file).read_text())
            fields = {k: (v if k in ("N", "cost") else np.asarray(v, float)) for k, v in step["tube_data"].items()}
            mpc = DrakeBackend().tube_mpc(TubeMPCData(**fields))
            rec.context.update(stage="recorded step, plain form")
            mpc.solve(np.asarray(step["x"], float), np.asarray(step["h_theta"], float), np.asarray(step["theta_hat"], float))

        return run

    def gain(file: str | None, margin: float, backend: str = "drake") -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            if file is None:
                A_v, B_v, Q, R = np.array([[[1.5]]]), np.zeros((1, 1, 1)), np.eye(1), np.eye(1)
                rec.context["record_only"] = True   # Clarabel panicked on it, Drake aborted the process
            else:
                data = json.loads((data_dir / file).read_text())
                A_v, B_v, Q, R = (np.array(data[k], float) for k in ("A_vertices", "B_vertices", "Q", "R"))
            rec.context.update(stage=f"gain LMI (16) as written, margin {margin:g}")
            try:
                if backend == "drake":
                    from amcp_drake.backends.drake_ import DrakeBackend

                    DrakeBackend()._gain_lmi(A_v, B_v, Q, R, np.eye(A_v.shape[1]), margin)
                else:
                    from amcp_reference.offline import _gain_lmi
                    from amcp_reference.solver_call import SolverCall

                    _gain_lmi(SolverCall("CLARABEL", None), A_v, B_v, Q, R, np.eye(A_v.shape[1]), margin)
            except SolveSkipped:
                pass

        return run

    def projection(file: str) -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from amcp_drake.backends.drake_ import DrakeBackend

            data = json.loads((data_dir / file).read_text())
            rec.context.update(stage="recorded projection (12)")
            DrakeBackend().project(np.asarray(data["point"], float), np.asarray(data["H"], float), np.asarray(data["h"], float))

        return run

    def supports(file: str) -> Callable[[ProgramRecorder], None]:
        def run(rec: ProgramRecorder) -> None:
            from amcp_drake.backends.drake_ import DrakeBackend

            data = json.loads((data_dir / file).read_text())
            rec.context.update(stage="recorded support LPs of a window update")
            DrakeBackend().support(np.asarray(data["H"], float), np.asarray(data["h"], float),
                                   np.asarray(data["directions"], float)[:2])

        return run

    cases = [
        ("lockstep-vertex-ladder", replay_step("lockstep-vertex-ladder", 4, "vertex", True),
         "Drake vertex form at 1e-10 stalled (AlmostSolved) with and without iterative refinement"),
        ("lockstep-plain-suboptimal", replay_step("lockstep-plain-suboptimal", 8, "plain", True),
         "plain form on a 1.3e-6-wide Θ_k: cvxpy's Clarabel at 1e-10 ended Solved 8.2e-9 above the optimum"),
        ("massera2017-plain-stall-step.json", tube_step("massera2017-plain-stall-step.json"),
         "massera2017 plain form on a 1e-4-wide Θ_k: Clarabel (QDLDL) ended AlmostSolved under every retry"),
        ("gain-lmi-almost-solved.json", gain("gain-lmi-almost-solved.json", 1e-6),
         "generated gain LMI (16): Clarabel ended AlmostSolved in the scaled forms"),
        ("campaign-0-13-projection.json", projection("campaign-0-13-projection.json"),
         "projection (12) of a point outside Θ_k by round-off (1e-12): both backends ended inaccurate when scaled naively"),
        ("campaign-0-19-projection.json", projection("campaign-0-19-projection.json"),
         "projection (12) onto a collapsed Θ_1: cvxpy ended optimal_inaccurate"),
        ("window-sliver-lp.json", supports("window-sliver-lp.json"),
         "support LPs of a window update on a sliver Θ_k (n = 1, p = 2)"),
        ("lockstep-plain-suboptimal", replay_step("lockstep-plain-suboptimal", 8, "plain", True, "cvxpy"),
         "cvxpy plain form on a 1.3e-6-wide Θ_k: Clarabel at 1e-10 ended Solved 8.2e-9 above the optimum, v 1.3e-4 off",
         "lockstep-plain-suboptimal-cvxpy"),
        (None, gain(None, 1e-8), "gain LMI (16) of x+ = 1.5x + 0u at margin 1e-8 (infeasible): Clarabel panicked in Rust "
         "and Drake aborted the process", "unstabilisable-gain-lmi"),
        (None, gain(None, 1e-8, "cvxpy"), "the same LMI as the cvxpy backend poses it (PSD slack variables)",
         "unstabilisable-gain-lmi-cvxpy"),
    ]
    for case in cases:
        path, run, note = case[:3]
        slug = case[3] if len(case) > 3 else (path or "").replace(".json", "")
        if path is None or (data_dir / path).exists():
            yield Source(f"hard case {slug}", run, hard=True, note=note, slug=slug)


def select(records: list[Recorded], per_kind: int) -> list[Recorded]:
    """Up to ``per_kind`` programs of each kind spread over the run: of distinct shapes first, then (when
    fewer shapes than ``per_kind``) the first and the last of the run (e.g. the first and a late step
    of a closed loop whose tube QP keeps its shape); plus the first one whose solve failed."""
    out = []
    kinds = sorted({r.kind for r in records if r.problem is not None})
    for kind in kinds:
        of_kind = [r for r in records if r.kind == kind and r.problem is not None]
        failed = [r for r in of_kind if r.success is False]
        shapes: dict[tuple, Recorded] = {}
        for r in of_kind:
            shapes.setdefault((r.problem.n, r.problem.A.shape[0], len(r.problem.lmis)), r)
        distinct = list(shapes.values())
        picks = [distinct[i] for i in np.unique(np.linspace(0, len(distinct) - 1, min(per_kind, len(distinct))).round().astype(int))]
        for i in np.unique(np.linspace(0, len(of_kind) - 1, min(per_kind, len(of_kind))).round().astype(int)):
            if len(picks) < per_kind and not any(of_kind[i] is r for r in picks):
                picks.append(of_kind[i])
        picks.sort(key=lambda r: next(j for j, q in enumerate(of_kind) if q is r))
        out.extend(picks + [r for r in failed[:1] if not any(r is q for q in picks)])
    return out


def _slug(text: str) -> str:
    text = text.replace(".json", "")
    return "".join(c if c.isalnum() or c in "-_." else "-" for c in text).strip("-").lower()


def export_corpus(out_dir: Path, sources: list[Source], per_kind: int = 2, max_bytes: int = 1_200_000,
                  progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Record every source, select, verify, write ``<id>.json.gz`` + ``index.json``; returns the index."""
    from amcp_drake.studies.solver_matrix.solvers import versions

    out_dir.mkdir(parents=True, exist_ok=True)
    index: dict[str, Any] = {"format": "amcp-solver-corpus-index", "version": 1, "versions": versions(),
                             "reference": {"kkt_tol": None}, "sources": [], "problems": [], "left_out": []}
    from amcp_drake.studies.solver_matrix.reference import KKT_TOL

    index["reference"]["kkt_tol"] = KKT_TOL
    for source in sources:
        rec = ProgramRecorder({"source": source.name})
        error = ""
        with rec, CvxpyRecorder(rec.context, records=rec.records) as crec:
            try:
                source.run(rec)
            except Exception as exc:  # noqa: BLE001 - a source that fails is reported, the others go on
                error = f"{type(exc).__name__}: {exc}"[:300]
        keep = source.hard or source.keep_all
        chosen = ([r for r in rec.records if r.problem is not None] if keep
                  else select(rec.records, source.per_kind or per_kind))
        entry = {"source": source.name, "note": source.note, "recorded": len(rec.records),
                 "unsupported": rec.unsupported + crec.unsupported,
                 "selected": len(chosen), "kept": 0, "error": error}
        counters: dict[str, int] = {}
        for r in chosen:
            pr = r.problem
            k = counters[r.kind] = counters.get(r.kind, 0) + 1
            pr.id = _slug(f"{source.slug or source.name}-{r.kind}-{k}")
            pr.provenance.pop("record_only", None)
            pr.provenance.update(backend="cvxpy" if r.solver.startswith("cvxpy") else "drake", solver_in_run=r.solver, options_in_run=_jsonable(r.options),
                                 success_in_run=r.success, status_in_run=r.solver_status, hard_case=source.hard,
                                 note=source.note)
            why = None if is_valid_id(pr.id) else f"id {pr.id!r} is not {ID_EXPECTED}"
            why = why or verify_reference(pr)
            if why is None:
                text = json.dumps(pr.to_dict(), allow_nan=False)
                if len(text) > max_bytes:
                    why = f"{len(text)} bytes of JSON, above max_bytes={max_bytes}"
            if why is not None:
                index["left_out"].append({"id": pr.id, "kind": r.kind, "reason": why})
                continue
            path = write_bytes_atomic(gzip.compress(text.encode(), mtime=0), out_dir / f"{pr.id}.json.gz")
            entry["kept"] += 1
            index["problems"].append({"id": pr.id, "kind": pr.kind, "class": pr.problem_class, "n": pr.n,
                                      "rows": int(pr.A.shape[0]), "reference": pr.reference.get("status"),
                                      "file": path.name, "bytes": path.stat().st_size, "hard_case": source.hard})
        index["sources"].append(entry)
        if progress is not None:
            progress(f"{source.name}: recorded {entry['recorded']}, kept {entry['kept']}" + (f" ({error})" if error else ""))
    write_json_atomic(out_dir / "index.json", index, indent=1)
    return index


def _jsonable(value: Any) -> Any:
    """Plain JSON: unknown objects as text, non-finite numbers (e.g. Clarabel's time limit inf) as text."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return str(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return str(value)


__all__ = ["DEFAULT_EXAMPLES", "DEFAULT_GENERATED", "DEFAULT_GENERATED_SEED", "FAMILY_PREFIXES", "LARGE_EXAMPLE_STEPS", "Source",
           "example_names", "example_sources", "export_corpus", "generated_sources", "hard_case_sources",
           "projection_sources", "select"]
