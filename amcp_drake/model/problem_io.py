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
                                                     # disturbance: a kind, or [[w_0], ..., [w_{steps-1}]]
      "online":   {... OnlineOptions fields, all optional ...},  # optional (Section 4 extensions)
      "keep_redundant_rows": false                   # optional; files written by amcp say true
    }

Reading is strict (docs/problem-format.md, "Strictness"): the text must be UTF-8 JSON without
duplicate keys, NaN or overlong integers (:mod:`amcp_drake.model.json_strict`); the layout is validated
against ``data/problem.schema.json`` (unknown keys at every level, with the closest known key
suggested; booleans are not numbers; entries of magnitude at most 1e9), each message naming the JSON
path of the field (``cost.R[0][0]``); then the dataclasses check shapes and the paper's assumptions.
Rows of W.H, Θ and Z implied by the others are removed with a note (``ProblemSpec.notes``) unless
``keep_redundant_rows`` is true (:func:`amcp_drake.model.limits.remove_redundant_rows`).

Files are written atomically (temporary file + rename), so a crash never leaves half a file.
"""

from __future__ import annotations

import difflib
import json
import os
import tempfile
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from amcp_drake.model.errors import ProblemError, ProblemFileError
from amcp_drake.model.json_strict import json_path, load_json_strict
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec, Scenario
from amcp_drake.model.signals import signals_to_json

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


@lru_cache(maxsize=1)
def problem_schema() -> dict:
    """The JSON Schema of problem files (``amcp_drake/data/problem.schema.json``, docs/problem-format.md)."""
    return json.loads((resources.files("amcp_drake") / "data" / "problem.schema.json").read_text())


def _entries_ok(values: Any, bound: float) -> bool:
    """True when ``values`` is a non-empty list of JSON numbers (not booleans) within ±bound."""
    if not isinstance(values, list) or not values:
        return False
    for x in values:
        kind = type(x)
        if (kind is not float and kind is not int) or not -bound <= x <= bound:
            return False
    return True


@lru_cache(maxsize=1)
def _schema_validator():
    """A Draft 2020-12 validator of the problem schema whose ``items`` keyword checks lists of entries
    (vectors) and lists of vectors (matrices) in one Python pass when they are valid, and falls back to
    the standard per-item validation (exact messages) when they are not: a 5 MB W.H validates in well
    under a second instead of ~40 s. The accepted language is unchanged."""
    import jsonschema

    schema = problem_schema()
    entry = schema["$defs"]["entry"]
    bound = float(entry["maximum"])
    assert entry["minimum"] == -bound
    standard_items = jsonschema.Draft202012Validator.VALIDATORS["items"]

    def items(validator, item_schema, instance, parent_schema):
        ref = item_schema.get("$ref") if isinstance(item_schema, dict) else None
        if ref == "#/$defs/entry" and _entries_ok(instance, bound):
            return
        if ref == "#/$defs/vector" and isinstance(instance, list) and all(_entries_ok(row, bound) for row in instance):
            return
        yield from standard_items(validator, item_schema, instance, parent_schema)

    # an integer is an integer literal: 10.0 is a number (JSON Schema would accept it as an integer)
    types = jsonschema.Draft202012Validator.TYPE_CHECKER.redefine(
        "integer", lambda checker, x: isinstance(x, (int, np.integer)) and not isinstance(x, bool))
    fast = jsonschema.validators.extend(jsonschema.Draft202012Validator, {"items": items}, type_checker=types)
    return fast(schema)


_JSON_TYPES = {"object": "a JSON object", "array": "a list", "number": "a number", "integer": "an integer",
               "string": "a string", "boolean": "true or false", "null": "null"}


#: A value read from JSON, named in words by its Python type; first match wins (bool before int).
_PYTHON_TYPES = ((bool, "a boolean"), (dict, "a JSON object"), (list, "a list"), (int, "an integer"),
                 (float, "a number"), (str, "a string"))


def _json_type(value: Any) -> str:
    for kind, words in _PYTHON_TYPES:
        if isinstance(value, kind):
            return words
    return "null" if value is None else type(value).__name__


#: Longest shown text of a received string or number in a message (a field may hold megabytes).
SHOWN_CHARS = 60


def shown(value: Any) -> str:
    """A received value for a message: JSON text (control characters escaped), cut to a few dozen characters
    with its full length said, and its JSON type."""
    text = json.dumps(value)
    if isinstance(value, (dict, list)):
        text = text if len(text) <= 40 else text[:37] + "..."
    elif len(text) > SHOWN_CHARS:
        length = f", {len(value):,} characters" if isinstance(value, str) else ""
        text = f"{text[:SHOWN_CHARS - 3]}...{length}"
    return f"{text} ({_json_type(value)})"


def _schema_error(error) -> ProblemFileError:
    """A ProblemFileError naming the JSON path, the expectation and the value of a jsonschema error."""
    path = tuple(error.absolute_path)
    field = json_path(path) if path else "file"
    kind, spec, value = error.validator, error.validator_value, error.instance
    if kind == "additionalProperties":
        known = sorted(error.schema.get("properties", {}))
        unknown = sorted(k for k in value if k not in known)
        key = unknown[0]
        close = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
        fix = f"Did you mean {close[0]!r}?" if close else ""
        return ProblemFileError(json_path(path + (key,)), f"one of the keys {known}", f"unknown key {key!r}", fix)
    if kind == "required":
        missing = next(k for k in spec if k not in value)
        return ProblemFileError(json_path(path + (missing,)), "a value", "nothing (key missing)")
    if kind == "type":
        types = spec if isinstance(spec, list) else [spec]
        expected = " or ".join(_JSON_TYPES.get(t, t) for t in types)
        if "number" in types or "integer" in types:
            expected += " (booleans are not numbers)" if isinstance(value, bool) else ""
        return ProblemFileError(field, expected, shown(value))
    if kind in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        op = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">", "exclusiveMaximum": "<"}[kind]
        if "magnitude" in error.schema.get("description", ""):
            return ProblemFileError(field, f"{error.schema['description']}; rescale the units", shown(value))
        return ProblemFileError(field, f"a value {op} {spec:g}" if isinstance(spec, float) else f"a value {op} {spec}",
                                shown(value))
    if kind in ("enum", "const"):
        options = spec if kind == "enum" else [spec]
        return ProblemFileError(field, "one of " + ", ".join(json.dumps(o) for o in options), shown(value))
    if kind == "minItems":
        return ProblemFileError(field, f"a list of at least {spec} item(s)", shown(value))
    if kind == "maxItems":
        return ProblemFileError(field, f"a list of at most {spec} item(s)", shown(value))
    if kind == "pattern":
        return ProblemFileError(field, _PATTERN_WORDS.get(spec, f"a string matching {spec}"), shown(value))
    if kind == "not" and error.absolute_path and error.absolute_path[-1] == "name":
        return ProblemFileError(field, "a name other than 'min' and 'max' (reserved for the array form of bounds)",
                                shown(value))
    if kind in ("minLength", "maxLength"):
        return ProblemFileError(field, f"a string of {'at least' if kind == 'minLength' else 'at most'} {spec} "
                                "characters", shown(value))
    message = error.message if len(error.message) <= 200 else error.message[:197] + "..."
    return ProblemFileError(field, f"a value matching the problem schema ({kind})", f"{shown(value)}: {message}")


#: The patterns of the schema in words (names and units: amcp_drake/model/signals.py).
_PATTERN_WORDS = {
    "^[A-Za-z][A-Za-z0-9_]{0,23}$": "a name of 1 to 24 characters: a letter, then letters, digits or '_'",
    "^[A-Za-z0-9 /*^.()%_°-]{0,16}$": "a unit of at most 16 characters among letters, digits, space and / * ^ . ( ) % - _ °",
}


def _deepest(error):
    """For anyOf errors, the alternative that got furthest into the value (the most specific message);
    when every alternative failed on the type of the value itself, one error listing the types."""
    while error.context:
        if all(c.validator == "type" and c.absolute_path == error.absolute_path for c in error.context):
            import copy

            combined = copy.copy(error.context[0])
            combined.validator_value = [t for c in error.context for t in
                                        (c.validator_value if isinstance(c.validator_value, list) else [c.validator_value])]
            return combined
        error = max(error.context, key=lambda e: (len(e.absolute_path), e.validator != "type"))
    return error


def validate_layout(data: Any) -> None:
    """Check ``data`` against the problem schema; raise ProblemFileError naming the first bad field."""
    if not isinstance(data, dict):
        raise ProblemFileError("file", "a JSON object at top level", shown(data))
    fmt = data.get("format")
    if fmt != FORMAT:
        raise ProblemFileError("format", f"'{FORMAT}'", shown(fmt))
    if type(data.get("version")) is not int or data.get("version") != VERSION:  # 1.0 and true are not 1
        raise ProblemFileError("version", f"{VERSION} (the only problem-file version this amcp reads)",
                               shown(data.get("version")))
    errors = sorted(_schema_validator().iter_errors(data), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        raise _schema_error(_deepest(errors[0]))


def spec_from_dict(data: dict, reduce_rows: bool = True) -> ProblemSpec:
    """Build and validate a :class:`ProblemSpec` from the documented JSON layout.

    ``reduce_rows``: remove the redundant rows of W.H, Θ and Z (with a note in ``spec.notes``) unless
    the file says ``"keep_redundant_rows": true``. Trajectory files pass False: a recorded run is
    re-checked on exactly the problem it ran."""
    validate_layout(data)
    raw, notes = _problem_fields(data)
    if reduce_rows and not data.get("keep_redundant_rows", False):
        from amcp_drake.model.limits import reduce_rows as reduce_redundant

        changes, reduced = reduce_redundant(raw["H_w"], raw["H_theta"], raw["h_theta"], raw["F"], raw["G"])
        raw.update(changes)
        notes += reduced
    problem = Problem(**raw)
    design = DesignOptions(**_known_keys("design", data.get("design", {}) or {}, _DESIGN_FIELDS))
    scenario = None
    if data.get("scenario") is not None:
        sc = data["scenario"]
        if not isinstance(sc, dict):
            raise ProblemFileError("scenario", "a JSON object", type(sc).__name__)
        scenario = Scenario(**_known_keys("scenario", sc, _SCENARIO_FIELDS))
    online = None
    if data.get("online") is not None:
        online = options_from_dict(data["online"], where="online")
    return ProblemSpec(problem=problem, design=design, scenario=scenario, online=online, notes=tuple(notes))


def _problem_fields(data: dict) -> tuple[dict, list[str]]:
    """The :class:`Problem` keyword arguments of a validated layout and the notes of the translation of
    the engineering forms (bounds by name, boxes, continuous time: model/problem_builder.py)."""
    from amcp_drake.model.problem_builder import problem_fields

    system, W, Theta = _get(data, "system", ""), _get(data, "W", ""), _get(data, "Theta", "")
    Z, bounds, cost = data.get("Z") or {}, data.get("bounds") or {}, _get(data, "cost", "")
    return problem_fields(
        A0=_get(system, "A0", "system"), B0=_get(system, "B0", "system"),
        A=_get(system, "A", "system"), B=_get(system, "B", "system"), continuous=system.get("continuous", False),
        dt=data.get("dt"), states=data.get("states"), inputs=data.get("inputs"),
        W_H=W.get("H"), W_box=W.get("box"), Theta_H=Theta.get("H"), Theta_h=Theta.get("h"),
        Theta_box=Theta.get("box"), x_bounds=bounds.get("x"), u_bounds=bounds.get("u"),
        F=Z.get("F"), G=Z.get("G"), Q=_get(cost, "Q", "cost"), R=_get(cost, "R", "cost"), N=_get(cost, "N", "cost"),
        theta_hat0=data.get("theta_hat0"), name=data.get("name", "problem"))


def options_from_dict(data: Any, where: str = "options"):
    """:class:`~amcp_drake.model.options.OnlineOptions` from a JSON object (unknown keys rejected)."""
    from dataclasses import fields

    from amcp_drake.model.options import OnlineOptions

    if not isinstance(data, dict):
        raise ProblemFileError(where, "a JSON object", type(data).__name__)
    return OnlineOptions(**_known_keys(where, data, {f.name for f in fields(OnlineOptions)}))


def _known_keys(section: str, data: dict, allowed: set[str]) -> dict:
    """``data`` when all its keys are in ``allowed``; else a ProblemFileError on ``section`` naming the
    unknown keys and the allowed ones."""
    unknown = set(data) - allowed
    if unknown:
        raise ProblemFileError(section, f"keys among {sorted(allowed)}", f"unknown keys {sorted(unknown)}")
    return data


def options_to_dict(options) -> dict:
    """The JSON object of an :class:`~amcp_drake.model.options.OnlineOptions` (all fields)."""
    from dataclasses import asdict

    return asdict(options)


def spec_to_dict(spec: ProblemSpec) -> dict:
    """The JSON layout of ``spec`` (inverse of :func:`spec_from_dict`)."""
    pr = spec.problem
    data: dict[str, Any] = {
        "format": FORMAT, "version": VERSION, "name": pr.name,
        # the rows are exactly those of the problem that ran (replays and trajectories reproduce it)
        "keep_redundant_rows": True,
        "system": {"A0": pr.A0.tolist(), "B0": pr.B0.tolist(), "A": pr.A.tolist(), "B": pr.B.tolist()},
        "W": {"H": pr.H_w.tolist()},
        "Theta": {"H": pr.H_theta.tolist(), "h": pr.h_theta.tolist()},
        "Z": {"F": pr.F.tolist(), "G": pr.G.tolist()},
        "cost": {"Q": pr.Q.tolist(), "R": pr.R.tolist(), "N": pr.N},
        "theta_hat0": pr.theta_hat0.tolist(),
    }
    if pr.states:
        data["states"] = signals_to_json(pr.states)
    if pr.inputs:
        data["inputs"] = signals_to_json(pr.inputs)
    if pr.dt is not None:
        data["dt"] = pr.dt
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
                            "steps": sc.steps, "seed": sc.seed,
                            "disturbance": np.asarray(sc.disturbance).tolist() if sc.explicit_disturbance
                            else sc.disturbance}
    if spec.online is not None:
        data["online"] = options_to_dict(spec.online)
    return data


def load_spec(path: str | os.PathLike) -> ProblemSpec:
    """Read a problem file (see module docstring)."""
    data = load_json_strict(path, ProblemFileError, "problem file")
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


# -- output paths ------------------------------------------------------------------------------------
# -- output paths ------------------------------------------------------------------------------
def _nearest_existing(path: Path) -> Path:
    probe = path
    while not (probe.exists() or probe.is_symlink()):
        if probe.parent == probe:
            break
        probe = probe.parent
    return probe


def _require_writable_dir(option: str, given: str, folder: Path) -> None:
    """Create and remove a probe directory in ``folder`` (the only reliable test: root passes
    ``os.access`` everywhere, yet cannot create files in /proc or on a read-only mount)."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".amcp-write-probe-", dir=folder))
    except OSError as exc:
        raise ProblemError(option, "a path in a writable directory",
                           f"{given!r}: cannot create files in {folder} ({exc.strerror or exc})") from None


