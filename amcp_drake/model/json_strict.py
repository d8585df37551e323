"""Strict reading of JSON files (problem files, trajectories): encodings, duplicate keys, depth, numbers.

Python's :mod:`json` is lenient in ways that hide mistakes in a hand-written problem file: the last
of two equal keys wins without a word, ``NaN``/``Infinity`` literals are accepted, ``1e400`` becomes
``inf``, a 5000-digit integer raises a bare ``ValueError`` and 100,000 nested brackets a
``RecursionError``. :func:`loads_strict` turns each of these into a
:class:`~amcp_drake.model.errors.ProblemFileError` (or the error class the caller asks for) whose message
names the file, the JSON path of the offending value (``cost.R[0][0]``), what was expected and what
was received. :func:`read_text_strict` refuses files that are not UTF-8 text (binary data, UTF-16/32
with or without a byte-order mark), naming the encoding it recognised.

Decisions (docs/decisions.md, "Strict input files"):

* ``MAX_DEPTH``: a problem file nests at most 4 levels (``system.A[i][r][c]``), a trajectory about 6;
  64 leaves room for future layouts and is far below Python's recursion limit.
* ``MAX_INT_DIGITS``: integers of more than 18 digits do not fit a signed 64-bit integer (seeds in
  the campaign store, horizons passed to Drake); they are refused wherever they appear.
* Non-finite numbers (``NaN``, ``Infinity``, ``1e400``) are refused wherever they appear; they are
  not JSON (RFC 8259) and no field of either format can hold one.
"""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path
from typing import Any

from amcp_drake.model.errors import ProblemFileError

#: Deepest nesting accepted (a problem file needs 4 levels, a trajectory about 6).
MAX_DEPTH = 64
#: Longest integer literal accepted: 18 digits always fit a signed 64-bit integer.
MAX_INT_DIGITS = 18
#: Largest problem file or points file read, in bytes (docs/decisions.md, "Input size limits"): 64 MiB of
#: JSON is about 3 million numbers, far more than any problem within the size limits of a run needs.
MAX_INPUT_BYTES = 64 * 2**20
#: Bytes read first, and checked for binary data before the rest is read.
READ_CHUNK = 1 << 16
#: The first two bytes of gzip data (RFC 1952).
GZIP_MAGIC = b"\x1f\x8b"

_BOMS = (
    (b"\x00\x00\xfe\xff", "UTF-32 (big-endian, with byte-order mark)"),
    (b"\xff\xfe\x00\x00", "UTF-32 (little-endian, with byte-order mark)"),
    (b"\xfe\xff", "UTF-16 (big-endian, with byte-order mark)"),
    (b"\xff\xfe", "UTF-16 (little-endian, with byte-order mark)"),
)


class _Rejected:
    """A value the parser met but may not accept; reported with its JSON path after parsing."""

    def __init__(self, expected: str, received: str) -> None:
        self.expected = expected
        self.received = received


def _parse_int(text: str) -> Any:
    digits = text.lstrip("-")
    if len(digits) > MAX_INT_DIGITS:
        return _Rejected(f"an integer of at most {MAX_INT_DIGITS} digits",
                         f"an integer of {len(digits)} digits ({text[:12]}...)")
    return int(text)


def _parse_float(text: str) -> Any:
    value = float(text)
    if not math.isfinite(value):
        return _Rejected("a finite number (at most about 1.8e308 in magnitude)", f"{text[:40]} (overflows to {value})")
    return value


def _parse_constant(text: str) -> _Rejected:
    return _Rejected("a finite number (NaN and Infinity are not JSON)", text)


def json_path(parts: tuple[Any, ...]) -> str:
    """``("cost", "R", 0, 0)`` -> ``"cost.R[0][0]"`` (the file root is ``"file"``)."""
    text = ""
    for part in parts:
        if isinstance(part, int):
            text += f"[{part}]"
        else:
            text += f".{part}" if text else str(part)
    return text or "file"


_SCALARS = frozenset({int, float, str, bool, type(None)})


class _Parse:
    """Per-call parser state: the objects holding a duplicate key, and whether a number was rejected."""

    def __init__(self) -> None:
        self.duplicates: dict[int, str] = {}
        self.rejected = False

    def object_pairs(self, pairs: list[tuple[str, Any]]) -> dict:
        obj: dict = {}
        for key, value in pairs:
            if key in obj and id(obj) not in self.duplicates:
                self.duplicates[id(obj)] = key
            obj[key] = value
        return obj

    def reject(self, value: _Rejected) -> _Rejected:
        self.rejected = True
        return value


