"""The layout of trajectory files, checked before anything is built from them (docs/trajectory-format.md).

A trajectory file is validated as strictly as a problem file: the JSON Schema
``amcp_drake/data/trajectory.schema.json`` (numbers are JSON numbers, never strings or booleans, of
magnitude at most :data:`MAX_ABS_RECORDED`; counts and indices are integers; statuses from the fixed
list), then :func:`check_consistency`: the records are numbered 0, 1, ..., the states, inputs and
disturbances have matching lengths, and ``stop_reason`` agrees with the records. Every message names the
JSON path of the field (``records[10].k``), what was expected and what was received.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from functools import lru_cache
from importlib import resources
from typing import Any

from amcp_drake.model.errors import ProblemFileError, TrajectoryError

#: Largest magnitude of a recorded number (states, inputs, multipliers, costs, times). A problem within
#: the problem-file bound (1e9) records far smaller numbers; 1e15 leaves room for badly scaled runs
#: while keeping every product the checks form (squares, Gram matrices) far from overflow.
MAX_ABS_RECORDED = 1e15
#: Statuses of a step whose input was applied: solved, or answered by the checked fallback ("inaccurate").
APPLIED_STATUSES = ("optimal", "optimal_inaccurate")
#: The stop reasons :func:`amcp_drake.online.simulate.simulate` writes.
STOP_REASON = re.compile(r"^(completed|step ([0-9]+): status ([a-z_]+)|inconsistent data at step ([0-9]+))$")


@lru_cache(maxsize=1)
def trajectory_schema() -> dict:
    """The JSON Schema of trajectory files (``amcp_drake/data/trajectory.schema.json``)."""
    return json.loads((resources.files("amcp_drake") / "data" / "trajectory.schema.json").read_text())


def _number_ok(x: Any, bound: float) -> bool:
    kind = type(x)
    return (kind is float or kind is int) and -bound <= x <= bound


def _vector_ok(values: Any, bound: float, allow_empty: bool = False) -> bool:
    if not isinstance(values, list) or not (values or allow_empty):
        return False
    return all(_number_ok(x, bound) for x in values)


def _array_ok(values: Any, bound: float) -> bool:
    """A nested list of numbers within ±bound (any depth, possibly empty), checked iteratively."""
    stack = [values]
    while stack:
        item = stack.pop()
        if not isinstance(item, list):
            return False
        for x in item:
            if type(x) is list:
                stack.append(x)
            elif not _number_ok(x, bound):
                return False
    return True


@lru_cache(maxsize=1)
def _validator():
    """A Draft 2020-12 validator of the trajectory schema whose ``items`` keyword accepts a valid list
    of numbers (vector, matrix, nested array) in one Python pass and falls back to the standard
    per-item validation, with its exact messages, only when the list is not valid."""
    import jsonschema

    schema = trajectory_schema()
    entry = schema["$defs"]["entry"]
    bound = float(entry["maximum"])
    assert entry["minimum"] == -bound == -MAX_ABS_RECORDED
    standard_items = jsonschema.Draft202012Validator.VALIDATORS["items"]
    fast_checks = {
        "#/$defs/entry": lambda v: _vector_ok(v, bound, allow_empty=True),
        "#/$defs/vector": lambda v: isinstance(v, list) and all(_vector_ok(row, bound) for row in v),
        "#/$defs/tensor": lambda v: _array_ok(v, bound),
    }

    def items(validator, item_schema, instance, parent_schema):
        check = fast_checks.get(item_schema.get("$ref")) if isinstance(item_schema, dict) else None
        if check is not None and check(instance):
            return
        yield from standard_items(validator, item_schema, instance, parent_schema)

    # an integer is an integer literal: 10.0 is a number (JSON Schema would accept it as an integer)
    types = jsonschema.Draft202012Validator.TYPE_CHECKER.redefine("integer", lambda checker, x: type(x) is int)
    fast = jsonschema.validators.extend(jsonschema.Draft202012Validator, {"items": items}, type_checker=types)
    return fast(schema)


_TYPES: dict[str, Callable[[Any], bool]] = {
    "object": lambda v: type(v) is dict,
    "array": lambda v: type(v) is list,
    "string": lambda v: type(v) is str,
    "integer": lambda v: type(v) is int,
    "number": lambda v: type(v) is int or type(v) is float,
    "null": lambda v: v is None,
    "boolean": lambda v: type(v) is bool,
}


def _compile(schema: dict, defs: dict, named: dict[str, Callable[[Any], bool]]) -> Callable[[Any], bool]:
    """A predicate equivalent to validating against ``schema`` (the keywords the trajectory schema uses;
    any other keyword raises KeyError, and the caller then uses jsonschema alone). True means valid;
    False means "let jsonschema find and word the error"."""
    known = {"$ref", "anyOf", "type", "const", "enum", "minimum", "maximum", "exclusiveMinimum", "minLength", "maxLength",
             "pattern", "required", "properties", "additionalProperties", "items", "minItems", "maxItems",
             "description", "title", "$schema", "$id", "$defs"}
    unknown = set(schema) - known
    if unknown:
        raise KeyError(sorted(unknown))
    if "$ref" in schema:
        name = schema["$ref"].removeprefix("#/$defs/")
        if name not in named:
            named[name] = lambda v: False  # recursion guard, replaced below
            compiled = _compile(defs[name], defs, named)
            named[name] = compiled
        return lambda v: named[name](v)
    checks: list[Callable[[Any], bool]] = []
    if "anyOf" in schema:
        options = [_compile(sub, defs, named) for sub in schema["anyOf"]]
        checks.append(lambda v: any(option(v) for option in options))
    if "type" in schema:
        checks.append(_TYPES[schema["type"]])
    if "const" in schema:
        const = schema["const"]
        checks.append(lambda v: type(v) is type(const) and v == const)
    if "enum" in schema:
        values = schema["enum"]
        checks.append(lambda v: any(type(v) is type(x) and v == x for x in values))
    number = lambda v: type(v) is int or type(v) is float  # noqa: E731
    if "minimum" in schema:
        low = schema["minimum"]
        checks.append(lambda v: not number(v) or v >= low)
    if "maximum" in schema:
        high = schema["maximum"]
        checks.append(lambda v: not number(v) or v <= high)
    if "exclusiveMinimum" in schema:
        low_open = schema["exclusiveMinimum"]
        checks.append(lambda v: not number(v) or v > low_open)
    if "minLength" in schema:
        length = schema["minLength"]
        checks.append(lambda v: type(v) is not str or len(v) >= length)
    if "maxLength" in schema:
        longest = schema["maxLength"]
        checks.append(lambda v: type(v) is not str or len(v) <= longest)
    if "pattern" in schema:
        pattern = re.compile(schema["pattern"])
        checks.append(lambda v: type(v) is not str or pattern.search(v) is not None)
    if "items" in schema or "minItems" in schema or "maxItems" in schema:
        item = _compile(schema.get("items", {}), defs, named)
        least, most = schema.get("minItems", 0), schema.get("maxItems")
        checks.append(lambda v: type(v) is not list or (len(v) >= least and (most is None or len(v) <= most)
                                                        and all(item(x) for x in v)))
    if "required" in schema or "properties" in schema or "additionalProperties" in schema:
        required = tuple(schema.get("required", ()))
        props = {key: _compile(sub, defs, named) for key, sub in schema.get("properties", {}).items()}
        extra = schema.get("additionalProperties", True)
        other = (lambda v: True) if extra is True else (lambda v: False) if extra is False else _compile(extra, defs,
                                                                                                         named)

        def check_object(v) -> bool:
            if type(v) is not dict:
                return True
            if any(key not in v for key in required):
                return False
            for key, value in v.items():
                check = props.get(key)
                if not (check(value) if check is not None else other(value)):
                    return False
            return True

        checks.append(check_object)
    return lambda v: all(check(v) for check in checks)


@lru_cache(maxsize=1)
def _fast_check() -> Callable[[Any], bool] | None:
    """The whole trajectory schema as one predicate (:func:`_compile`), with numeric lists checked in one
    pass each; None when the schema uses a keyword the compiler does not know."""
    schema = trajectory_schema()
    defs = schema["$defs"]
    bound = float(defs["entry"]["maximum"])
    named: dict[str, Callable[[Any], bool]] = {
        "entry": lambda v: _number_ok(v, bound),
        "vector": lambda v: _vector_ok(v, bound),
        "matrix": lambda v: type(v) is list and bool(v) and all(_vector_ok(row, bound) for row in v),
        "rows": lambda v: type(v) is list and all(_vector_ok(row, bound) for row in v),
        "array": lambda v: _array_ok(v, bound),
        "tensor": lambda v: _number_ok(v, bound) or _array_ok(v, bound),
    }
    try:
        return _compile(schema, defs, named)
    except KeyError:
        return None


def _message(error) -> str:
    from amcp_drake.model.problem_io import _deepest, _schema_error

    error = _deepest(error)
    if error.validator == "pattern" and tuple(error.absolute_path) == ("stop_reason",):
        return (f"stop_reason: expected one of \"completed\", \"step K: status S\", \"inconsistent data at step K\" "
                f"(what a run writes); received {json.dumps(error.instance)}")
    return str(_schema_error(error))


def validate_trajectory_layout(data: Any) -> None:
    """Check ``data`` against the trajectory schema; TrajectoryError naming the first bad field. A valid
    file is accepted by the compiled predicate alone (:func:`_fast_check`, linear in the file); only an
    invalid one goes through jsonschema, for the exact field and message."""
    fast = _fast_check()
    if fast is not None and fast(data):
        return
    errors = sorted(_validator().iter_errors(data), key=lambda e: [str(p) for p in e.absolute_path])
    if errors:
        raise TrajectoryError(_message(errors[0]))


def _fail(field: str, expected: str, received: str) -> TrajectoryError:
    return TrajectoryError(str(ProblemFileError(field, expected, received)))


def check_consistency(data: dict) -> None:
    """The records against each other and against ``stop_reason`` (a layout already valid):

    * ``records[i].k == i``; len(x) = T + 1 and len(w) = T for T = len(u) applied inputs;
    * every step that applied an input has an input ``u`` and a status in :data:`APPLIED_STATUSES`;
    * ``"completed"``: T + 1 records (the last one at x_T, whatever its status), the others applied;
    * ``"step K: status S"``: K = T, K + 1 records, records[K] has status S (not optimal) and no input;
    * ``"inconsistent data at step K"``: K = T records, all applied (step K raised before its record), or
      K + 1 records whose last one records the event (no input; ``AdaptiveMPC.step(x, on_inconsistent="record")``);
    * ``theta_star`` and ``w`` both null (a measured run) or both recorded.
    """
    records, steps = data["records"], len(data["u"])
    for i, record in enumerate(records):
        if record["k"] != i:
            raise _fail(f"records[{i}].k", f"{i} (records are numbered 0, 1, ... in order)", json.dumps(record["k"]))
    if len(data["x"]) != steps + 1:
        raise _fail("x", f"{steps + 1} states (one more than the {steps} inputs in u)", f"{len(data['x'])} states")
    if (data["theta_star"] is None) != (data["w"] is None):
        raise _fail("theta_star" if data["w"] is None else "w",
                    "null together with " + ("w" if data["w"] is None else "theta_star") +
                    " (a measured run: both unknown) or both recorded (a simulated run)", "a value" if data["w"] is None
                    else "null")
    if data["w"] is not None and len(data["w"]) != steps:
        raise _fail("w", f"{steps} disturbances (one per input in u)", f"{len(data['w'])}")
    reason = data["stop_reason"]
    match = STOP_REASON.match(reason)
    if match.group(1) == "completed":
        expected_records, last_status = steps + 1, None
    elif match.group(2) is not None:
        stopped, last_status = int(match.group(2)), match.group(3)
        if stopped != steps or last_status == "optimal":
            raise _fail("stop_reason", f"\"step {steps}: status S\" with S not optimal (u holds {steps} inputs)",
                        json.dumps(reason))
        expected_records = steps + 1
    else:
        stopped = int(match.group(4))
        if stopped != steps:
            raise _fail("stop_reason", f"\"inconsistent data at step {steps}\" (u holds {steps} inputs)",
                        json.dumps(reason))
        # K records (the step raised), or K + 1 with the event recorded at step K (no input applied)
        expected_records, last_status = (steps + 1 if len(records) == steps + 1 else steps), None
    if len(records) != expected_records:
        raise _fail("records", f"{expected_records} step records (stop_reason {json.dumps(reason)}, {steps} inputs)",
                    f"{len(records)}")
    applied = records if len(records) == steps else records[:-1]
    for i, record in enumerate(applied):
        if record["status"] not in APPLIED_STATUSES:
            raise _fail(f"records[{i}].status", f"\"optimal\" or \"optimal_inaccurate\" (stop_reason "
                        f"{json.dumps(reason)}: step {i} applied an input)", json.dumps(record["status"]))
        if record["u"] is None:
            raise _fail(f"records[{i}].u", f"the input applied at step {i} (stop_reason {json.dumps(reason)})", "null")
    if match.group(4) is not None and len(records) == steps + 1 and records[-1]["u"] is not None:
        raise _fail(f"records[{steps}].u", f"null (stop_reason {json.dumps(reason)}: the step recorded the event and "
                    "applied no input)", "an input")
    if last_status is not None:
        last = len(records) - 1
        if records[-1]["status"] != last_status:
            raise _fail(f"records[{last}].status", json.dumps(last_status) + " (as stop_reason says)",
                        json.dumps(records[-1]["status"]))
        if records[-1]["u"] is not None:
            raise _fail(f"records[{last}].u", f"null (stop_reason {json.dumps(reason)}: no input applied)",
                        "an input")


__all__ = ["MAX_ABS_RECORDED", "check_consistency", "trajectory_schema", "validate_trajectory_layout"]
