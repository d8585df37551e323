"""Closed-loop simulation of system (1) under the adaptive MPC, and the recorded Trajectory.

A :class:`Trajectory` holds the problem, the design, the online options, θ*, the disturbance
sequence and every :class:`~amcp_drake.online.controller.StepRecord`; it is saved as JSON (gzip when the
name ends in ``.gz``) and loaded back, so a run can be re-checked (``amcp certify --trajectory``)
without re-running it.
"""

from __future__ import annotations

import gzip
import json
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import InconsistentDataError, ProblemError, TrajectoryError
from amcp_drake.model.json_strict import GZIP_MAGIC, decode_utf8, first_non_finite, loads_strict, read_bytes_limited
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import DISTURBANCE_KINDS, Problem, ProblemSpec, check_theta_rate
from amcp_drake.model.problem_io import (
    options_from_dict,
    options_to_dict,
    shown,
    spec_from_dict,
    spec_to_dict,
    write_bytes_atomic,
    write_text_atomic,
)
from amcp_drake.model.status import SolveStatus
from amcp_drake.model.trajectory_schema import check_consistency, validate_trajectory_layout
from amcp_drake.offline.design import OfflineDesign
from amcp_drake.online import answers
from amcp_drake.online.controller import AdaptiveMPC, StepRecord

TRAJECTORY_FORMAT = "amcp-trajectory"
TRAJECTORY_VERSION = 1
#: Versions of the trajectory format this code reads; any other "version" is refused (exit 2), since
#: a newer layout may hold data this version would silently ignore.
SUPPORTED_TRAJECTORY_VERSIONS = (1,)
#: Largest trajectory file read, and largest decompressed content of a gzip one (a run of MAX_STEPS steps
#: of Example 1 is ~0.5 GB of JSON); the file size is checked before it is read, the decompressed size
#: guards against a small .gz that expands without end.
MAX_TRAJECTORY_BYTES = 2**31


def disturbance_sequence(problem: Problem, kind: str | np.ndarray, steps: int, seed: int = 0) -> np.ndarray:
    """w_0..w_{steps-1}, shape (steps, n): ``"uniform"`` i.i.d. uniform on W (rejection sampling
    from the bounding box of W), ``"vertices"`` i.i.d. uniform over the vertices of W, ``"zero"``,
    or an explicit array (returned as is after a shape check)."""
    n = problem.n
    if not isinstance(kind, str):
        arr = np.asarray(kind, float)
        if arr.shape != (steps, n) or not np.all(np.isfinite(arr)):
            raise ProblemError("disturbance", f"a finite array of shape ({steps}, {n})", f"shape {arr.shape}")
        return arr
    if kind not in DISTURBANCE_KINDS:
        raise ProblemError("disturbance", f"one of {sorted(DISTURBANCE_KINDS)} or an array", repr(kind))
    rng = np.random.default_rng(seed)
    if kind == "zero":
        return np.zeros((steps, n))
    verts = problem.w_vertices()
    if kind == "vertices":
        return verts[rng.integers(len(verts), size=steps)]
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    out = np.empty((steps, n))
    ones = np.ones(len(problem.H_w))
    for k in range(steps):
        while True:
            w = rng.uniform(lo, hi)
            if np.all(problem.H_w @ w <= ones):
                out[k] = w
                break
    return out


