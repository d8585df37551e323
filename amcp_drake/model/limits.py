"""Resource limits: an estimate of the size of a run checked before anything is built, and the
removal of redundant rows of W, Θ and Z at load.

**Size estimate** (:func:`estimate_run_size`). The tube QP (20) in the plain form (15) has, for n
states, m inputs, p parameters, horizon N, u facets and v vertices of the tube shape X0, q rows of Θ
(plus ``design.theta_extra_directions``) and c rows of Z:

* variables, as built by ``backends/drake_tube.py`` with every row of (15c) (``prune=False``, its
  fallback): (N+1)·n (z) + (N+1) (α) + N·m (v) + N·v·u·(q−p) (the multipliers Λ_N; the other p of
  each row are solved from (15d), ``backends/multiplier_basis.py``) + N·n (the deviations e_l of the
  tube centres that (15c) is written in); its default program leaves out
  the rows implied by others on Θ0 (``backends/dominated_rows.py``, not known before the design) and
  is smaller; the cvxpy backend keeps all N·v·u·q multipliers;
* rows: N·c (15a) + u (15b) + N·v·u (15c) + N·v·u·p ((15d) in cvxpy, Λ_B >= 0 in Drake) + N·n (the
  rows defining e_l in Drake) + c (terminal set, estimated by c rows; its true size is known only after
  the design);
* nonzeros, of the cvxpy form (the larger of the two, so the memory bound holds for both):
  N·c·(n+m+1) + u·(n+1) + N·v·u·(2n+m+2+q) + N·v·u·p·(n+m+1+q) + c·(n+1).

Before the design, u and v are not known: u is ``design.x0_facets`` (else the automatic design's
first candidate's, 2n facets from n = 4 on, else 8) and v is bounded by the upper bound theorem
(McMullen 1970) for a polytope with u facets in dimension n (exact for n <= 2: v = u), except for the
automatic design from n = 4 on, whose first candidate is the parallelotope (2n facets, 2^n vertices):
the estimate before the design is then that of the smallest design it may return. Once the design is
known, :func:`check_run_size` given the design repeats the estimate with its own u, v and q (its
H_θ, ``design.theta_extra_directions`` included) and refuses the run before the controller is built.
The set update LP (9) adds q + q·r·L variables (r rows of W, L = 1 or the window length of update "window"); every step records Θ_k,
(v, z, α) and Λ (N·v·u·q numbers), kept in memory for the whole run and written at the end.

The **vertex form** of (20) (``formulation="vertex"``, ``backends/vertex_form.py``) has no multipliers:
(N+1)·(n+1) + N·m variables; N·c (15a) + u (15b) + N·u·S rows of (5b) at the S vertices of Θ_k (S
counted on Θ0, at most the upper bound theorem's for q rows in p dimensions) + c; nonzeros
N·c·(n+m+1) + u·(n+1) + N·u·S·(2n+m+2) + c·(n+1); it records no Λ. The estimate follows the
formulation the run uses: ``"auto"`` is resolved by the caller once the design is known
(``online/formulation_choice.py``); before the design it is the smaller of the two estimates.

Memory = :data:`BYTES_PER_NONZERO` × nonzeros + :data:`BYTES_PER_RECORDED_NUMBER` × numbers recorded
over the run, both measured (peak RSS of Example 1 with N = 10 and 200, 5 to 40 steps: the estimate is
within 10 % of the measurement). A run whose estimate exceeds the limit (default
:data:`DEFAULT_MAX_MEMORY_MB`; ``--max-memory`` raises it) is refused with a
:class:`~amcp_drake.model.errors.ProblemError` before the design starts.

**Redundant rows** (:func:`remove_redundant_rows`). A row a·x <= b of a polytope with an interior
point c is implied by the others exactly when the point a/(b − a·c) of the polar lies in the convex
hull of the other such points and the origin. The hull is computed once with Qhull
(``scipy.spatial.ConvexHull``) in the span of the rows, so a set of 100,000 rows is reduced in well
under a second instead of one LP per row; a row is kept whenever its polar point is a hull vertex or
lies outside the hull of the kept rows by more than :data:`POLAR_TOL`. Above :data:`MAX_HULL_DIM`
dimensions only duplicate rows are merged (Qhull's cost grows quickly with the dimension).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from math import comb
from typing import Any

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError

#: Most closed-loop steps of one run (``--steps``, ``scenario.steps``): at ~20 ms per step of Example 1
#: that is over half an hour, and the recorded trajectory is held in memory; longer studies are split.
MAX_STEPS = 100_000
#: Default limit of the estimated memory of a run, in MiB (the shared machines have 23 GB; Example 1
#: with N = 10 and 50 steps is estimated at a few MB). Raised with ``--max-memory``.
DEFAULT_MAX_MEMORY_MB = 2048
#: Largest ``--max-memory``, in MiB (2**30 MiB = 1 PiB): any real machine is below it, and the limit in bytes
#: stays an exact integer (a value like 1e308 would overflow when converted to bytes).
MAX_MEMORY_MB = 2**30
#: Bytes per nonzero of the tube QP: the scipy lil_matrix it is assembled in (Python lists), the CSC
#: copy and Drake's and Clarabel's own copies. Measured (peak RSS, Drake backend, Example 1 with
#: N = 200: 553k nonzeros, 177 MiB above the design) as 320.
BYTES_PER_NONZERO = 320
#: Bytes per number recorded over the run: 8 in the numpy record, a Python float in the JSON tree and
#: its text when the trajectory is written. Measured (same run, 5 vs 40 steps: 6.2 MiB per step of
#: 78k numbers) as 80.
BYTES_PER_RECORDED_NUMBER = 80
#: Qhull is used for the redundancy test up to this dimension; above it only duplicates are merged.
MAX_HULL_DIM = 8
#: A polar point outside the hull of the kept rows by more than this is kept (Qhull's own precision
#: is ~1e-13 relative; 1e-9 matches polytope.REDUNDANCY_TOL).
POLAR_TOL = 1e-9
#: Relative singular-value threshold for the span of the rows.
RANK_TOL = 1e-12


def max_vertices(facets: int, dim: int) -> int:
    """Upper bound theorem: the most vertices a polytope with ``facets`` facets in R^dim can have."""
    if dim <= 0:
        return 1
    if dim <= 2:
        return facets if dim == 2 else 2
    half_floor, half_ceil = dim // 2, (dim + 1) // 2
    return comb(facets - half_ceil, half_floor) + comb(facets - half_floor - 1, half_ceil - 1)


@dataclass(frozen=True)
class SizeEstimate:
    """Estimated size of a run (module docstring)."""

    n: int
    m: int
    p: int
    N: int
    facets: int
    vertices: int
    theta_rows: int
    w_rows: int
    z_rows: int
    steps: int
    variables: int
    rows: int
    nonzeros: int
    recorded_numbers: int
    memory_bytes: int
    #: True when the sizes of X0 and Θ are those of a design found, False for the estimate before it.
    designed: bool = False
    #: The formulation of (20) estimated: "plain" (15) or "vertex".
    formulation: str = "plain"

    def describe(self) -> str:
        """One line with the inputs and the estimate."""
        x0 = (f"X0 facets = {self.facets} ({self.vertices} vertices)" if self.designed
              else f"design.x0_facets = {self.facets} (<= {self.vertices} vertices)")
        return (f"n = {self.n}, m = {self.m}, p = {self.p}, cost.N = {self.N}, {x0}, "
                f"{self.theta_rows} rows of Theta, {self.w_rows} rows of W.H, "
                f"{self.z_rows} rows of Z, {self.steps} steps: tube QP {'(15)' if self.formulation == 'plain' else '(20) in the vertex form'} with {self.variables:,} variables, "
                f"{self.rows:,} rows, {self.nonzeros:,} nonzeros; {self.recorded_numbers:,} numbers recorded; "
                f"estimated memory {_mib(self.memory_bytes)}")


def _mib(nbytes: int) -> str:
    mib = nbytes / 2**20
    return f"{mib / 1024:,.1f} GiB" if mib >= 1024 else f"{mib:,.1f} MiB"


#: The formulations of (20) an estimate is made for (``"auto"``: module docstring).
ESTIMATED_FORMULATIONS = ("plain", "vertex", "auto")


def estimate_run_size(n: int, m: int, p: int, N: int, facets: int, theta_rows: int, w_rows: int, z_rows: int,
                      steps: int = 1, window: int = 1, vertices: int | None = None, formulation: str = "plain",
                      theta_vertices: int | None = None) -> SizeEstimate:
    """The size of a run (module docstring); Python integers, so absurd inputs cannot overflow.
    ``vertices``: the number of vertices of X0 when known (default: the upper bound theorem's);
    ``formulation``: "plain" (15), "vertex" or "auto" (the smaller of the two); ``theta_vertices``: the
    number S of vertices of Θ0 when known (default: the upper bound theorem's for q rows in p dimensions)."""
    if formulation not in ESTIMATED_FORMULATIONS:
        raise ValueError(f"formulation: expected one of {', '.join(ESTIMATED_FORMULATIONS)}; received {formulation!r}")
    if formulation == "auto":
        both = [estimate_run_size(n, m, p, N, facets, theta_rows, w_rows, z_rows, steps, window, vertices, form,
                                  theta_vertices) for form in ("plain", "vertex")]
        return min(both, key=lambda est: est.memory_bytes)
    nv = max_vertices(facets, n) if vertices is None else int(vertices)
    u, q, c = facets, theta_rows, z_rows
    update_nonzeros = q * w_rows * window * (p + 1) + q * (p + 1)
    per_step = q * (p + 1) + (N + 1) * (n + 1) + N * m + q * w_rows * window
    if formulation == "plain":
        block = N * nv * u
        variables = (N + 1) * n + (N + 1) + N * m + block * (q - p) + N * n
        rows = N * c + u + block + block * p + N * n + c
        nonzeros = (N * c * (n + m + 1) + u * (n + 1) + block * (2 * n + m + 2 + q) + block * p * (n + m + 1 + q)
                    + c * (n + 1))
        per_step += block * q  # the multipliers Λ of every step
    else:
        S = max_vertices(max(q, p + 1), p) if theta_vertices is None else int(theta_vertices)
        block = N * u * S
        variables = (N + 1) * (n + 1) + N * m
        rows = N * c + u + block + c
        nonzeros = N * c * (n + m + 1) + u * (n + 1) + block * (2 * n + m + 2) + c * (n + 1)
    recorded = (steps + 1) * per_step
    memory = BYTES_PER_NONZERO * (nonzeros + update_nonzeros) + BYTES_PER_RECORDED_NUMBER * recorded
    return SizeEstimate(n, m, p, N, facets, nv, q, w_rows, c, steps, variables, rows, nonzeros, recorded, memory,
                        formulation=formulation)


#: From this dimension on the automatic design tries the parallelotope (2n facets, 2^n vertices) first
#: (``offline/auto.py``); the estimate before the design takes that smallest candidate.
PARALLELOTOPE_FIRST_DIM = 4


def estimate_for(problem, design_options=None, steps: int = 1, online=None, design=None,
                 formulation: str = "plain") -> SizeEstimate:
    """:func:`estimate_run_size` for a :class:`~amcp_drake.model.problem.Problem` and its design options
    (``design.x0_facets``, ``design.x0_template``, ``design.theta_extra_directions``); with ``design`` (an
    OfflineDesign), for that design's X0 (its facets and vertices), its shape H_θ of (9) and the vertices
    of Θ0; ``formulation`` of (20) as in :func:`estimate_run_size`."""
    facets, vertices = max(8, 2 * problem.n), None
    if design_options is not None and getattr(design_options, "x0_facets", None) is not None:
        facets = design_options.x0_facets
    elif (problem.n >= PARALLELOTOPE_FIRST_DIM
          and getattr(design_options, "x0_template", "auto") == "auto" and getattr(design_options, "x0_H", None) is None):
        facets, vertices = 2 * problem.n, 2 ** problem.n
    extra = getattr(design_options, "theta_extra_directions", None) if design_options is not None else None
    theta_rows = len(problem.H_theta) + (0 if extra is None else len(np.atleast_2d(extra)))
    theta_vertices = None
    if design is not None:
        facets, vertices, theta_rows = len(design.H_x), len(design.X0_vertices), len(design.H_theta)
        theta_vertices = _theta0_vertex_count(design)
    window = online.window if online is not None and getattr(online, "update", "") == "window" else 1
    est = estimate_run_size(problem.n, problem.m, problem.p, int(problem.N), int(facets), theta_rows,
                            len(problem.H_w), len(problem.F), steps=int(steps), window=int(window), vertices=vertices,
                            formulation=formulation, theta_vertices=theta_vertices)
    return replace(est, designed=design is not None)


def _theta0_vertex_count(design) -> int | None:
    """The number of vertices of Θ0 = {H_θ θ <= h_θ0} of a design (None when they cannot be enumerated:
    the estimate then takes the upper bound theorem's)."""
    try:
        found = polytope.theta_vertices(np.asarray(design.H_theta, float), np.asarray(design.h_theta0, float))
    except (ValueError, TypeError, AttributeError):
        return None
    return None if found is None else len(found)


def check_run_size(problem, design_options=None, steps: int = 1, online=None,
                   max_memory_mb: float = DEFAULT_MAX_MEMORY_MB, option: str = "--max-memory",
                   design=None, formulation: str = "plain") -> SizeEstimate:
    """Refuse a run whose estimated memory exceeds ``max_memory_mb`` (ProblemError naming the stage, the
    sizes, the estimate and the limit). Called twice per run: before the design (``design`` None: the
    estimate from ``design_options``) and once the design is known (``design``: its X0's facets and
    vertices and its H_θ, so the run is refused before the controller is built). ``formulation``: the
    form of (20) the run uses (with a design, "auto" resolved by the caller)."""
    est = estimate_for(problem, design_options, steps, online, design=design, formulation=formulation)
    if est.memory_bytes <= max_memory_mb * 2**20:
        return est
    if design is None:
        field = "problem size (cost.N, design.x0_facets, rows of Theta and W.H, steps)"
        fix = "Reduce cost.N, design.x0_facets or the steps"
    else:
        field = "problem size with the design found (cost.N, the design's X0, rows of Theta and W.H, steps)"
        fix = "Reduce cost.N or the steps, give a design with fewer facets (design.x0_template, design.x0_facets)"
    if formulation == "plain":
        fix += ", solve (20) in the vertex form (--formulation auto or vertex: no multipliers)"
    raise ProblemError(field, f"an estimated memory of at most {max_memory_mb:,g} MiB", est.describe(),
                       f"{fix}, or raise the limit with {option} (docs/problem-format.md, 'Size limits').")


def design_size_bytes(problem, design_options=None) -> tuple[int, int]:
    """(facets, bytes): the facets of X0 the design options ask for (``design.x0_facets``, else the rows of
    a given ``design.x0_H``, else the default template's) and the memory of the arrays of that size the
    design holds at once: 8 bytes per entry of H_x, of H_x A_cl(θ^k) at each of the t vertices of Θ and of
    their h̄ rows, 8·u·n·(2 + t) bytes. A lower bound of the design's memory, known before it starts;
    each stage of the design is sized again, once its inputs are known, by ``offline/budget.py``."""
    x0_H = getattr(design_options, "x0_H", None)
    if x0_H is not None:
        facets = len(np.atleast_2d(x0_H))
    elif design_options is not None and hasattr(design_options, "facets_for"):
        facets = design_options.facets_for(problem.n)
    else:
        facets = max(8, 2 * problem.n)
    theta_vertices = max_vertices(len(problem.H_theta), problem.p)
    try:
        found = polytope.theta_vertices(problem.H_theta, problem.h_theta)
        theta_vertices = len(found) if found is not None else theta_vertices
    except (ValueError, TypeError):
        pass
    return int(facets), 8 * int(facets) * problem.n * (2 + int(theta_vertices))


def check_design_size(problem, design_options=None, max_memory_mb: float = DEFAULT_MAX_MEMORY_MB,
                      option: str = "--max-memory") -> int:
    """Refuse an offline design whose X0 alone (:func:`design_size_bytes`) exceeds ``max_memory_mb``
    (ProblemError naming ``design.x0_facets``, the estimate and the limit); the check of ``amcp design``,
    which builds no run. Returns the estimate in bytes."""
    facets, nbytes = design_size_bytes(problem, design_options)
    if nbytes <= max_memory_mb * 2**20:
        return nbytes
    raise ProblemError("design size (design.x0_facets, design.x0_H)", f"an estimated memory of at most "
                       f"{max_memory_mb:,g} MiB", f"design.x0_facets = {facets} facets of X0 in n = {problem.n} "
                       f"dimensions: its rows alone need an estimated {_mib(nbytes)}",
                       f"Reduce design.x0_facets, or raise the limit with {option}.")


# -- redundant rows --------------------------------------------------------------------------------
def nonredundant_rows(H: np.ndarray, h: np.ndarray, interior: np.ndarray) -> np.ndarray:
    """Indices (ascending) of the rows of {x | H x <= h} not implied by the others; ``interior`` is a
    point with H·interior < h. Of equal rows one is kept."""
    H = np.asarray(H, float)
    slack = np.asarray(h, float) - H @ np.asarray(interior, float)
    if np.any(slack <= 0):
        raise ValueError("nonredundant_rows needs a strictly interior point")
    P = H / slack[:, None]
    first = np.arange(len(P))  # (Qhull keeps one of equal points; the others are dropped as inside)
    if len(first) <= 1:
        return first
    _, S, Vt = np.linalg.svd(P[first], full_matrices=False)
    if S[0] == 0:  # every row is zero (0 <= h holds everywhere): nothing to compare, every row kept
        return first
    rank = int(np.sum(S > RANK_TOL * S[0]))
    if rank > MAX_HULL_DIM:  # only exact duplicates are merged
        _, unique = np.unique(P, axis=0, return_index=True)
        return np.sort(unique)
    coords = P[first] @ Vt[:rank].T
    if rank == 1:
        t = coords[:, 0]
        keep = {int(np.argmax(t))} if t.max() > 0 else set()
        if t.min() < 0:
            keep.add(int(np.argmin(t)))
        return np.sort(first[sorted(keep)])
    points = np.vstack([np.zeros(rank), coords])
    try:
        hull = ConvexHull(points)
    except QhullError:  # degenerate configuration Qhull cannot handle: keep every distinct row
        return first
    kept = np.zeros(len(first), dtype=bool)
    kept[hull.vertices[hull.vertices > 0] - 1] = True
    # every dropped point must lie in the hull of the kept ones (and the origin) within POLAR_TOL
    try:
        kept_hull = ConvexHull(np.vstack([np.zeros(rank), coords[kept]])) if kept.sum() >= rank else None
    except QhullError:
        kept_hull = None
    if kept_hull is not None:
        scale = np.max(np.abs(coords), axis=1)
        outside = (coords @ kept_hull.equations[:, :-1].T + kept_hull.equations[:, -1]).max(axis=1)
        kept |= outside > POLAR_TOL * np.maximum(scale, 1.0)
    else:
        kept[:] = True
    return first[kept]


_FIELDS = {"W": "W.H", "Theta": "Theta.H, Theta.h", "Z": "Z.F, Z.G"}


def _as_rows(value: Any) -> np.ndarray | None:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return arr if arr.ndim == 2 and arr.size and np.all(np.isfinite(arr)) else None


def _note(name: str, total: int, keep: np.ndarray) -> str:
    dropped = np.setdiff1d(np.arange(total), keep)
    shown = ", ".join(str(int(i)) for i in dropped[:8]) + (", ..." if len(dropped) > 8 else "")
    note = f"{_FIELDS[name]}: removed {len(dropped)} of {total} rows implied by the others (rows {shown}); {len(keep)} kept"
    if name == "Theta":
        note += ("; they are no longer facet directions of the fixed-shape update (9): list them in "
                 "design.theta_extra_directions to keep them")
    return note + " (\"keep_redundant_rows\": true keeps every row)"


def normalise_theta_rows(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The rows of Θ = {θ | H θ <= h} as read from a hand-written file, made comparable: a zero row with
    h_i >= 0 holds everywhere and is dropped; a zero row with h_i < 0 is left for the validation (Θ is
    empty, refused naming ``Theta.h[i]``); every other row is divided by its largest |entry| (the same
    set: rows scaled by 1e-9 or 1e9 give the same design as unit rows). Returns (H, h, notes); the
    arrays are the inputs when nothing changed."""
    zero = np.all(H == 0, axis=1)
    notes = []
    if np.any(zero & (h < 0)):
        return H, h, notes
    if np.any(zero) and not np.all(zero):
        dropped = np.flatnonzero(zero)
        shown = ", ".join(str(int(i)) for i in dropped[:8]) + (", ..." if len(dropped) > 8 else "")
        notes.append(f"Theta: removed the zero row{'s' if len(dropped) > 1 else ''} {shown} "
                     f"(0 <= {'h' if len(dropped) > 1 else f'{h[dropped[0]]:g}'} holds everywhere)")
        H, h = H[~zero], h[~zero]
    scale = np.max(np.abs(H), axis=1)
    if np.any(scale != 1.0) and np.all(scale > 0):
        scaled = np.flatnonzero(scale != 1.0)
        shown = ", ".join(str(int(i)) for i in scaled[:8]) + (", ..." if len(scaled) > 8 else "")
        notes.append(f"Theta: rows {shown} divided by their largest |entry| (the same set; rows of very different "
                     "scales make the support LPs ill-conditioned)")
        H, h = H / scale[:, None], h / scale
    return H, h, notes


def reduce_rows(H_w: Any, H_theta: Any, h_theta: Any, F: Any, G: Any) -> tuple[dict[str, Any], list[str]]:
    """Redundant rows of W = {H_w w <= 1}, Θ = {H_θ θ <= h_θ} and Z = {F x + G u <= 1} removed, on raw
    (not yet validated) data, so that a problem with 100,000 redundant rows is reduced *before* the
    validation LPs run on it. Returns the changed arrays (keys H_w, H_theta, h_theta, F, G; a set that
    did not change, or whose data are malformed, is left out: the validation reports it) and one note
    per reduced set. Rows keep their order."""
    changes: dict[str, Any] = {}
    notes: list[str] = []
    W = _as_rows(H_w)
    if W is not None:
        keep = nonredundant_rows(W, np.ones(len(W)), np.zeros(W.shape[1]))
        if len(keep) < len(W):
            changes["H_w"] = W[keep]
            notes.append(_note("W", len(W), keep))
    Ht, ht = _as_rows(H_theta), _as_rows(np.reshape(h_theta, (-1, 1)) if np.ndim(h_theta) == 1 else None)
    if Ht is not None and ht is not None and len(ht) == len(Ht):
        Ht, ht, theta_notes = normalise_theta_rows(Ht, ht[:, 0])
        if theta_notes:
            changes.update(H_theta=Ht, h_theta=ht)
            notes += theta_notes
    if Ht is not None and ht is not None and len(ht) == len(Ht) and not np.any(np.all(Ht == 0, axis=1)):
        centre, radius = polytope.chebyshev_center(Ht, ht)
        if np.isfinite(radius) and radius > 0:
            keep = nonredundant_rows(Ht, ht, centre)
            if len(keep) < len(Ht):
                changes.update(H_theta=Ht[keep], h_theta=ht[keep])
                notes.append(_note("Theta", len(Ht), keep))
    Fa, Ga = _as_rows(F), _as_rows(G)
    if Fa is not None and Ga is not None and len(Fa) == len(Ga):
        FG = np.hstack([Fa, Ga])
        if not np.any(np.all(FG == 0, axis=1)):
            keep = nonredundant_rows(FG, np.ones(len(FG)), np.zeros(FG.shape[1]))
            if len(keep) < len(FG):
                changes.update(F=Fa[keep], G=Ga[keep])
                notes.append(_note("Z", len(FG), keep))
    return changes, notes


def remove_redundant_rows(problem) -> tuple[Any, list[str]]:
    """``problem`` (a :class:`~amcp_drake.model.problem.Problem`) with the redundant rows of W.H, Θ and Z
    removed (:func:`reduce_rows`), and the notes; the same object when nothing was redundant."""
    changes, notes = reduce_rows(problem.H_w, problem.H_theta, problem.h_theta, problem.F, problem.G)
    return (problem.with_changes(**changes) if changes else problem), notes


__all__ = [
    "BYTES_PER_NONZERO",
    "BYTES_PER_RECORDED_NUMBER",
    "DEFAULT_MAX_MEMORY_MB",
    "MAX_MEMORY_MB",
    "MAX_STEPS",
    "SizeEstimate",
    "check_run_size",
    "estimate_for",
    "estimate_run_size",
    "max_vertices",
    "nonredundant_rows",
    "normalise_theta_rows",
    "reduce_rows",
    "remove_redundant_rows",
]