def _check_tree(data: Any, state: _Parse, source: str, error: type[Exception]) -> None:
    """Walk the containers of the parsed tree iteratively (a list of numbers is skipped in one C-level
    pass); raise on the first duplicate key, rejected number or excess depth."""
    if isinstance(data, _Rejected):
        raise _error(error, "file", data.expected, data.received)
    if not isinstance(data, (dict, list)):  # a lone scalar (null, 5, "text"): nothing inside to check
        return
    look_inside = state.rejected or bool(state.duplicates)
    stack: list[tuple[Any, tuple[Any, ...]]] = [(data, ())]
    while stack:
        value, path = stack.pop()
        if len(path) >= MAX_DEPTH:
            raise _error(error, json_path(path[:6]) + "...", f"JSON nested at most {MAX_DEPTH} levels deep",
                         f"deeper nesting in {source}")
        if isinstance(value, dict):
            key = state.duplicates.get(id(value))
            if key is not None:
                raise _error(error, json_path(path + (key,)), "each key once per JSON object",
                             f"key {key!r} more than once in {source} (the last one would silently win)")
            items = value.items()
        else:
            if not look_inside:
                kinds = set(map(type, value))
                if kinds <= _SCALARS:
                    continue
                if kinds == {list} and len(path) + 2 < MAX_DEPTH:  # a matrix: rows of numbers need no visit
                    rows = [(row, path + (i,)) for i, row in enumerate(value) if not set(map(type, row)) <= _SCALARS]
                    stack.extend(reversed(rows))
                    continue
            items = enumerate(value)
        children = []
        for key, child in items:
            if type(child) in _SCALARS:
                continue
            if isinstance(child, _Rejected):
                raise _error(error, json_path(path + (key,)), child.expected, child.received)
            children.append((child, path + (key,)))
        stack.extend(reversed(children))


def _error(error: type[Exception], field: str, expected: str, received: str) -> Exception:
    if issubclass(error, ProblemFileError):
        return error(field, expected, received)
    return error(f"{field}: expected {expected}; received {received}")


def loads_strict(text: str, source: str = "file", error: type[Exception] = ProblemFileError) -> Any:
    """Parse JSON text strictly (module docstring); ``source`` names the file in messages.

    ``error`` is the exception class raised: a :class:`ProblemFileError` subclass gets
    (field, expected, received); any other class a single message in the same words."""
    state = _Parse()

    def parse_int(text: str) -> Any:
        value = _parse_int(text)
        return state.reject(value) if isinstance(value, _Rejected) else value

    def parse_float(text: str) -> Any:
        value = float(text)
        if value - value == 0.0:  # finite (inf - inf and nan - nan are nan)
            return value
        return state.reject(_parse_float(text))

    try:
        data = json.loads(text, object_pairs_hook=state.object_pairs, parse_int=parse_int, parse_float=parse_float,
                          parse_constant=lambda constant: state.reject(_parse_constant(constant)))
    except json.JSONDecodeError as exc:
        raise _error(error, "file", "valid JSON", f"{source}: {exc.msg} at line {exc.lineno}, column {exc.colno}") \
            from None
    except RecursionError:
        raise _error(error, "file", f"JSON nested at most {MAX_DEPTH} levels deep",
                     f"{source}: nesting too deep to parse") from None
    _check_tree(data, state, source, error)
    return data


def decode_utf8(raw: bytes, source: str, error: type[Exception] = ProblemFileError) -> str:
    """Decode UTF-8 text (a UTF-8 byte-order mark is allowed); refuse binary data and other encodings."""
    for bom, name in _BOMS:
        if raw.startswith(bom):
            raise _error(error, "file", "UTF-8 encoded JSON text", f"{source} is {name}; save it as UTF-8")
    if raw.startswith(b"\xef\xbb\xbf"):
        raw = raw[3:]
    if b"\x00" in raw[:4096]:
        guess = _guess_nul_encoding(raw[:400])
        raise _error(error, "file", "UTF-8 encoded JSON text", f"{source} contains NUL bytes ({guess})")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _error(error, "file", "UTF-8 encoded JSON text",
                     f"{source}: byte 0x{raw[exc.start]:02x} at offset {exc.start} is not UTF-8 "
                     "(binary data, or a Latin-1/Windows-1252 file)") from None


def _guess_nul_encoding(sample: bytes) -> str:
    """Name the encoding of text with NUL bytes from their positions (ASCII text in UTF-16/32)."""
    def zero(start: int, step: int) -> bool:
        part = sample[start::step]
        return len(part) >= 2 and not any(part)

    if not any(sample):  # only NUL bytes (/dev/zero): no text in any encoding
        return "binary data"
    if zero(1, 4) and zero(2, 4) and zero(3, 4):
        return "UTF-32 (little-endian) without byte-order mark"
    if zero(0, 4) and zero(1, 4) and zero(2, 4):
        return "UTF-32 (big-endian) without byte-order mark"
    if zero(1, 2):
        return "UTF-16 (little-endian) without byte-order mark"
    if zero(0, 2):
        return "UTF-16 (big-endian) without byte-order mark"
    return "binary data"