@dataclass
class Trajectory:
    """A recorded closed-loop run. ``x`` (T+1, n) states, ``u`` (T, m) inputs, ``w`` (T, n) the
    disturbances applied, ``records`` the T+1 step records (the last one may hold a failure).

    A *measured run* (a plant other than amcp's simulator of (1): a Drake plant, hardware, a user's own
    loop, :func:`amcp_drake.online.measured.measured_trajectory`) has ``theta_star`` and ``w`` both None:
    θ* and the disturbances are unknown, and the certificate checks what x, u and the records show."""

    problem: Problem
    design: OfflineDesign
    options: OnlineOptions
    backend: str
    theta_star: np.ndarray | None
    x: np.ndarray
    u: np.ndarray
    w: np.ndarray | None
    records: list[StepRecord]
    stop_reason: str = "completed"
    mu_state_bound: float | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def steps(self) -> int:
        """Number of applied inputs T."""
        return len(self.u)

    @property
    def all_solved(self) -> bool:
        """True when every step's QP (and update) ended OPTIMAL."""
        return all(r.status is SolveStatus.OPTIMAL for r in self.records)

    # -- persistence ------------------------------------------------------------------------------
    @property
    def measured(self) -> bool:
        """True for a measured run: θ* and the disturbances w_k unknown (both None)."""
        return self.theta_star is None and self.w is None

    @property
    def time_varying(self) -> bool:
        """True when θ* was given as a sequence θ*_k (Section 4.1) that is not constant."""
        if self.theta_star is None:
            return False
        seq = np.asarray(self.theta_star, float)
        return seq.ndim == 2 and bool(np.any(seq != seq[0]))

    def theta_star_at(self, k: int) -> np.ndarray:
        """θ*_k: the constant θ*, or entry k of the sequence (the last entry past its end).
        ValueError for a measured run (θ* unknown)."""
        if self.theta_star is None:
            raise ValueError("theta_star: unknown in a measured run")
        seq = np.asarray(self.theta_star, float)
        if seq.ndim == 1:
            return seq
        return seq[min(k, len(seq) - 1)]

    def to_dict(self) -> dict[str, Any]:
        spec = ProblemSpec(self.problem)
        return {
            "format": TRAJECTORY_FORMAT, "version": TRAJECTORY_VERSION,
            "problem": spec_to_dict(spec), "design": self.design.to_dict(),
            "options": options_to_dict(self.options),
            "backend": self.backend,
            "theta_star": None if self.theta_star is None else np.asarray(self.theta_star).tolist(),
            "x": self.x.tolist(), "u": self.u.tolist(), "w": None if self.w is None else self.w.tolist(),
            "stop_reason": self.stop_reason, "mu_state_bound": self.mu_state_bound, "meta": self.meta,
            "records": [_record_to_dict(r) for r in self.records],
        }

    def save(self, path: str | Path) -> Path:
        """Write JSON atomically (gzip when the name ends in .gz). A non-finite number anywhere is a
        TrajectoryError naming its field (``records[10].cost``), raised before any file is opened."""
        data = self.to_dict()
        bad = first_non_finite(data)
        if bad is not None:
            raise TrajectoryError(f"{bad[0]}: expected a finite number to write the trajectory {path}; received "
                                  f"{bad[1]} (nothing was written)")
        text = json.dumps(data, allow_nan=False)
        path = Path(path)
        if path.suffix == ".gz":
            return write_bytes_atomic(gzip.compress(text.encode("utf-8")), path)
        return write_text_atomic(text, path)

    @classmethod
    def load(cls, path: str | Path) -> Trajectory:
        """Read a file written by :meth:`save` (gzip recognised by its magic bytes). Unreadable,
        truncated or corrupt gzip data, non-UTF-8 text, invalid or non-strict JSON (duplicate keys, NaN)
        and an unknown format version raise TrajectoryError naming the file or the field."""
        path = Path(path)
        try:
            open(path, "rb").close()
        except OSError as exc:
            raise TrajectoryError(f"--trajectory: expected a readable trajectory file; received {path}, which "
                                  f"cannot be read ({exc.strerror or exc})") from None
        raw = read_bytes_limited(path, MAX_TRAJECTORY_BYTES, TrajectoryError, "trajectory file", gzip_ok=True)
        size = len(raw)
        try:
            if raw[:2] == GZIP_MAGIC:
                raw = _gunzip(raw, path)
            text = decode_utf8(raw, str(path), TrajectoryError)
            del raw
            return cls.from_dict(loads_strict(text, str(path), TrajectoryError))
        except MemoryError:
            raise TrajectoryError(f"file: expected a trajectory file that fits in the memory available; received "
                                  f"{path} ({size:,} bytes): memory ran out while reading it (MemoryError)") from None

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Trajectory:
        if not isinstance(data, dict) or data.get("format") != TRAJECTORY_FORMAT:
            raise TrajectoryError(f"format: expected {TRAJECTORY_FORMAT!r} (not a trajectory file); received "
                                  f"{shown(data.get('format')) if isinstance(data, dict) else repr(type(data).__name__)}")
        version = data.get("version")
        if type(version) is not int or version not in SUPPORTED_TRAJECTORY_VERSIONS:  # 1.0 and true are not 1
            raise TrajectoryError(f"version: expected one of {list(SUPPORTED_TRAJECTORY_VERSIONS)} (the trajectory "
                                  f"format versions this amcp reads); received {shown(version)}")
        validate_trajectory_layout(data)
        check_consistency(data)
        try:
            problem = spec_from_dict(data["problem"], reduce_rows=False).problem
        except ProblemError as exc:
            raise TrajectoryError(f"problem.{exc}") from None
        except KeyError:
            raise TrajectoryError("problem: expected the recorded problem; received nothing (key missing)") from None
        try:
            return cls(problem=problem, design=OfflineDesign.from_dict(data["design"]),
                       options=options_from_dict(data["options"]), backend=data["backend"],
                       theta_star=None if data["theta_star"] is None else np.asarray(data["theta_star"], float),
                       x=np.asarray(data["x"], float).reshape(-1, problem.n),
                       u=np.asarray(data["u"], float).reshape(-1, problem.m),
                       w=None if data["w"] is None else np.asarray(data["w"], float).reshape(-1, problem.n),
                       records=_records_from_list(data["records"]),
                       stop_reason=data.get("stop_reason", ""), mu_state_bound=data.get("mu_state_bound"),
                       meta=data.get("meta", {}))
        except KeyError as exc:
            raise TrajectoryError(f"{exc.args[0]}: expected a value; received nothing (key missing)") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise TrajectoryError(f"file: expected the documented trajectory layout; received malformed data "
                                  f"({exc})") from None