def check_output_dir(option: str, path: str | os.PathLike | None) -> Path:
    """A usable output directory for ``option``: not empty, not a file, not below a file, writable
    (existing or to be created). Raises ProblemError (exit 2) before anything is computed."""
    given = "" if path is None else str(path)
    if not given.strip():
        raise ProblemError(option, "a directory path", "an empty string (it would write into the current directory)")
    out = Path(given)
    if (out.exists() or out.is_symlink()) and not out.is_dir():
        raise ProblemError(option, "a directory (new or existing)", f"{given!r} is a file")
    base = _nearest_existing(out)
    if not base.is_dir():
        raise ProblemError(option, "a directory path (new or existing)", f"{given!r} lies below the file {base}")
    _require_writable_dir(option, given, base)
    return out


def check_output_file(option: str, path: str | os.PathLike | None) -> Path:
    """A usable output file path for ``option``: not empty, not a directory, its folder writable."""
    out, base = _file_path(option, path, "a file path")
    _require_writable_dir(option, str(path), base)
    return out


def check_store_path(option: str, path: str | os.PathLike | None) -> Path:
    """A campaign store path: not empty, not a directory, not below a file (SQLite opens or creates it;
    whether its content is a store is the campaign's check)."""
    return _file_path(option, path, "the path of a SQLite store file")[0]