def _sniff(first: bytes, source: str, error: type[Exception], gzip_ok: bool) -> None:
    """Refuse binary data from the first chunk of a file, before the rest is read (a device such as
    /dev/zero or /dev/urandom, an image, a gzip file where text is expected)."""
    if gzip_ok and first[:2] == GZIP_MAGIC:
        return
    for bom, name in _BOMS:
        if first.startswith(bom):
            return  # decode_utf8 names the encoding once the (bounded) file is read
    if b"\x00" in first[:READ_CHUNK]:  # refused as decode_utf8 would refuse it, before the rest is read
        guess = _guess_nul_encoding(first[:400])
        raise _error(error, "file", "UTF-8 encoded JSON text", f"{source} contains NUL bytes ({guess})")


def read_bytes_limited(path: str | os.PathLike, limit: int = MAX_INPUT_BYTES,
                       error: type[Exception] = ProblemFileError, what: str = "file", gzip_ok: bool = False) -> bytes:
    """The bytes of ``path``, at most ``limit`` of them: a regular file larger than the limit is refused
    before it is read, any other file (a pipe, a device) as soon as more than ``limit`` bytes arrived,
    and binary data (NUL bytes: /dev/zero, /dev/urandom) after the first :data:`READ_CHUNK` bytes.
    ``gzip_ok``: gzip data (magic 1f 8b) pass the binary check. Errors are ``error`` naming the path."""
    path = Path(path)
    source = str(path)

    def too_big(received: str) -> Exception:
        return _error(error, "file", f"at most {limit:,} bytes (the size limit of a {what}; docs/decisions.md, "
                      "'Input size limits')", f"{source}: {received}")

    try:
        handle = open(path, "rb")
    except IsADirectoryError:
        raise _error(error, "file", f"a readable {what}", f"{path} is a directory") from None
    except OSError as exc:
        raise _error(error, "file", f"a readable {what}", f"{path}: {exc.strerror or exc}") from None
    chunks: list[bytes] = []
    total = 0
    with handle:
        try:
            info = os.fstat(handle.fileno())
            if stat.S_ISDIR(info.st_mode):
                raise _error(error, "file", f"a readable {what}", f"{path} is a directory")
            if stat.S_ISREG(info.st_mode) and info.st_size > limit:
                raise too_big(f"{info.st_size:,} bytes")
            while True:
                chunk = handle.read(READ_CHUNK if not chunks else min(limit + 1 - total, 1 << 24) or 1)
                if not chunk:
                    break
                if not chunks:
                    _sniff(chunk, source, error, gzip_ok)
                total += len(chunk)
                if total > limit:
                    raise too_big(f"more than {limit:,} bytes")
                chunks.append(chunk)
            return b"".join(chunks)
        except MemoryError:
            chunks.clear()
            raise _error(error, "file", f"a {what} that fits in the memory available",
                         f"{source}: memory ran out after {total:,} bytes (MemoryError)") from None
        except IsADirectoryError:
            raise _error(error, "file", f"a readable {what}", f"{path} is a directory") from None
        except OSError as exc:
            raise _error(error, "file", f"a readable {what}", f"{path}: {exc.strerror or exc}") from None


def read_text_strict(path: str | os.PathLike, error: type[Exception] = ProblemFileError,
                     what: str = "file", limit: int = MAX_INPUT_BYTES) -> str:
    """The UTF-8 text of ``path`` (:func:`decode_utf8`), at most ``limit`` bytes
    (:func:`read_bytes_limited`); unreadable files raise ``error`` naming the path."""
    return decode_utf8(read_bytes_limited(path, limit, error, what), str(path), error)


def load_json_strict(path: str | os.PathLike, error: type[Exception] = ProblemFileError, what: str = "file",
                     limit: int = MAX_INPUT_BYTES) -> Any:
    """:func:`read_text_strict` then :func:`loads_strict`."""
    return loads_strict(read_text_strict(path, error, what, limit), str(path), error)


def first_non_finite(value: Any, path: tuple[Any, ...] = ()) -> tuple[str, Any] | None:
    """(JSON path, value) of the first NaN or infinity in a tree of dicts/lists/floats (for writers:
    ``json.dumps(allow_nan=False)`` says only "Out of range float values are not JSON compliant")."""
    stack: list[tuple[Any, tuple[Any, ...]]] = [(value, path)]
    while stack:
        item, where = stack.pop()
        if isinstance(item, float):
            if not math.isfinite(item):
                return json_path(where), item
        elif isinstance(item, dict):
            stack.extend((v, where + (k,)) for k, v in reversed(list(item.items())))
        elif isinstance(item, (list, tuple)):
            stack.extend((v, where + (i,)) for i, v in reversed(list(enumerate(item))))
    return None


__all__ = ["MAX_DEPTH", "MAX_INPUT_BYTES", "MAX_INT_DIGITS", "decode_utf8", "first_non_finite", "json_path",
           "load_json_strict", "loads_strict", "read_bytes_limited", "read_text_strict"]