def formulation_meta(controller) -> dict:
    """The trajectory's record of the form of (20) solved: ``formulation`` ("plain" or "vertex") and, when
    ``formulation="auto"`` chose it, ``formulation_reason`` (the size rule's sentence)."""
    meta = {"formulation": controller.backend.formulation}
    choice = controller.formulation_choice
    if choice is not None:
        meta["formulation_reason"] = f"auto: {choice.reason}"
    return meta


def _gunzip(raw: bytes, path: Path) -> bytes:
    """Decompress gzip data; truncated or corrupt data and oversized content raise TrajectoryError."""
    import io
    import zlib

    try:
        with gzip.GzipFile(fileobj=io.BytesIO(raw)) as handle:
            data = handle.read(MAX_TRAJECTORY_BYTES + 1)
    except EOFError:
        raise TrajectoryError(f"file: expected a complete gzip file; received {path}, truncated (the compressed "
                              "data end before the end-of-stream marker)") from None
    except (OSError, zlib.error) as exc:
        raise TrajectoryError(f"file: expected gzip-compressed JSON; received {path}: corrupt data ({exc})") from None
    if len(data) > MAX_TRAJECTORY_BYTES:
        raise TrajectoryError(f"file: expected at most {MAX_TRAJECTORY_BYTES:,} bytes of JSON after decompression; "
                              f"received more from {path}")
    return data


#: Fields of StepRecord not written to a trajectory file: the typed attempts of the answer policy (the
#: provenance entries ``answers`` rendered from them are written).
_NOT_WRITTEN = {"attempts"}


def _record_to_dict(r: StepRecord) -> dict[str, Any]:
    out = {}
    for f in fields(StepRecord):
        if f.name in _NOT_WRITTEN:
            continue
        value = getattr(r, f.name)
        if isinstance(value, np.ndarray):
            value = value.tolist()
        elif isinstance(value, SolveStatus):
            value = value.value
        elif f.name == "answers" and value is not None:
            value = [dict(e) for e in value]
        elif isinstance(value, tuple):
            # ±inf (one-sided PE bounds) is not JSON: stored as None
            value = [None if isinstance(v, float) and not np.isfinite(v) else v for v in value]
        out[f.name] = value
    return out


_ARRAY_FIELDS = {"x", "u", "H_theta", "h_theta", "theta_hat", "theta_tilde", "v", "z", "alpha", "Lambda", "set_Lambda",
                 "h_theta_stages"}
_STATUS_FIELDS = {"status", "set_status", "projection_status"}


def _records_from_list(records: Any) -> list[StepRecord]:
    if not isinstance(records, list):
        raise TrajectoryError(f"records: expected a list of step records; received {type(records).__name__}")
    out = []
    for i, r in enumerate(records):
        try:
            if not isinstance(r, dict):
                raise TypeError(f"{type(r).__name__} instead of an object")
            out.append(_record_from_dict(r))
        except (TypeError, ValueError, KeyError) as exc:
            raise TrajectoryError(f"records[{i}]: expected a step record; received malformed data ({exc})") from None
    return out


def _record_from_dict(d: dict[str, Any]) -> StepRecord:
    kwargs = {}
    for f in fields(StepRecord):
        if f.name not in d:
            continue
        value = d[f.name]
        if f.name in _ARRAY_FIELDS and value is not None:
            value = np.asarray(value, float)
        elif f.name in _STATUS_FIELDS:
            value = SolveStatus(value)
        elif f.name == "infeasible_constraints":
            value = tuple(value)
        elif f.name == "answers":
            value = answers.validate(value, "answers")
        elif f.name == "pe_bounds" and value is not None:
            value = (float("-inf") if value[0] is None else value[0], float("inf") if value[1] is None else value[1])
        kwargs[f.name] = value
    return StepRecord(**kwargs)


