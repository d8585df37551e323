"""Problems as engineers write them, translated to the normalised rows of the paper.

The :class:`~amcp_drake.model.problem.Problem` holds the paper's representation: W = {w | H_w w <= 1}
(Assumption 1), Θ = {θ | H_θ θ <= h_θ} (3), Z = {(x, u) | F x + G u <= 1} (4), and the discrete-time
model (1)-(2). This module builds those fields from the forms of docs/problem-format.md,
"Engineering forms", for the JSON file (:func:`amcp_drake.model.problem_io.spec_from_dict`) and the
Python constructors alike (:meth:`Problem.from_matrices`, :meth:`Problem.from_drake_systems`,
:meth:`Problem.from_control`); errors name the JSON path of the field (``bounds.x.p[0]``, ``W.box[1]``).

* **Bounds by name** ``x_bounds={"p": (lo, hi), ...}`` (or ``{"min": [...], "max": [...]}``), likewise
  ``u_bounds``; ``None`` for a side without a bound. A bound must leave 0 strictly inside (lo < 0 < hi:
  the paper's Z contains the origin in its interior, and its rows have right-hand side 1): the upper
  bound x_i <= hi is the row e_iᵀ/hi, the lower bound x_i >= lo is the row e_iᵀ/lo. Rows: states in
  index order (upper, then lower), then inputs, then the general rows ``F``, ``G`` (kept as given).
* **A box W** ``W_box=[c_1, ..., c_n]`` (|w_i| <= c_i, c_i > 0): rows +e_iᵀ/c_i, −e_iᵀ/c_i per i.
* **A box Θ** ``Theta_box=[[lo_1, hi_1], ...]`` (lo_i < hi_i): rows +e_iᵀ <= hi_i, −e_iᵀ <= −lo_i per i;
  θ̂0 defaults to the box's centre.
* **A continuous-time model** (``continuous=True``, ``dt`` required): ẋ = A_c(θ) x + B_c(θ) u is
  discretised by zero-order hold, exactly, with one matrix exponential of the augmented matrix
  [[A_c, B_c], [0, 0]]·dt (:func:`zoh`). The discretised model stays affine in θ (2) only when θ
  enters B_c alone: then A_d = e^{A0 dt}, B_d(θ) = Γ (B0 + Σ B_i θ_i) with Γ = ∫₀^dt e^{A0 s} ds, so
  B_{d,i} = Γ B_i exactly. A continuous-time model with some A_i ≠ 0 is refused (the exponential of
  an affine family is not affine; any affine fit would leave an unbounded model error outside W).
  W, Z, Q and R are the discrete-time quantities of the paper (per sample). docs/decisions.md,
  "Continuous-time models".
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.signals import as_signals, default_names
from amcp_drake.model.validate import MAX_ABS_ENTRY, as_matrix, as_vector, reject_booleans

#: Smallest magnitude of a bound or half-width: its row 1/bound must stay within MAX_ABS_ENTRY.
MIN_ABS_BOUND = 1.0 / MAX_ABS_ENTRY


def _shown(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


# -- zero-order hold ------------------------------------------------------------------------------------
def zoh(Ac: np.ndarray, Bc: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """(A_d, B_d) = (e^{A_c dt}, ∫₀^dt e^{A_c s} ds B_c) from expm([[A_c, B_c], [0, 0]]·dt)."""
    from scipy.linalg import expm

    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = Ac * dt
    M[:n, n:] = Bc * dt
    E = expm(M)
    return E[:n, :n], E[:n, n:]


def discretise(A0: np.ndarray, B0: np.ndarray, A: np.ndarray, B: np.ndarray, dt: float, where: str = "system"):
    """The zero-order-hold discretisation of the affine family (2) in continuous time; θ must enter B
    alone (module docstring). Returns (A0_d, B0_d, A_d, B_d)."""
    for i, Ai in enumerate(A):
        if np.any(Ai):
            raise ProblemError(
                f"{where}.A[{i}]", "a zero matrix in a continuous-time model: zero-order hold keeps the model affine "
                "in θ (eq. (2)) only when θ enters B alone", "a non-zero matrix",
                "Discretise the model yourself and give the discrete-time matrices, or let θ enter B only "
                "(docs/decisions.md, 'Continuous-time models')")
    n, m = B0.shape
    p = A.shape[0]
    Ad, Bd_all = zoh(A0, np.hstack([B0, *B]), dt)
    Bd = Bd_all[:, :m]
    Bi = np.stack([Bd_all[:, m * (i + 1): m * (i + 2)] for i in range(p)]) if p else np.zeros((0, n, m))
    return Ad, Bd, np.zeros_like(A), Bi


# -- sets -----------------------------------------------------------------------------------------------
def _number_or_none(field: str, value: Any) -> float | None:
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ProblemError(field, "a number or null (no bound on this side)", _shown(value))
    value = float(value)
    if not np.isfinite(value):
        raise ProblemError(field, "a finite number or null (no bound on this side)", _shown(value))
    return value


def _named_bounds(field: str, spec: Any, names: tuple[str, ...]) -> list[tuple]:
    """(lo, hi, field of lo, field of hi) per signal from the by-name or the min/max form (None: no
    bound on that side; ``(None, None)`` for a signal without bounds)."""
    out: list[tuple] = [(None, None)] * len(names)
    if spec is None:
        return out
    if not isinstance(spec, dict):
        raise ProblemError(field, 'an object {"name": [lo, hi], ...} or {"min": [...], "max": [...]}', _shown(spec))
    if set(spec) & {"min", "max"}:
        if set(spec) - {"min", "max"}:
            extra = sorted(set(spec) - {"min", "max"})[0]
            raise ProblemError(f"{field}.{extra}", "either the arrays min/max or bounds by name, not both",
                               f"the key {extra!r} beside min/max")
        sides = {}
        for side in ("min", "max"):
            arr = spec.get(side)
            if arr is None:
                sides[side] = [None] * len(names)
                continue
            if not isinstance(arr, (list, tuple, np.ndarray)) or len(arr) != len(names):
                raise ProblemError(f"{field}.{side}", f"a list of {len(names)} numbers or nulls (one per signal)",
                                   _shown(arr))
            sides[side] = [_number_or_none(f"{field}.{side}[{i}]", v) for i, v in enumerate(arr)]
        return [(None, None) if lo is None and hi is None else (lo, hi, f"{field}.min[{i}]", f"{field}.max[{i}]")
                for i, (lo, hi) in enumerate(zip(sides["min"], sides["max"]))]
    for key, value in spec.items():
        if key not in names:
            raise ProblemError(f"{field}.{key}", f"the name of a signal, one of {list(names)}", f"unknown name {key!r}")
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ProblemError(f"{field}.{key}", "[lo, hi] (a number or null on each side)", _shown(value))
        i = names.index(key)
        out[i] = (_number_or_none(f"{field}.{key}[0]", value[0]), _number_or_none(f"{field}.{key}[1]", value[1]),
                  f"{field}.{key}[0]", f"{field}.{key}[1]")
    return out


def _require_resolvable(field: str, bound: float) -> None:
    """A bound (half-width) of magnitude at least MIN_ABS_BOUND: its row 1/bound stays within the entry
    bound of problem data (docs/decisions.md, "Strict input files")."""
    if abs(bound) < MIN_ABS_BOUND:
        raise ProblemError(field, f"a magnitude of at least {MIN_ABS_BOUND:g} (its row 1/bound has entries of magnitude "
                           f"at most {MAX_ABS_ENTRY:g}; rescale the units)", f"{bound:g}")


def bound_rows(field: str, spec: Any, names: tuple[str, ...]) -> np.ndarray:
    """Rows r with r·v <= 1 for the bounds ``spec`` on the signals ``names`` (module docstring): per
    signal in index order, e_iᵀ/hi for v_i <= hi, then e_iᵀ/lo for v_i >= lo; lo < 0 < hi required."""
    rows = []
    for i, entry in enumerate(_named_bounds(field, spec, names)):
        if entry == (None, None):
            continue
        lo, hi, lo_field, hi_field = entry
        if lo is None and hi is None:
            raise ProblemError(f"{field}.{names[i]}", "a bound on at least one side", "[null, null]")
        if hi is not None:
            if not hi > 0:
                raise ProblemError(hi_field, "an upper bound > 0: the origin must lie strictly inside Z (eq. (4), "
                                   "rows F x + G u <= 1)", f"{hi:g}",
                                   "Shift the coordinates so that the equilibrium 0 lies strictly between the bounds")
            _require_resolvable(hi_field, hi)
            rows.append(np.eye(len(names))[i] / hi)
        if lo is not None:
            if not lo < 0:
                raise ProblemError(lo_field, "a lower bound < 0: the origin must lie strictly inside Z (eq. (4), "
                                   "rows F x + G u <= 1)", f"{lo:g}",
                                   "Shift the coordinates so that the equilibrium 0 lies strictly between the bounds")
            _require_resolvable(lo_field, lo)
            rows.append(np.eye(len(names))[i] / lo)
    return np.array(rows).reshape(-1, len(names)) + 0.0  # + 0.0: no -0.0 in the rows written back


def box_W(field: str, half_widths: Any, n: int) -> np.ndarray:
    """W.H of the box |w_i| <= c_i: rows +e_iᵀ/c_i, −e_iᵀ/c_i for each i."""
    c = as_vector(field, half_widths, size=n)
    bad = np.flatnonzero(~(c > 0))
    if bad.size:
        raise ProblemError(f"{field}[{bad[0]}]", "a half-width > 0 (0 must lie in the interior of W, Assumption 1)",
                           f"{c[bad[0]]:g}")
    for i in range(n):
        _require_resolvable(f"{field}[{i}]", c[i])
    rows = []
    for i in range(n):
        e = np.eye(n)[i] / c[i]
        rows += [e, -e]
    return np.array(rows) + 0.0  # + 0.0: no -0.0 in the rows written back


def box_Theta(field: str, box: Any, p: int) -> tuple[np.ndarray, np.ndarray]:
    """(H_θ, h_θ) of the box lo_i <= θ_i <= hi_i: rows +e_iᵀ <= hi_i, −e_iᵀ <= −lo_i for each i."""
    reject_booleans(field, box, "a list of [lo, hi] pairs")
    if not isinstance(box, (list, tuple, np.ndarray)) or len(box) != p:
        raise ProblemError(field, f"a list of {p} intervals [lo, hi] (one per parameter)", _shown(box))
    H, h = [], []
    for i, pair in enumerate(box):
        lo, hi = as_vector(f"{field}[{i}]", pair, size=2)
        if not lo < hi:
            raise ProblemError(f"{field}[{i}]", "an interval [lo, hi] with lo < hi (Θ has a non-empty interior, "
                               "eq. (3))", f"[{lo:g}, {hi:g}]")
        e = np.eye(p)[i]
        H += [e, -e]
        h += [hi, -lo]
    return np.array(H) + 0.0, np.array(h) + 0.0


def _stack(field: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    arr = np.asarray(value, dtype=float) if not isinstance(value, (list, tuple)) or value else np.zeros((0, *shape))
    if arr.ndim == 2 and shape[1] == 1 and arr.shape[1] == shape[0]:
        arr = arr[:, :, None]
    if arr.ndim == 2 and arr.shape == shape:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != shape:
        raise ProblemError(field, f"a list of {shape[0]}x{shape[1]} matrices", f"an array of shape {arr.shape}")
    return arr


# -- the whole problem ----------------------------------------------------------------------------------
def problem_fields(*, A0: Any, B0: Any, A: Any = None, B: Any = None, Q: Any, R: Any, N: int,
                   W_H: Any = None, W_box: Any = None, Theta_H: Any = None, Theta_h: Any = None,
                   Theta_box: Any = None, x_bounds: Any = None, u_bounds: Any = None, F: Any = None,
                   G: Any = None, theta_hat0: Any = None, states: Any = None, inputs: Any = None,
                   dt: float | None = None, continuous: bool = False, name: str = "problem") -> tuple[dict, list[str]]:
    """The keyword arguments of :class:`~amcp_drake.model.problem.Problem` and the notes of what was
    translated, from the forms of the module docstring.

    ``A``/``B``: lists of p matrices (one may be omitted: zeros). W: ``W_H`` or ``W_box``. Θ:
    ``Theta_H`` and ``Theta_h``, or ``Theta_box``. Z: ``x_bounds``/``u_bounds`` and/or the general rows
    ``F``, ``G`` (at least one constraint). ``states``/``inputs``: names (strings, or
    ``{"name", "unit"}``). ``dt``: the sample time in seconds (required with ``continuous=True``)."""
    A0 = as_matrix("system.A0", A0)
    n = A0.shape[0]
    B0 = as_matrix("system.B0", B0, rows=n)
    m = B0.shape[1]
    if A is None and B is None:
        raise ProblemError("system.A", "a list of p matrices A_i (or system.B: θ must enter the model, eq. (2))",
                           "nothing")
    A = _stack("system.A", A, (n, n)) if A is not None else None
    B = _stack("system.B", B, (n, m)) if B is not None else None
    A = np.zeros((B.shape[0], n, n)) if A is None else A
    B = np.zeros((A.shape[0], n, m)) if B is None else B
    if A.shape[0] != B.shape[0]:
        raise ProblemError("system.B", f"{A.shape[0]} matrices (one per parameter, like system.A)", f"{B.shape[0]}")
    p = A.shape[0]
    notes: list[str] = []
    if not isinstance(continuous, (bool, np.bool_)):
        raise ProblemError("system.continuous", "true or false", _shown(continuous))
    if continuous:
        if dt is None:
            raise ProblemError("dt", "a sample time in seconds (system.continuous is true: the model is "
                               "discretised by zero-order hold with it)", "nothing")
        if isinstance(dt, bool) or not isinstance(dt, (int, float, np.floating)) or not (np.isfinite(dt) and dt > 0):
            raise ProblemError("dt", "a sample time in seconds, a finite number > 0", _shown(dt))
        for field, mat in (("system.A0", A0), ("system.B0", B0)):
            if not np.all(np.isfinite(mat)):
                raise ProblemError(field, "finite numbers", "a non-finite entry")
        A0, B0, A, B = discretise(A0, B0, A, B, float(dt))
        notes.append(f"system: continuous-time model discretised by zero-order hold with dt = {float(dt):g} s "
                     "(exact: θ enters B only)")
    states_sig = as_signals("states", states, n)
    inputs_sig = as_signals("inputs", inputs, m)
    # W
    if (W_H is None) == (W_box is None):
        raise ProblemError("W", "exactly one of W.H (rows, H w <= 1) and W.box (half-widths)",
                           "both" if W_H is not None else "neither")
    H_w = box_W("W.box", W_box, n) if W_box is not None else W_H
    # Θ
    if Theta_box is not None:
        if Theta_H is not None or Theta_h is not None:
            raise ProblemError("Theta", "either Theta.box or Theta.H with Theta.h, not both", "both")
        H_theta, h_theta = box_Theta("Theta.box", Theta_box, p)
        if theta_hat0 is None:
            theta_hat0 = np.asarray([np.mean(pair) for pair in np.asarray(Theta_box, float)])
    else:
        if Theta_H is None or Theta_h is None:
            missing = "Theta.H" if Theta_H is None else "Theta.h"
            raise ProblemError(missing, "a value (or Theta.box)", "nothing (key missing)")
        H_theta, h_theta = Theta_H, Theta_h
        if theta_hat0 is None:
            raise ProblemError("theta_hat0", "a point of Theta (required unless Theta is given as a box)",
                               "nothing (key missing)")
    # Z
    state_names = tuple(s.name for s in states_sig) or default_names("x", n)
    input_names = tuple(s.name for s in inputs_sig) or default_names("u", m)
    x_rows = bound_rows("bounds.x", x_bounds, state_names)
    u_rows = bound_rows("bounds.u", u_bounds, input_names)
    blocks_F = [x_rows, np.zeros((len(u_rows), n))]
    blocks_G = [np.zeros((len(x_rows), m)), u_rows]
    if F is not None or G is not None:
        if F is None or G is None:
            raise ProblemError("Z.F" if F is None else "Z.G", "a value (Z needs both F and G)", "nothing (key missing)")
        F_general = as_matrix("Z.F", F, cols=n)
        blocks_F.append(F_general)
        blocks_G.append(as_matrix("Z.G", G, rows=F_general.shape[0], cols=m))
    F_all, G_all = np.vstack(blocks_F), np.vstack(blocks_G)
    if F_all.shape[0] == 0:
        raise ProblemError("Z", "constraints: bounds.x / bounds.u by name, or the rows Z.F, Z.G", "nothing")
    if len(x_rows) + len(u_rows):
        notes.append(f"bounds: {len(x_rows)} state and {len(u_rows)} input bound(s) written as rows of Z "
                     "(F x + G u <= 1)")
    fields = {"A0": A0, "B0": B0, "A": A, "B": B, "H_w": H_w, "H_theta": H_theta, "h_theta": h_theta,
              "F": F_all, "G": G_all, "Q": Q, "R": R, "N": N, "theta_hat0": theta_hat0, "name": name,
              "states": states_sig, "inputs": inputs_sig, "dt": None if dt is None else dt}
    return fields, notes


# -- families of systems, one per parameter vertex -------------------------------------------------------
def drake_matrices(systems: Any) -> list[tuple[np.ndarray, np.ndarray, float | None]]:
    """(A, B, sample time or None for continuous time) of each Drake ``LinearSystem``/``AffineSystem``;
    an ``AffineSystem`` must have f0 = 0 (the model (1) has no constant term). The outputs (C, D, y0)
    are not used: the controller measures the state."""
    out = []
    for k, system in enumerate(_as_list("systems", systems)):
        where = f"systems[{k}]"
        if not (hasattr(system, "A") and hasattr(system, "B") and hasattr(system, "time_period")):
            raise ProblemError(where, "a Drake LinearSystem or AffineSystem", type(system).__name__)
        f0 = np.asarray(system.f0(), float) if hasattr(system, "f0") else np.zeros(0)
        if np.any(f0):
            raise ProblemError(f"{where}.f0", "zero (the model (1) x⁺ = A(θ)x + B(θ)u + w has no constant term)",
                               f"{f0.tolist()}", "Shift the coordinates to the equilibrium")
        period = float(system.time_period())
        out.append((np.asarray(system.A(), float), np.asarray(system.B(), float), period if period > 0 else None))
    return out


def control_matrices(systems: Any) -> list[tuple[np.ndarray, np.ndarray, float | None]]:
    """(A, B, sample time or None for continuous time) of each python-control ``StateSpace``
    (``dt = 0``: continuous time; ``dt > 0``: discrete time with that period; ``dt`` None or True,
    an unspecified sample time, is refused)."""
    out = []
    for k, system in enumerate(_as_list("systems", systems)):
        where = f"systems[{k}]"
        if not (hasattr(system, "A") and hasattr(system, "B") and hasattr(system, "dt")):
            raise ProblemError(where, "a python-control StateSpace", type(system).__name__)
        dt = system.dt
        if dt is None or isinstance(dt, bool) or not (dt >= 0):
            raise ProblemError(f"{where}.dt", "0 (continuous time) or a sample time > 0 in seconds",
                               _shown(dt), "Create the system with an explicit dt")
        out.append((np.asarray(system.A, float), np.asarray(system.B, float), float(dt) if dt > 0 else None))
    return out


def _as_list(field: str, systems: Any) -> list:
    if not isinstance(systems, (list, tuple)) or len(systems) < 2:
        raise ProblemError(field, "a list of p + 1 >= 2 systems: θ = 0, then θ = e_1, ..., e_p", _shown(systems))
    return list(systems)


def from_system_family(cls: type, family: list[tuple[np.ndarray, np.ndarray, float | None]], **forms: Any):
    """``cls.from_matrices`` of the family (A(0), B(0)), (A(e_1), B(e_1)), ...: A0 = A(0),
    A_i = A(e_i) − A(0), B likewise (exact when the family is affine in θ, eq. (2)). Discrete-time
    systems give ``dt`` (all periods equal); continuous-time systems need ``dt`` and are discretised by
    zero-order hold (θ must then enter B alone)."""
    periods = {period for _, _, period in family}
    if len(periods) > 1:
        raise ProblemError("systems", "systems of one kind and one sample time",
                           f"sample times {sorted(periods, key=lambda t: -1.0 if t is None else t)} (None: continuous)")
    period = periods.pop()
    A_nom, B_nom, _ = family[0]
    for k, (Ak, Bk, _) in enumerate(family):
        if Ak.shape != A_nom.shape or Bk.shape != B_nom.shape:
            raise ProblemError(f"systems[{k}]", f"A {A_nom.shape} and B {B_nom.shape} like systems[0]",
                               f"A {Ak.shape}, B {Bk.shape}")
    A = [Ak - A_nom for Ak, _, _ in family[1:]]
    B = [Bk - B_nom for _, Bk, _ in family[1:]]
    if period is None:
        forms.setdefault("continuous", True)
    else:
        given = forms.get("dt")
        if given is not None and given != period:
            raise ProblemError("dt", f"the systems' sample time {period:g} s (or nothing)", f"{given!r}")
        forms["dt"] = period
    return cls.from_matrices(A_nom, B_nom, A, B, **forms)


__all__ = ["bound_rows", "box_Theta", "box_W", "control_matrices", "discretise", "drake_matrices",
           "from_system_family", "problem_fields", "zoh"]
