"""Memory, time and progress bounds of the offline design (:class:`DesignBudget`).

Every stage of the design that allocates in proportion to the sizes it works on (vertex enumeration,
the products rows × vertices of the two row recursions, the support values w̄, f̄, h̄) asks the budget
first, with an estimate in bytes: :meth:`DesignBudget.require` raises :class:`DesignSizeError` naming
the stage, the estimate and the limit before anything of that size is allocated, and the automatic
design records the candidate as "too large" and goes on with the next one. Products of many rows
with many vertices are computed in chunks of at most :meth:`DesignBudget.chunk_bytes` bytes
(:func:`chunked_row_maxima`), so their memory does not grow with the number of rows.

Estimates:

* vertex enumeration (Qhull) of a polytope with r rows in dimension d: V vertices, each costing
  :data:`BYTES_PER_QHULL_VERTEX` bytes per coordinate (Qhull's facet records of the dual hull: normal,
  vertex and neighbour sets, and scipy's copies). Before any enumeration in dimension d, V is the
  upper bound theorem's :func:`~amcp_drake.model.limits.max_vertices` (r, d) (a bound). Once one has
  run, V is the count measured there, scaled by (r / r_prev)^⌊d/2⌋ (the growth order of the same
  theorem) and never above it: the row recursions enumerate one slowly growing set after another, and
  the worst-case bound of a set with hundreds of rows in six dimensions (10^7 vertices) is three orders
  of magnitude above the measured counts. This later figure is an estimate, not a bound.
* a product of r rows with v vertices: 8·r·v bytes, in chunks.

Time: :meth:`DesignBudget.tick` is called by every loop of the design (template iterations, terminal
set iterations, chunks); it raises :class:`CandidateTimeout` once the candidate's time budget
(``candidate_seconds``, the CLI's ``--candidate-budget``) is used up, and reports progress through the
``progress`` callback at most every ``progress_seconds`` seconds of wall time (default
:data:`PROGRESS_SECONDS`; the CLI's ``--progress-every``). The budget counts
the process's CPU time, not wall time: on a loaded machine a candidate's wall time is several times
its CPU time (measured up to 18× on the shared 2-core machine), and a wall-clock budget would make
the template the automatic design chooses depend on the load. The budget holds no global
state: the automatic design makes one per candidate (:meth:`DesignBudget.for_candidate`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from amcp_drake.model.errors import DesignError
from amcp_drake.model.limits import DEFAULT_MAX_MEMORY_MB, max_vertices

#: Bytes per vertex and coordinate that vertex enumeration with Qhull needs (scipy's
#: HalfspaceIntersection: the dual hull's facets with their normals, vertex and neighbour lists, and
#: the intersections, dual facets and equations scipy returns). Measured (peak RSS of vertex enumeration
#: of random polytopes in 3-7 dimensions with 10^3-10^5 vertices) at 150-400; 512 leaves room.
BYTES_PER_QHULL_VERTEX = 512
#: Most bytes of one chunk of a rows × vertices product (:func:`chunked_row_maxima`): 64 MiB, or a
#: sixteenth of the memory limit when that is smaller.
CHUNK_BYTES = 64 * 2**20
#: Default time budget of one candidate of the automatic design, in CPU seconds (``--candidate-budget``):
#: a candidate of the 2-D and 3-D examples takes 0.1-3 s, the bounded constructions at n = 6 a few
#: seconds; one that takes longer is abandoned for the next one and recorded as "time budget".
DEFAULT_CANDIDATE_SECONDS = 60.0
#: A long stage reports progress at most this often (seconds).
PROGRESS_SECONDS = 3.0


class DesignSizeError(DesignError):
    """A stage of the design would need more memory than the limit; nothing of that size was
    allocated. ``stage``, ``estimate`` (bytes) and ``limit`` (bytes) name it."""

    def __init__(self, stage: str, estimate: int, limit: int, detail: str = "") -> None:
        self.stage, self.estimate, self.limit = stage, int(estimate), int(limit)
        text = f"too large: {stage} needs an estimated {_mib(estimate)}, above the memory limit of {_mib(limit)}"
        if detail:
            text += f" ({detail})"
        super().__init__(text + "; raise --max-memory or choose a smaller template")


class CandidateTimeout(DesignError):
    """A candidate of the design used up its time budget (``stage`` names where)."""

    def __init__(self, stage: str, seconds: float, used: float | None = None) -> None:
        self.stage, self.seconds = stage, float(seconds)
        self.used = float(used) if used is not None else float(seconds)
        super().__init__(f"time budget: {seconds:g} s of CPU used up in {stage} ({self.used:.1f} s used); moving on "
                         "(--candidate-budget sets the budget)")


def _mib(nbytes: float) -> str:
    mib = nbytes / 2**20
    return f"{mib / 1024:,.1f} GiB" if mib >= 1024 else f"{mib:,.1f} MiB"


class DesignBudget:
    """The memory limit, time budget and progress callback of one design (module docstring).

    ``max_memory_mb``: the limit in MiB (default the CLI's ``--max-memory`` default);
    ``candidate_seconds``: time budget of one candidate (None: unbounded); ``progress``: called with
    one line of text (the CLI prints it to stderr); ``label``: the candidate's name in those lines;
    ``progress_seconds``: the least wall time between two progress lines; ``clock``: the CPU-time clock
    of the budget (default ``time.process_time``; tests pass a deterministic counter).
    """

    def __init__(self, max_memory_mb: float = DEFAULT_MAX_MEMORY_MB, candidate_seconds: float | None = None,
                 progress: Callable[[str], None] | None = None, label: str = "design",
                 progress_seconds: float = PROGRESS_SECONDS, clock: Callable[[], float] | None = None) -> None:
        if not (isinstance(max_memory_mb, (int, float)) and np.isfinite(max_memory_mb) and max_memory_mb > 0):
            raise ValueError(f"max_memory_mb: expected a positive finite number; received {max_memory_mb!r}")
        if candidate_seconds is not None and not (np.isfinite(candidate_seconds) and candidate_seconds > 0):
            raise ValueError(f"candidate_seconds: expected a positive finite number or None; received {candidate_seconds!r}")
        if not (isinstance(progress_seconds, (int, float)) and np.isfinite(progress_seconds) and progress_seconds > 0):
            raise ValueError(f"progress_seconds: expected a positive finite number; received {progress_seconds!r}")
        self.progress_seconds = float(progress_seconds)
        self.max_memory_mb = float(max_memory_mb)
        self.candidate_seconds = candidate_seconds
        self.progress = progress
        self.label = label
        self.clock = clock
        self._start = self._cpu()  # the budget: CPU time of this process
        self._last_report = time.perf_counter()  # progress: wall time
        self._measured: dict[int, tuple[int, int]] = {}  # dimension -> (rows, vertices) of the last enumeration

    @property
    def limit_bytes(self) -> int:
        return int(self.max_memory_mb * 2**20)

    def for_candidate(self, label: str) -> DesignBudget:
        """A fresh budget (clock restarted) for one candidate of the automatic design."""
        return DesignBudget(self.max_memory_mb, self.candidate_seconds, self.progress, label, self.progress_seconds,
                            self.clock)

    def elapsed(self) -> float:
        """CPU seconds used by the process since this budget started."""
        return self._cpu() - self._start

    def _cpu(self) -> float:
        return self.clock() if self.clock is not None else time.process_time()

    def require(self, stage: str, nbytes: float, detail: str = "") -> None:
        """Refuse (DesignSizeError) a stage whose estimate ``nbytes`` exceeds the memory limit."""
        if nbytes > self.limit_bytes:
            raise DesignSizeError(stage, int(min(nbytes, 2**62)), self.limit_bytes, detail)

    def estimate_vertices(self, rows: int, dim: int) -> tuple[float, str]:
        """(estimated vertex count, how it was obtained) of a polytope with ``rows`` rows in ``dim``
        dimensions (module docstring)."""
        bound = float(max_vertices(max(int(rows), dim + 1), dim))
        if dim in self._measured:
            rows_prev, verts_prev = self._measured[dim]
            scaled = verts_prev * (max(int(rows), 1) / max(rows_prev, 1)) ** (dim // 2)
            if scaled < bound:
                return scaled, f"{verts_prev:,} vertices measured at {rows_prev} rows, scaled to {rows} rows"
        return bound, f"at most {bound:,.0f} vertices (upper bound theorem)"

    def note_vertices(self, rows: int, dim: int, count: int) -> None:
        """Record a measured vertex count (used by :meth:`estimate_vertices`)."""
        self._measured[dim] = (int(rows), int(count))

    def require_vertices(self, stage: str, rows: int, dim: int) -> None:
        """Refuse a vertex enumeration whose estimate exceeds the memory limit."""
        count, how = self.estimate_vertices(rows, dim)
        self.require(stage, count * dim * BYTES_PER_QHULL_VERTEX,
                     f"vertex enumeration of {rows} rows in {dim} dimensions: {how}")

    def chunk_bytes(self) -> int:
        """Most bytes of one chunk of a rows × vertices product."""
        return max(2**16, min(CHUNK_BYTES, self.limit_bytes // 16))

    def tick(self, stage: str) -> None:
        """Check the time budget (CandidateTimeout) and report progress every ``progress_seconds``."""
        used = self.elapsed()
        if self.candidate_seconds is not None and used > self.candidate_seconds:
            raise CandidateTimeout(stage, self.candidate_seconds, used)
        now = time.perf_counter()
        if self.progress is not None and now - self._last_report >= self.progress_seconds:
            self._last_report = now
            self.progress(f"  ... {self.label}: {stage} ({used:.0f} s CPU)")


def unbounded() -> DesignBudget:
    """The budget of a design called without one: the default memory limit, no time budget, silent."""
    return DesignBudget()


def chunked_row_maxima(directions: np.ndarray, points: np.ndarray, budget: DesignBudget, stage: str) -> np.ndarray:
    """max_j directions_i · points_j for every row i, in chunks of rows of at most
    ``budget.chunk_bytes()`` bytes (the full product is never formed)."""
    directions = np.asarray(directions, float)
    points = np.asarray(points, float)
    if len(directions) == 0:
        return np.zeros(0)
    per_row = 8 * max(1, len(points))
    step = max(1, budget.chunk_bytes() // per_row)
    out = np.empty(len(directions))
    for start in range(0, len(directions), step):
        budget.tick(stage)
        out[start:start + step] = np.max(directions[start:start + step] @ points.T, axis=1)
    return out


def chunked_tight_counts(rows: np.ndarray, points: np.ndarray, tol: float, budget: DesignBudget,
                         stage: str) -> list[np.ndarray]:
    """For every row a_i, the indices of the points with |a_i · x_j − 1| <= tol, in chunks."""
    rows = np.asarray(rows, float)
    per_row = 8 * max(1, len(points))
    step = max(1, budget.chunk_bytes() // per_row)
    out: list[np.ndarray] = []
    for start in range(0, len(rows), step):
        budget.tick(stage)
        tight = np.abs(rows[start:start + step] @ points.T - 1.0) <= tol
        out.extend(np.flatnonzero(t) for t in tight)
    return out


__all__ = ["BYTES_PER_QHULL_VERTEX", "CHUNK_BYTES", "CandidateTimeout", "DEFAULT_CANDIDATE_SECONDS", "DesignBudget",
           "DesignSizeError", "PROGRESS_SECONDS", "chunked_row_maxima", "chunked_tight_counts", "unbounded"]