def simulate(controller: AdaptiveMPC, x0, theta_star, steps: int, disturbance: str | np.ndarray = "uniform",
             seed: int = 0, progress: bool = False, mu_state_bound: float | None = None) -> Trajectory:
    """Run ``steps`` steps of the closed loop x_{k+1} = A(θ*)x_k + B(θ*)u_k + w_k under ``controller``.

    ``theta_star`` is θ* (p,) or a sequence θ*_k of shape (steps, p) or (steps+1, p) (system (24),
    Section 4.1): each θ*_k must lie in Θ and consecutive ones obey Assumption 17,
    ‖θ*_{k+1} − θ*_k‖ <= d_θ of the controller's options (up to THETA_RATE_TOL). A (steps, p)
    sequence is extended by θ*_steps = θ*_{steps−1}; the stored sequence has steps+1 rows.

    The run ends early, keeping the partial trajectory, when a step's status is not OPTIMAL.
    InconsistentDataError (Θ_{k-1} ∩ Δ_k empty) propagates with the partial trajectory attached
    as ``exc.trajectory``. ``mu_state_bound`` (the box of (11) when Z is unbounded in x) defaults to
    the one the controller's design recorded, so the trajectory carries what its certificate needs.
    """
    problem = controller.problem
    x = np.asarray(x0, float)
    if x.shape != (problem.n,) or not np.all(np.isfinite(x)):
        raise ProblemError("x0", f"a finite vector of length {problem.n}", f"{np.asarray(x0)!r}")
    theta_star = np.asarray(theta_star, float)
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 1:
        raise ProblemError("steps", "an integer >= 1", repr(steps))
    if theta_star.ndim == 2 and theta_star.shape == (steps, problem.p):
        theta_star = np.vstack([theta_star, theta_star[-1:]])
    if theta_star.shape not in ((problem.p,), (steps + 1, problem.p)) or not np.all(np.isfinite(theta_star)):
        raise ProblemError("theta_star", f"a finite vector of length {problem.p} or a sequence of shape "
                           f"({steps}, {problem.p}) / ({steps + 1}, {problem.p})", f"shape {theta_star.shape}")
    for k, th in enumerate(np.atleast_2d(theta_star)):
        if polytope.max_violation(problem.H_theta, problem.h_theta, th) > 1e-9:
            raise ProblemError("theta_star" if theta_star.ndim == 1 else f"theta_star[{k}]",
                               "a point of Theta (Assumption 1 / 17)", f"{th.tolist()}")
    check_theta_rate(theta_star, controller.options.d_theta)
    if mu_state_bound is None:
        mu_state_bound = controller.design.mu_state_bound
    W = disturbance_sequence(problem, disturbance, steps, seed)
    controller.reset()
    xs, us, ws, records = [x], [], [], []
    stop = "completed"
    iterator = range(steps)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc=f"closed loop ({controller.backend.name})", unit="step")

    def _trajectory() -> Trajectory:
        return Trajectory(problem=problem, design=controller.design, options=controller.options,
                          backend=controller.backend.name, theta_star=theta_star, x=np.array(xs),
                          u=np.array(us).reshape(-1, problem.m), w=np.array(ws).reshape(-1, problem.n),
                          records=records, stop_reason=stop, mu_state_bound=mu_state_bound,
                          meta={"disturbance": disturbance if isinstance(disturbance, str) else "array", "seed": seed,
                                **formulation_meta(controller)})

    for k in iterator:
        try:
            u, record = controller.step(x)
        except InconsistentDataError as exc:
            stop = f"inconsistent data at step {k}"
            exc.trajectory = _trajectory()
            raise
        records.append(record)
        if u is None:
            stop = f"step {k}: status {record.status.value}"
            break
        x = problem.step(x, u, theta_star if theta_star.ndim == 1 else theta_star[k], W[k])
        xs.append(x)
        us.append(u)
        ws.append(W[k])
    else:
        # final step record at x_T: set update, LMS and QP at the last state (checks Θ_T, θ̂_T)
        try:
            _, record = controller.step(x)
            records.append(record)
        except InconsistentDataError as exc:
            stop = f"inconsistent data at step {steps}"
            exc.trajectory = _trajectory()
            raise
    return _trajectory()