def _file_path(option: str, path: str | os.PathLike | None, expected: str) -> tuple[Path, Path]:
    """(path, its nearest existing folder) for a file ``option``: not empty, not a directory, not
    below a regular file. ProblemError naming ``option`` otherwise."""
    given = "" if path is None else str(path)
    if not given.strip():
        raise ProblemError(option, expected, "an empty string")
    out = Path(given)
    if out.is_dir():
        raise ProblemError(option, expected, f"{given!r} is a directory")
    base = _nearest_existing(out.parent)
    if not base.is_dir():
        raise ProblemError(option, expected if expected != "a file path" else
                           "a file path (its folder new or existing)", f"{given!r} lies below the file {base}")
    return out, base


def jsonable(value: Any) -> Any:
    """Nested data made writable as strict JSON: numpy scalars and arrays converted to Python, tuples to
    lists, keys to strings, non-finite floats (not JSON, RFC 8259) replaced by None."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if np.isfinite(value) else None
    return value


def write_json_atomic(data: Any, path: str | os.PathLike) -> Path:
    """Write JSON to ``path`` through a temporary file in the same folder and a rename."""
    return write_text_atomic(json.dumps(data, indent=1, allow_nan=False), path)


def write_text_atomic(text: str, path: str | os.PathLike) -> Path:
    """Write text (UTF-8) to ``path`` through a temporary file in the same folder and a rename."""
    return write_bytes_atomic(text.encode("utf-8"), path)


def write_bytes_atomic(data: bytes, path: str | os.PathLike) -> Path:
    """Write bytes to ``path`` through a temporary file in the same folder and a rename: a reader
    sees the old file or the whole new one, never a half-written one. On a failure (a full disk) the
    temporary file and the folders created for it are removed."""
    path = Path(path)
    created = []
    probe = path.parent
    while not (probe.exists() or probe.is_symlink()) and probe.parent != probe:
        created.append(probe)
        probe = probe.parent
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    except BaseException:
        _remove_empty_dirs(created)
        raise
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp creates 0600; a result file is as readable as any other
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        _remove_empty_dirs(created)
        raise
    return path


def _remove_empty_dirs(folders: list[Path]) -> None:
    """Remove the folders (innermost first) while they are empty."""
    for folder in folders:
        try:
            folder.rmdir()
        except OSError:
            return


__all__ = [
    "ProblemError",
    "check_output_dir",
    "check_output_file",
    "check_store_path",
    "load_problem",
    "load_spec",
    "options_from_dict",
    "options_to_dict",
    "problem_schema",
    "save_spec",
    "spec_from_dict",
    "spec_to_dict",
    "validate_layout",
    "write_json_atomic",
    "write_bytes_atomic",
    "write_text_atomic",
]
