"""The solver-neutral corpus format: one optimisation problem of the scheme per JSON file.

A problem is

    minimise  ½ xᵀ P x + qᵀ x + r
    s.t.      lower <= A x <= upper           (rows; lower = upper is an equality, null = unbounded)
              lb <= x <= ub                     (null = unbounded)
              mat(g0 + G x) ⪰ 0                 (each LMI block; mat() reshapes s·s entries column-major)

with the matrices stored sparse as ``{"shape": [m, n], "row": [...], "col": [...], "val": [...]}``
(nested lists, full double precision), so that any solver of any stack can be fed from it. ``kind``
names the problem of the paper it came from (:data:`KINDS`): the tube QP (20) in the plain form of
(15) or the vertex form of (5b), the set updates (9) and (7), the projection QP (12), the gain SDP
(16) and the support LPs of the design. ``reference`` holds the verified answer (``x``, objective,
KKT residuals, the exact basis check of an LP; :mod:`.reference`) or ``{"status": "infeasible", ...}``
with its certificate; ``provenance`` where the problem was recorded.

A file is read strictly (:func:`amcp_drake.model.json_strict.load_json_strict`): a missing or mistyped
field raises :class:`~amcp_drake.model.errors.ProblemFileError` naming it. A corpus file is data from
someone else: its ``id`` must match :data:`ID_PATTERN` (it names the files derived from it, never a
path), and its ``reference`` must have the layout of :func:`check_reference_layout`; whether the
reference is right is checked again by :func:`.reference.check_reference` when the matrix loads it
(:func:`.reference.load_checked_corpus`).
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from amcp_drake.model.errors import ProblemFileError

FORMAT, VERSION = "amcp-solver-corpus", 1

#: kind -> (paper equation, one-line description)
KINDS = {
    "tube_qp_plain": ("(20)", "tube MPC QP, plain form: (15a)-(15d) with the multipliers Λ"),
    "tube_qp_vertex": ("(20)", "tube MPC QP, vertex form of (5b)"),
    "set_update_lp": ("(9)", "fixed-complexity set update LP"),
    "exact_update_lp": ("(7)", "redundancy LP of the exact update (a support LP of Θ_{k-1} ∩ Δ_k)"),
    "projection_qp": ("(12)", "projection of the LMS estimate onto Θ"),
    "gain_sdp": ("(16)", "robust gain / terminal cost LMI"),
    "support_lp": ("(14), A.1", "support-function LP of the offline design"),
}
#: A problem id: letters, digits, ``_``, ``.`` and ``-``, 1 to 64 characters, not starting with ``.`` or ``-``
#: (file names are derived from it: ``<id>.json.gz``, reproducers ``<solver>-<verdict>-<id>.py``).
ID_PATTERN = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}")
ID_EXPECTED = "1 to 64 characters of A-Z a-z 0-9 _ . -, not starting with '.' or '-'"
#: Reference statuses: a verified optimum or a verified infeasibility certificate.
REFERENCE_STATUSES = ("optimal", "infeasible")
#: Problem classes, from the data: an LP has no P and no LMI, an SDP has an LMI.
CLASSES = ("lp", "qp", "sdp")


@dataclass
class CorpusProblem:
    """One problem of the corpus (see the module docstring for the mathematics)."""

    id: str
    kind: str
    P: sp.csr_matrix | None
    q: np.ndarray
    r: float
    A: sp.csr_matrix
    lower: np.ndarray            # -inf where unbounded
    upper: np.ndarray            # +inf where unbounded
    lb: np.ndarray
    ub: np.ndarray
    lmis: list[tuple[int, sp.csr_matrix, np.ndarray]] = field(default_factory=list)  # (size s, G (s², n), g0 (s²,))
    reference: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.q.size)

    @property
    def problem_class(self) -> str:
        if self.lmis:
            return "sdp"
        if self.P is not None and self.P.nnz:
            return "qp"
        return "lp"

    @property
    def size(self) -> int:
        """Stored nonzeros: the order in which the smallest problem of a class is chosen."""
        nnz = self.A.nnz + (self.P.nnz if self.P is not None else 0) + sum(G.nnz for _, G, _ in self.lmis)
        return int(nnz + self.n)

    @property
    def equation(self) -> str:
        return KINDS.get(self.kind, ("?", ""))[0]

    # -- evaluation (numpy only) -----------------------------------------------------------
    def objective(self, x: np.ndarray) -> float:
        x = np.asarray(x, float)
        value = float(self.q @ x + self.r)
        if self.P is not None:
            value += 0.5 * float(x @ (self.P @ x))
        return value

    def lmi_matrix(self, j: int, x: np.ndarray) -> np.ndarray:
        s, G, g0 = self.lmis[j]
        M = (g0 + G @ np.asarray(x, float)).reshape(s, s, order="F")
        return 0.5 * (M + M.T)

    def violation(self, x: np.ndarray) -> float:
        """Largest constraint violation at ``x``, each row relative to 1 + |its bound| (an LMI block:
        its most negative eigenvalue relative to 1 + the largest |entry| of g0); inf for a non-finite x."""
        x = np.asarray(x, float)
        if x.shape != (self.n,) or not np.all(np.isfinite(x)):
            return float("inf")
        worst = 0.0
        Ax = self.A @ x if self.A.shape[0] else np.zeros(0)
        for values, bound, sign in ((Ax, self.upper, 1.0), (Ax, self.lower, -1.0), (x, self.ub, 1.0), (x, self.lb, -1.0)):
            finite = np.isfinite(bound)
            if np.any(finite):
                excess = sign * (values[finite] - bound[finite]) / (1.0 + np.abs(bound[finite]))
                worst = max(worst, float(np.max(excess, initial=0.0)))
        for j, (_, _, g0) in enumerate(self.lmis):
            lam = float(np.linalg.eigvalsh(self.lmi_matrix(j, x))[0])
            worst = max(worst, -lam / (1.0 + float(np.max(np.abs(g0), initial=0.0))))
        return worst

    # -- files -----------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "format": FORMAT, "version": VERSION, "id": self.id, "kind": self.kind, "equation": self.equation,
            "class": self.problem_class, "n": self.n,
            "objective": {"P": None if self.P is None else _sparse_out(self.P), "q": _vec_out(self.q), "r": float(self.r)},
            "linear": {"A": _sparse_out(self.A), "lower": _vec_out(self.lower), "upper": _vec_out(self.upper)},
            "bounds": {"lower": _vec_out(self.lb), "upper": _vec_out(self.ub)},
            "lmi": [{"size": s, "G": _sparse_out(G), "g0": _vec_out(g0)} for s, G, g0 in self.lmis],
            "reference": self.reference, "provenance": self.provenance,
        }

    @classmethod
    def from_dict(cls, data: Any, source: str = "corpus problem", require_reference: bool = True) -> CorpusProblem:
        """The problem of a corpus file's data (module docstring); ``require_reference`` False also takes
        an empty ``reference`` (a crash's reproducer keeps problems without a verifiable answer)."""
        r = _Reader(source)
        r.require(isinstance(data, dict), "", "a JSON object", type(data).__name__)
        r.require(data.get("format") == FORMAT, "format", repr(FORMAT), repr(data.get("format")))
        r.require(data.get("version") == VERSION, "version", str(VERSION), repr(data.get("version")))
        n = r.int(data, "n")
        kind = r.get(data, "kind", str)
        r.require(kind in KINDS, "kind", f"one of {sorted(KINDS)}", repr(kind))
        obj = r.get(data, "objective", dict)
        lin = r.get(data, "linear", dict)
        bnd = r.get(data, "bounds", dict)
        P = None if obj.get("P") is None else r.sparse(obj["P"], "objective.P", (n, n))
        A = r.sparse(lin.get("A"), "linear.A", (None, n))
        m = A.shape[0]
        lmis = []
        for j, block in enumerate(r.get(data, "lmi", list)):
            s = r.int(block, "size", f"lmi[{j}].size")
            lmis.append((s, r.sparse(block.get("G"), f"lmi[{j}].G", (s * s, n)), r.vec(block.get("g0"), f"lmi[{j}].g0", s * s)))
        problem_id = r.get(data, "id", str)
        r.require(is_valid_id(problem_id), "id", ID_EXPECTED, repr(problem_id)[:80])
        reference = r.get(data, "reference", dict)
        if require_reference or reference:
            check_reference_layout(reference, n, source)
        problem = cls(
            id=problem_id, kind=kind, P=P, q=r.vec(obj.get("q"), "objective.q", n),
            r=float(r.get(obj, "r", (int, float), "objective.r")), A=A,
            lower=r.vec(lin.get("lower"), "linear.lower", m, -np.inf), upper=r.vec(lin.get("upper"), "linear.upper", m, np.inf),
            lb=r.vec(bnd.get("lower"), "bounds.lower", n, -np.inf), ub=r.vec(bnd.get("upper"), "bounds.upper", n, np.inf),
            lmis=lmis, reference=reference, provenance=r.get(data, "provenance", dict),
        )
        return problem

    def reference_x(self) -> np.ndarray | None:
        x = self.reference.get("x")
        return None if x is None else np.asarray(x, float)


def is_valid_id(value: Any) -> bool:
    """Whether ``value`` is a problem id of :data:`ID_PATTERN`."""
    return isinstance(value, str) and ID_PATTERN.fullmatch(value) is not None


def check_id(value: Any, name: str = "id") -> str:
    """``value`` when it is a valid problem id, else ProblemFileError naming ``name``."""
    if not is_valid_id(value):
        raise ProblemFileError(name, ID_EXPECTED, repr(value)[:80])
    return value


def check_reference_layout(reference: Any, n: int, source: str = "corpus problem") -> None:
    """The layout of a stored reference: ``status`` "optimal" with a finite number ``objective`` and a list
    ``x`` of ``n`` finite numbers, or ``status`` "infeasible". ProblemFileError naming the field otherwise."""
    r = _Reader(source)
    r.require(isinstance(reference, dict), "reference", "a JSON object", type(reference).__name__)
    status = reference.get("status")
    r.require(status in REFERENCE_STATUSES, "reference.status", f"one of {list(REFERENCE_STATUSES)}", repr(status)[:80])
    if status != "optimal":
        return
    objective = reference.get("objective")
    r.require(isinstance(objective, (int, float)) and not isinstance(objective, bool) and bool(np.isfinite(objective)),
              "reference.objective", "a finite number (the verified optimum)",
              "none" if "objective" not in reference else repr(objective)[:80])
    r.require(bool(np.all(np.isfinite(r.vec(reference.get("x"), "reference.x", n)))), "reference.x",
              f"a list of {n} finite numbers", "a non-finite entry")


class _Reader:
    """Typed access to the fields of one file; every error names the field."""

    def __init__(self, source: str) -> None:
        self.source = source

    def require(self, ok: bool, name: str, expected: str, received: str) -> None:
        if not ok:
            raise ProblemFileError(f"{self.source}: {name or '(top level)'}", expected, received)

    def get(self, data: dict, key: str, types, name: str | None = None):
        value = data.get(key) if isinstance(data, dict) else None
        self.require(isinstance(value, types) and not isinstance(value, bool), name or key,
                     f"a value of type {getattr(types, '__name__', types)}", type(value).__name__)
        return value

    def int(self, data: dict, key: str, name: str | None = None) -> int:
        value = self.get(data, key, int, name)
        self.require(value >= 0, name or key, "an integer >= 0", repr(value))
        return value

    def vec(self, values: Any, name: str, length: int, none_as: float | None = None) -> np.ndarray:
        self.require(isinstance(values, list) and len(values) == length, name, f"a list of {length} numbers",
                     f"{type(values).__name__} of length {len(values) if isinstance(values, list) else '-'}")
        out = np.empty(length)
        for i, v in enumerate(values):
            if v is None and none_as is not None:
                out[i] = none_as
                continue
            self.require(isinstance(v, (int, float)) and not isinstance(v, bool), f"{name}[{i}]",
                         "a number" + (" or null" if none_as is not None else ""), repr(v))
            out[i] = float(v)
        return out

    def sparse(self, data: Any, name: str, shape: tuple[int | None, int]) -> sp.csr_matrix:
        self.require(isinstance(data, dict), name, "a sparse matrix {shape, row, col, val}", type(data).__name__)
        got = data.get("shape")
        self.require(isinstance(got, list) and len(got) == 2 and all(isinstance(v, int) and v >= 0 for v in got),
                     f"{name}.shape", "[rows, cols]", repr(got))
        self.require((shape[0] is None or got[0] == shape[0]) and got[1] == shape[1], f"{name}.shape",
                     f"[{'m' if shape[0] is None else shape[0]}, {shape[1]}]", repr(got))
        nnz = len(data.get("val", [])) if isinstance(data.get("val"), list) else -1
        rows = self.vec(data.get("row"), f"{name}.row", nnz)
        cols = self.vec(data.get("col"), f"{name}.col", nnz)
        vals = self.vec(data.get("val"), f"{name}.val", nnz)
        self.require(bool(np.all((rows >= 0) & (rows < max(got[0], 1)) & (rows == np.round(rows)))), f"{name}.row",
                     f"integers in [0, {got[0]})", "out of range")
        self.require(bool(np.all((cols >= 0) & (cols < max(got[1], 1)) & (cols == np.round(cols)))), f"{name}.col",
                     f"integers in [0, {got[1]})", "out of range")
        return sp.csr_matrix((vals, (rows.astype(int), cols.astype(int))), shape=tuple(got))


def _sparse_out(M) -> dict[str, Any]:
    C = sp.coo_matrix(M)
    keep = C.data != 0.0
    return {"shape": [int(C.shape[0]), int(C.shape[1])], "row": C.row[keep].tolist(), "col": C.col[keep].tolist(),
            "val": [float(v) for v in C.data[keep]]}


def _vec_out(v: np.ndarray) -> list[float | None]:
    return [float(x) if np.isfinite(x) else None for x in np.asarray(v, float)]


def write_json_atomic(path: str | os.PathLike, data: Any, indent: int | None = None) -> Path:
    """Write ``data`` as JSON to ``path`` through a temporary file in the same folder and a rename, so a
    reader never sees a half-written file."""
    return write_text_atomic(path, json.dumps(data, indent=indent, allow_nan=False) + "\n")


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` to ``path`` atomically, as readable as any file the user creates (the umask's
    permissions, not the 0600 of a temporary file): :func:`amcp_drake.model.problem_io.write_text_atomic`."""
    from amcp_drake.model.problem_io import write_text_atomic as write

    return write(text, path)


def load_problem(path: str | os.PathLike) -> CorpusProblem:
    """One corpus file (``.json`` or gzip-compressed ``.json.gz``), read strictly, at most
    :data:`~amcp_drake.model.json_strict.MAX_INPUT_BYTES` bytes on disk and after decompression."""
    import gzip
    import io

    from amcp_drake.model.json_strict import MAX_INPUT_BYTES, decode_utf8, loads_strict, read_bytes_limited

    path = Path(path)
    raw = read_bytes_limited(path, MAX_INPUT_BYTES, ProblemFileError, "corpus file", gzip_ok=True)
    try:
        if path.name.endswith(".gz"):
            with gzip.GzipFile(fileobj=io.BytesIO(raw)) as handle:
                raw = handle.read(MAX_INPUT_BYTES + 1)
    except (OSError, EOFError, gzip.BadGzipFile) as exc:
        raise ProblemFileError(str(path), "a readable corpus file (JSON, optionally gzip-compressed)",
                               f"{type(exc).__name__}: {exc}") from None
    if len(raw) > MAX_INPUT_BYTES:
        raise ProblemFileError(str(path), f"at most {MAX_INPUT_BYTES:,} bytes of JSON after decompression (the size "
                               "limit of a corpus file; docs/decisions.md, 'Input size limits')", "more")
    data = loads_strict(decode_utf8(raw, str(path)), str(path))
    return CorpusProblem.from_dict(data, source=str(path))


def load_corpus(paths: list[str | os.PathLike] | str | os.PathLike) -> list[CorpusProblem]:
    """Every ``*.json`` corpus problem under the given files/folders, sorted by id; two files with one id
    are refused. Whether the references are right: :func:`.reference.load_checked_corpus`."""
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    files: list[Path] = []
    for given in paths:
        if not os.fspath(given).strip():   # Path("") is ".", the current folder
            raise ProblemFileError("--corpus", "an existing corpus file or folder", "an empty string")
        p = Path(given)
        if p.is_dir():
            files.extend(f for f in sorted([*p.rglob("*.json"), *p.rglob("*.json.gz")]) if f.name != "index.json")
        elif p.is_file():
            files.append(p)
        else:
            raise ProblemFileError("--corpus", "an existing corpus file or folder", str(p))
    problems = [load_problem(f) for f in files]
    seen: dict[str, Path] = {}
    for f, pr in zip(files, problems):
        if pr.id in seen:
            raise ProblemFileError(f"{f}: id", "an id no other corpus file has", f"{pr.id!r}, also the id of {seen[pr.id]}")
        seen[pr.id] = f
    if not problems:
        raise ProblemFileError("--corpus", "at least one corpus problem (*.json, *.json.gz)", f"none under {[str(p) for p in paths]}")
    return sorted(problems, key=lambda pr: pr.id)


def shipped_corpus_dir() -> Path:
    """The representative corpus shipped with the package."""
    return Path(__file__).resolve().parents[2] / "data" / "solver_corpus"


__all__ = ["CLASSES", "FORMAT", "ID_EXPECTED", "ID_PATTERN", "KINDS", "REFERENCE_STATUSES", "VERSION", "CorpusProblem",
           "check_id", "check_reference_layout", "is_valid_id", "load_corpus", "load_problem", "shipped_corpus_dir",
           "write_json_atomic", "write_text_atomic"]
