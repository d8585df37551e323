"""A saved offline design (``amcp design FILE --out design.json``) and its reuse (``--design design.json``).

The file holds the :class:`~amcp_drake.offline.result.OfflineDesign` and the SHA-256 of the canonical
problem it was made for (:mod:`amcp_drake.model.problem_hash`)::

    {"format": "amcp-design", "version": 1,
     "problem": {"name": ..., "sha256": ..., "n": ..., "m": ..., "p": ...},
     "generator": "amcp-drake <version>", "design": {<OfflineDesign.to_dict()>}}

A file from elsewhere is data: :func:`load_design` refuses (a :class:`~amcp_drake.model.errors.ProblemError`
naming ``--design``, the field, what was expected and what was received)

1. a file that is not a design file of this format and version, or malformed (a missing field, a
   shape that does not fit the problem, a number that is not finite);
2. a design of another problem (its hash differs from the problem's);
3. a design whose derived data do not follow from its own sets: the vertices of X0 are those of
   {H_x x <= 1}, the vertices of Θ those of the problem's Θ, Θ0 = {H_θ θ <= h_θ0} equals Θ, h̄ of
   Appendix A.1 is the maximum over the vertices of X0 (to 1e-6, as w̄ and f̄), λ̄ = max h̄, and
   ``mu_state_bound`` is the problem's;
4. a design that fails any of the independent checks of the offline design
   (:func:`~amcp_drake.offline.checks.verify_design`: (16), Assumption 8, X0 contractive and robustly
   invariant, w̄ and f̄ recomputed, Assumption 11 for X_f, μ of (11)).

A design that passes is used as it is: nothing is designed again.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError, ProblemFileError
from amcp_drake.model.problem_hash import spec_hash
from amcp_drake.offline.result import OfflineDesign, closed_loop_vertices

DESIGN_FORMAT = "amcp-design"
DESIGN_VERSION = 1
#: The option that names a design file in messages.
OPTION = "--design"
#: Round-off allowed between a recorded vertex (of X0, Θ) and the recomputed one, relative to the
#: set's extent (Qhull's accuracy is ~1e-12 relative).
VERTEX_MATCH_TOL = 1e-8
#: Round-off allowed between the recorded h̄ and its recomputation over the vertices (the design takes the
#: larger of an LP value and the vertex maximum; the same tolerance as w̄ and f̄ in offline/checks.py).
H_BAR_TOL = 1e-6

#: (field, shape) of every array of a design, in the sizes n, m, p, u (facets of X0), v (vertices of
#: X0), c (rows of Z), r (rows of X_f), q (rows of H_θ), t (vertices of Θ); None: any size.
_ARRAYS = (("K", ("m", "n")), ("P", ("n", "n")), ("H_x", ("u", "n")), ("X0_vertices", ("v", "n")),
           ("w_bar", ("u",)), ("f_bar", ("c",)), ("h_bar", ("t", "u")), ("A_z", ("n", "n")), ("H_T", ("r", "n")),
           ("h_T", ("r",)), ("H_theta", ("q", "p")), ("h_theta0", ("q",)), ("theta_vertices", ("t", "p")))
_NUMBERS = ("lambda_bar", "mu", "mu_sup")
_TEXTS = ("mu_region", "backend", "gain_source", "mu_method")


def design_document(spec, design: OfflineDesign) -> dict:
    """The JSON object of a design file for ``design``, made for ``spec`` (module docstring)."""
    from amcp_drake import __version__
    from amcp_drake.model.problem_io import jsonable

    pr = spec.problem
    return {"format": DESIGN_FORMAT, "version": DESIGN_VERSION,
            "problem": {"name": pr.name, "sha256": spec_hash(spec), "n": pr.n, "m": pr.m, "p": pr.p},
            "generator": f"amcp-drake {__version__}", "design": jsonable(design.to_dict())}


def save_design(spec, design: OfflineDesign, path: str | os.PathLike) -> Path:
    """Write the design file atomically (whole or not at all)."""
    from amcp_drake.model.problem_io import write_json_atomic

    return write_json_atomic(design_document(spec, design), path)


def load_design(path: str | os.PathLike, spec) -> OfflineDesign:
    """The design of the file at ``path`` for ``spec`` (a ProblemSpec), checked as the module docstring
    says; ProblemError naming ``--design`` otherwise."""
    from amcp_drake.model.json_strict import load_json_strict

    data = load_json_strict(path, ProblemFileError, f"{OPTION} file")
    return design_from_document(data, spec, str(path))


def design_from_document(data, spec, source: str = "design file") -> OfflineDesign:
    """:func:`load_design` for an already parsed JSON object ``data`` (``source`` names it in messages)."""
    if not isinstance(data, dict) or data.get("format") != DESIGN_FORMAT:
        received = data.get("format") if isinstance(data, dict) else type(data).__name__
        raise ProblemError(f"{OPTION} format", f"{DESIGN_FORMAT!r} (a file written by amcp design --out)",
                           f"{received!r} in {source}")
    version = data.get("version")
    if isinstance(version, bool) or version != DESIGN_VERSION:
        raise ProblemError(f"{OPTION} version", f"{DESIGN_VERSION}", f"{version!r} in {source}")
    problem = data.get("problem")
    recorded = problem.get("sha256") if isinstance(problem, dict) else None
    expected = spec_hash(spec)
    if recorded != expected:
        raise ProblemError(f"{OPTION} problem.sha256", f"a design of this problem (SHA-256 {expected})",
                           f"a design of another problem (SHA-256 {recorded}) in {source}",
                           "Design this problem (amcp design PROBLEM --out FILE) or pass the problem the design "
                           "was made for; nothing was run")
    design = _design(data.get("design"), spec.problem, source)
    _require_consistent(design, spec, source)
    _require_checks_pass(design, spec, source)
    return design


def _design(raw, problem, source: str) -> OfflineDesign:
    """The OfflineDesign of ``raw``, every field present, of its type and shape, finite."""
    if not isinstance(raw, dict):
        raise ProblemError(f"{OPTION} design", "a JSON object (the design)", f"{type(raw).__name__} in {source}")
    sizes = {"n": problem.n, "m": problem.m, "p": problem.p, "c": len(problem.F)}
    values: dict = {}
    for name, shape in _ARRAYS:
        values[name] = _array(raw, name, shape, sizes, source)
    for name in _NUMBERS:
        values[name] = _number(raw, name, source)
    for name in _TEXTS:
        value = raw.get(name)
        if not isinstance(value, str):
            raise ProblemError(f"{OPTION} design.{name}", "a string", f"{value!r} in {source}")
        values[name] = value
    iterations = raw.get("terminal_iterations")
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 0:
        raise ProblemError(f"{OPTION} design.terminal_iterations", "an integer >= 0", f"{iterations!r} in {source}")
    info = raw.get("info", {})
    if not isinstance(info, dict):
        raise ProblemError(f"{OPTION} design.info", "a JSON object", f"{type(info).__name__} in {source}")
    bound = raw.get("mu_state_bound")
    if bound is not None and (isinstance(bound, bool) or not isinstance(bound, (int, float))
                              or not np.isfinite(bound) or bound <= 0):
        raise ProblemError(f"{OPTION} design.mu_state_bound", "null or a positive finite number", f"{bound!r} in {source}")
    if len(values["H_x"]) <= problem.n:
        raise ProblemError(f"{OPTION} design.H_x", f"more than n = {problem.n} rows (a bounded X0)",
                           f"{len(values['H_x'])} rows in {source}")
    return OfflineDesign(**values, terminal_iterations=iterations, info=info,
                         mu_state_bound=None if bound is None else float(bound))


def _array(raw: dict, name: str, shape: tuple[str, ...], sizes: dict, source: str) -> np.ndarray:
    field = f"{OPTION} design.{name}"
    if name not in raw:
        raise ProblemError(field, "a value", f"nothing (missing) in {source}")
    value = raw[name]
    try:
        if any(isinstance(x, bool) for x in np.asarray(value, dtype=object).ravel()):
            raise ValueError("booleans are not numbers")
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProblemError(field, f"an array of real numbers of shape ({', '.join(shape)})",
                           f"{_short(value)} ({exc}) in {source}") from None
    if arr.ndim != len(shape):
        raise ProblemError(field, f"an array of {len(shape)} dimension(s) ({', '.join(shape)})",
                           f"shape {arr.shape} in {source}")
    for axis, (label, length) in enumerate(zip(shape, arr.shape)):
        want = sizes.setdefault(label, length)
        if length != want:
            raise ProblemError(field, f"{label} = {want} along axis {axis} (shape ({', '.join(shape)}))",
                               f"shape {arr.shape} in {source}")
    if arr.size == 0 or not np.all(np.isfinite(arr)):
        raise ProblemError(field, "a non-empty array of finite numbers", f"{_short(value)} in {source}")
    return arr


def _number(raw: dict, name: str, source: str) -> float:
    value = raw.get(name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ProblemError(f"{OPTION} design.{name}", "a finite number", f"{value!r} in {source}")
    return float(value)


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _same_points(recorded: np.ndarray, computed: np.ndarray) -> float:
    """The largest distance from a point of one set to the nearest point of the other, relative to the
    sets' extent (inf when the counts differ)."""
    if recorded.shape != computed.shape:
        return float("inf")
    scale = max(1.0, float(np.max(np.abs(computed))))
    dist = np.linalg.norm(recorded[:, None, :] - computed[None, :, :], axis=2)
    return float(max(np.max(np.min(dist, axis=1)), np.max(np.min(dist, axis=0)))) / scale


