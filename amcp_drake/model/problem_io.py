"""Problem files: JSON, documented in docs/problem-format.md.

Layout (format "amcp-problem", version 1)::

    {
      "format": "amcp-problem", "version": 1, "name": "lorenzen2019",
      "system": {"A0": [[..]], "B0": [[..]], "A": [[[..]], ...], "B": [[[..]], ...]},
      "W":      {"H": [[..]]},                       # W = {w | H w <= 1}
      "Theta":  {"H": [[..]], "h": [..]},            # Θ = {θ | H θ <= h}
      "Z":      {"F": [[..]], "G": [[..]]},          # Z = {(x,u) | F x + G u <= 1}
      "cost":   {"Q": [[..]], "R": [[..]], "N": 10},
      "theta_hat0": [..],
      "design":   {... DesignOptions fields, all optional ...},
      "scenario": {"x0": [..], "theta_star": [..], "steps": 50, "disturbance": "uniform", "seed": 0},
      "online":   {... OnlineOptions fields, all optional ...}   # optional (Section 4 extensions)
    }

Files are written atomically (temporary file + rename), so a crash never leaves half a file.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.model.errors import ProblemError, ProblemFileError
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec, Scenario

FORMAT = "amcp-problem"
VERSION = 1
_DESIGN_FIELDS = set(DesignOptions.__dataclass_fields__)
_SCENARIO_FIELDS = set(Scenario.__dataclass_fields__)


def _get(data: dict, key: str, where: str) -> Any:
    if not isinstance(data, dict):
        raise ProblemFileError(where or "file", "a JSON object", type(data).__name__)
    if key not in data:
        raise ProblemFileError(f"{where}.{key}" if where else key, "a value", "nothing (key missing)")
    return data[key]


def spec_from_dict(data: dict) -> ProblemSpec:
    """Build and validate a :class:`ProblemSpec` from the documented JSON layout."""
    if not isinstance(data, dict):
        raise ProblemFileError("file", "a JSON object at top level", type(data).__name__)
    fmt = data.get("format")
    if fmt != FORMAT:
        raise ProblemFileError("format", f"'{FORMAT}'", repr(fmt))
    if data.get("version") != VERSION:
        raise ProblemFileError("version", str(VERSION), repr(data.get("version")))
    system = _get(data, "system", "")
    problem = Problem(
        A0=_get(system, "A0", "system"), B0=_get(system, "B0", "system"),
        A=_get(system, "A", "system"), B=_get(system, "B", "system"),
        H_w=_get(_get(data, "W", ""), "H", "W"),
        H_theta=_get(_get(data, "Theta", ""), "H", "Theta"), h_theta=_get(data["Theta"], "h", "Theta"),
        F=_get(_get(data, "Z", ""), "F", "Z"), G=_get(data["Z"], "G", "Z"),
        Q=_get(_get(data, "cost", ""), "Q", "cost"), R=_get(data["cost"], "R", "cost"), N=_get(data["cost"], "N", "cost"),
        theta_hat0=_get(data, "theta_hat0", ""), name=data.get("name", "problem"),
    )
    design_data = data.get("design", {}) or {}
    unknown = set(design_data) - _DESIGN_FIELDS
    if unknown:
        raise ProblemFileError("design", f"keys among {sorted(_DESIGN_FIELDS)}", f"unknown keys {sorted(unknown)}")
    design = DesignOptions(**design_data)
    scenario = None
    if data.get("scenario") is not None:
        sc = data["scenario"]
        if not isinstance(sc, dict):
            raise ProblemFileError("scenario", "a JSON object", type(sc).__name__)
        unknown = set(sc) - _SCENARIO_FIELDS
        if unknown:
            raise ProblemFileError("scenario", f"keys among {sorted(_SCENARIO_FIELDS)}", f"unknown keys {sorted(unknown)}")
        scenario = Scenario(**sc)
    online = None
    if data.get("online") is not None:
        online = options_from_dict(data["online"], where="online")
    return ProblemSpec(problem=problem, design=design, scenario=scenario, online=online)


def options_from_dict(data: Any, where: str = "options"):
    """:class:`~amcp_drake.model.options.OnlineOptions` from a JSON object (unknown keys rejected)."""
    from dataclasses import fields

    from amcp_drake.model.options import OnlineOptions

    if not isinstance(data, dict):
        raise ProblemFileError(where, "a JSON object", type(data).__name__)
    names = {f.name for f in fields(OnlineOptions)}
    unknown = set(data) - names
    if unknown:
        raise ProblemFileError(where, f"keys among {sorted(names)}", f"unknown keys {sorted(unknown)}")
    return OnlineOptions(**data)


def options_to_dict(options) -> dict:
    """The JSON object of an :class:`~amcp_drake.model.options.OnlineOptions` (all fields)."""
    from dataclasses import asdict

    return asdict(options)


def spec_to_dict(spec: ProblemSpec) -> dict:
    """The JSON layout of ``spec`` (inverse of :func:`spec_from_dict`)."""
    pr = spec.problem
    data: dict[str, Any] = {
        "format": FORMAT, "version": VERSION, "name": pr.name,
        "system": {"A0": pr.A0.tolist(), "B0": pr.B0.tolist(), "A": pr.A.tolist(), "B": pr.B.tolist()},
        "W": {"H": pr.H_w.tolist()},
        "Theta": {"H": pr.H_theta.tolist(), "h": pr.h_theta.tolist()},
        "Z": {"F": pr.F.tolist(), "G": pr.G.tolist()},
        "cost": {"Q": pr.Q.tolist(), "R": pr.R.tolist(), "N": pr.N},
        "theta_hat0": pr.theta_hat0.tolist(),
    }
    design: dict[str, Any] = {}
    defaults = DesignOptions()
    for key in _DESIGN_FIELDS:
        value = getattr(spec.design, key)
        default = getattr(defaults, key)
        if isinstance(value, np.ndarray):
            design[key] = value.tolist()
        elif value != default:
            design[key] = value
    data["design"] = design
    if spec.scenario is not None:
        sc = spec.scenario
        data["scenario"] = {"x0": np.asarray(sc.x0).tolist(), "theta_star": np.asarray(sc.theta_star).tolist(),
                            "steps": sc.steps, "disturbance": sc.disturbance, "seed": sc.seed}
    if spec.online is not None:
        data["online"] = options_to_dict(spec.online)
    return data


def load_spec(path: str | os.PathLike) -> ProblemSpec:
    """Read a problem file (see module docstring)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ProblemFileError("file", "a readable problem file", f"{path}: {exc.strerror}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ProblemFileError("file", "valid JSON", f"{path}: {exc.msg} at line {exc.lineno}") from None
    try:
        return spec_from_dict(data)
    except TypeError as exc:  # e.g. DesignOptions(**{...}) with a bad call
        raise ProblemFileError("file", "the documented layout", str(exc)) from None


def load_problem(path: str | os.PathLike) -> Problem:
    """Read only the :class:`Problem` of a problem file."""
    return load_spec(path).problem


def save_spec(spec: ProblemSpec, path: str | os.PathLike) -> Path:
    """Write ``spec`` as JSON atomically; return the path."""
    return write_json_atomic(spec_to_dict(spec), path)


def write_json_atomic(data: Any, path: str | os.PathLike) -> Path:
    """Write JSON to ``path`` through a temporary file in the same folder and a rename."""
    return write_text_atomic(json.dumps(data, indent=1, allow_nan=False), path)


def write_text_atomic(text: str, path: str | os.PathLike) -> Path:
    """Write text to ``path`` through a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; a result file is as readable as any other
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


__all__ = ["load_spec", "load_problem", "save_spec", "spec_from_dict", "spec_to_dict", "options_from_dict",
           "options_to_dict", "write_json_atomic",
           "write_text_atomic", "ProblemError"]