def _require_consistent(design: OfflineDesign, spec, source: str) -> None:
    """Item 3 of the module docstring."""
    problem = spec.problem

    def refuse(name: str, expected: str, received: str) -> None:
        raise ProblemError(f"{OPTION} design.{name}", expected, f"{received} in {source}",
                           "The file was changed after it was written; design again (amcp design PROBLEM --out FILE)")

    if design.mu_state_bound != spec.design.mu_state_bound:
        refuse("mu_state_bound", f"the problem's design.mu_state_bound ({spec.design.mu_state_bound!r})",
               repr(design.mu_state_bound))
    try:
        x0_vertices = polytope.vertices(design.H_x, np.ones(len(design.H_x)))
    except ValueError as exc:
        refuse("H_x", "a bounded X0 = {x | H_x x <= 1} with an interior", f"rows whose vertices cannot be found ({exc})")
    gap = _same_points(design.X0_vertices, x0_vertices)
    if not gap <= VERTEX_MATCH_TOL:
        refuse("X0_vertices", f"the {len(x0_vertices)} vertices of {{x | H_x x <= 1}} (to {VERTEX_MATCH_TOL:g})",
               f"{len(design.X0_vertices)} points, farthest {gap:.3g} from a vertex")
    theta_vertices = problem.theta_vertices()
    gap = _same_points(design.theta_vertices, theta_vertices)
    if not gap <= VERTEX_MATCH_TOL:
        refuse("theta_vertices", f"the {len(theta_vertices)} vertices of the problem's Theta", f"{gap:.3g} from them")
    try:
        theta0_vertices = polytope.vertices(design.H_theta, design.h_theta0)
    except ValueError as exc:
        refuse("h_theta0", "Theta0 = {H_theta θ <= h_theta0} equal to Theta", f"a set whose vertices cannot be found ({exc})")
    gap = _same_points(theta0_vertices, theta_vertices)
    if not gap <= VERTEX_MATCH_TOL:
        refuse("h_theta0", "Theta0 = {H_theta θ <= h_theta0} equal to the problem's Theta (fixed shape of (9))",
               f"a set whose vertices are {gap:.3g} from Theta's")
    A_cl = closed_loop_vertices(problem, design.K, design.theta_vertices)
    h_bar = np.array([np.max(design.H_x @ Ak @ design.X0_vertices.T, axis=1) for Ak in A_cl])
    gap = float(np.max(np.abs(h_bar - design.h_bar)))
    if not gap <= H_BAR_TOL:
        refuse("h_bar", f"max over the vertices of X0 of H_x A_cl(θ^k) x (Appendix A.1, to {H_BAR_TOL:g})",
               f"values {gap:.3g} from it")
    if not abs(design.lambda_bar - float(np.max(design.h_bar))) <= 1e-12:
        refuse("lambda_bar", f"max h_bar = {float(np.max(design.h_bar))!r}", repr(design.lambda_bar))


def _require_checks_pass(design: OfflineDesign, spec, source: str) -> None:
    """Item 4 of the module docstring."""
    from amcp_drake.offline.checks import verify_design

    failed = [c for c in verify_design(spec.problem, design, spec.design.mu_state_bound) if not c.passed]
    if failed:
        listed = "; ".join(f"{c.name} ({c.status}{'' if c.margin is None else f', margin {c.margin:.3g}'})"
                           for c in failed)
        raise ProblemError(f"{OPTION} design", "a design that passes every independent check of the offline design",
                           f"a design that fails {len(failed)}: {listed} in {source}",
                           "Design again (amcp design PROBLEM --out FILE); nothing was run")


__all__ = ["DESIGN_FORMAT", "DESIGN_VERSION", "design_document", "design_from_document", "load_design", "save_design"]
