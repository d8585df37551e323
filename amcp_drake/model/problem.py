"""The problem model: system (1)-(2), W, Theta, Z (Assumption 1, eqs (3)-(4)), cost and horizon.

All matrices are float64 numpy arrays. Shapes (n states, m inputs, p parameters):

* ``A0`` (n, n), ``B0`` (n, m); ``A`` (p, n, n), ``B`` (p, n, m): eq. (2),
  A(θ) = A0 + Σ_i A_i θ_i, B(θ) = B0 + Σ_i B_i θ_i.
* ``H_w`` (q_w, n): W = {w | H_w w <= 1} (Assumption 1).
* ``H_theta`` (q, p), ``h_theta`` (q,): Θ = {θ | H_θ θ <= h_θ}, eq. (3).
* ``F`` (c, n), ``G`` (c, m): Z = {(x, u) | F x + G u <= 1}, eq. (4).
* ``Q`` (n, n) ≻ 0, ``R`` (m, m) ≻ 0, horizon ``N`` >= 1: cost (17).
* ``theta_hat0`` (p,) ∈ Θ: initial point estimate of (12).
* ``states`` (n names and units, or empty), ``inputs`` (m, or empty), ``dt`` (sample time in
  seconds, or None): descriptive only (tables, plots, reports); they change no computation.

The engineering forms (bounds by name, box W and Θ, continuous-time models, Drake and python-control
systems) are translated to these fields by :mod:`amcp_drake.model.problem_builder`
(:meth:`Problem.from_matrices`, :meth:`Problem.from_drake_systems`, :meth:`Problem.from_control`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError
from amcp_drake.model.signals import Signal, as_signals, default_names
from amcp_drake.model.validate import (
    as_matrix,
    as_positive_int,
    as_vector,
    reject_booleans,
    require_finite,
    require_positive_definite,
)

#: θ̂0 may lie this far outside Θ (rounding in a problem file) before it is rejected.
THETA_HAT0_TOL = 1e-9
#: Slack on the rate bound of Assumption 17 when a θ* sequence is validated (round-off of a
#: sequence generated at exactly the rate d_θ).
THETA_RATE_TOL = 1e-12
#: A row of an explicit disturbance sequence (``scenario.disturbance``) may lie this far outside W
#: (H_w w <= 1 + tol) before it is rejected: vertices of W computed by vertex enumeration and
#: written to a file exceed the facets by round-off (~1e-15); 1e-9 matches THETA_HAT0_TOL.
DISTURBANCE_W_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class Problem:
    """An uncertain linear system with constraints, validated on construction."""

    A0: np.ndarray
    B0: np.ndarray
    A: np.ndarray
    B: np.ndarray
    H_w: np.ndarray
    H_theta: np.ndarray
    h_theta: np.ndarray
    F: np.ndarray
    G: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    N: int
    theta_hat0: np.ndarray
    name: str = "problem"
    states: tuple[Signal, ...] = ()
    inputs: tuple[Signal, ...] = ()
    dt: float | None = None

    def __post_init__(self) -> None:
        A0 = as_matrix("system.A0", self.A0)
        n = A0.shape[0]
        if A0.shape[1] != n:
            raise ProblemError("system.A0", f"a square matrix ({n}x{n})", f"shape {A0.shape}")
        B0 = as_matrix("system.B0", self.B0, rows=n)
        m = B0.shape[1]
        A = _stack("system.A", self.A, (n, n))
        B = _stack("system.B", self.B, (n, m))
        if A.shape[0] != B.shape[0]:
            raise ProblemError("system.B", f"{A.shape[0]} matrices (one per parameter, like system.A)", f"{B.shape[0]}")
        p = A.shape[0]
        if p < 1:
            raise ProblemError("system.A", "at least one uncertain parameter (p >= 1)", "p = 0")
        for i in range(p):
            if not (np.any(A[i]) or np.any(B[i])):
                raise ProblemError(
                    f"system.A[{i}], system.B[{i}]",
                    "at least one non-zero entry (parameter i must enter the model)",
                    "both all zero",
                    "Remove the parameter or give it a direction.",
                )
        H_w = as_matrix("W.H", self.H_w, cols=n)
        _require_bounded("W.H", H_w, np.ones(H_w.shape[0]), "W = {w | H_w w <= 1}")
        H_theta = as_matrix("Theta.H", self.H_theta, cols=p)
        h_theta = as_vector("Theta.h", self.h_theta, size=H_theta.shape[0])
        empty = np.all(H_theta == 0, axis=1) & (h_theta < 0)
        if np.any(empty):
            row = int(np.argmax(empty))
            raise ProblemError(f"Theta.h[{row}]", f"a value >= 0 for the zero row Theta.H[{row}] (0 <= h)",
                               f"{h_theta[row]:g}: Theta would be empty")
        _require_bounded("Theta.H", H_theta, h_theta, "Theta = {θ | H_θ θ <= h_θ}")
        F = as_matrix("Z.F", self.F, cols=n)
        G = as_matrix("Z.G", self.G, rows=F.shape[0], cols=m)
        if np.any(np.all(np.hstack([F, G]) == 0, axis=1)):
            row = int(np.argmax(np.all(np.hstack([F, G]) == 0, axis=1)))
            raise ProblemError("Z.F, Z.G", "no all-zero row (0 <= 1 is vacuous)", f"row {row} is all zero")
        Q = as_matrix("cost.Q", self.Q, rows=n, cols=n)
        require_positive_definite("cost.Q", Q)
        R = as_matrix("cost.R", self.R, rows=m, cols=m)
        require_positive_definite("cost.R", R)
        N = as_positive_int("cost.N", self.N, 1)
        theta_hat0 = as_vector("theta_hat0", self.theta_hat0, size=p)
        violation = polytope.max_violation(H_theta, h_theta, theta_hat0)
        if violation > THETA_HAT0_TOL:
            raise ProblemError("theta_hat0", "a point of Theta (H_θ θ̂0 <= h_θ)", f"{theta_hat0.tolist()}, outside by {violation:.3g}")
        if not isinstance(self.name, str) or not self.name:
            raise ProblemError("name", "a non-empty string", repr(self.name))
        object.__setattr__(self, "states", as_signals("states", self.states, n))
        object.__setattr__(self, "inputs", as_signals("inputs", self.inputs, m))
        if self.dt is not None:
            if isinstance(self.dt, bool) or not isinstance(self.dt, (int, float, np.floating)) \
                    or not np.isfinite(self.dt) or not 0 < self.dt <= 1e9:
                raise ProblemError("dt", "a sample time in seconds, a finite number > 0", repr(self.dt))
            object.__setattr__(self, "dt", float(self.dt))
        for key, value in dict(A0=A0, B0=B0, A=A, B=B, H_w=H_w, H_theta=H_theta, h_theta=h_theta,
                               F=F, G=G, Q=0.5 * (Q + Q.T), R=0.5 * (R + R.T), N=N, theta_hat0=theta_hat0).items():
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
            object.__setattr__(self, key, value)

    # -- dimensions -------------------------------------------------------------------------
    @property
    def n(self) -> int:
        """State dimension."""
        return self.A0.shape[0]

    @property
    def m(self) -> int:
        """Input dimension."""
        return self.B0.shape[1]

    @property
    def p(self) -> int:
        """Number of uncertain parameters."""
        return self.A.shape[0]

    # -- names and units (descriptive) ---------------------------------------------------------
    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the states: those given, else ``x1 … xn``."""
        return tuple(s.name for s in self.states) or default_names("x", self.n)

    @property
    def input_names(self) -> tuple[str, ...]:
        """Names of the inputs: those given, else ``u1 … um``."""
        return tuple(s.name for s in self.inputs) or default_names("u", self.m)

    def state_label(self, i: int) -> str:
        """Text of state i in tables and plots: ``name [unit]`` (``x{i+1}`` when unnamed)."""
        return self.states[i].label if self.states else f"x{i + 1}"

    def input_label(self, j: int) -> str:
        """Text of input j in tables and plots: ``name [unit]`` (``u{j+1}`` when unnamed)."""
        return self.inputs[j].label if self.inputs else f"u{j + 1}"

    def describe_signals(self) -> str:
        """One line naming the states, inputs and sample time (empty when none of them is given)."""
        if not (self.states or self.inputs or self.dt is not None):
            return ""
        parts = [f"states ({', '.join(self.state_label(i) for i in range(self.n))})",
                 f"inputs ({', '.join(self.input_label(j) for j in range(self.m))})"]
        if self.dt is not None:
            parts.append(f"sample time dt = {self.dt:g} s")
        return "; ".join(parts)

    # -- model, eq. (2) -----------------------------------------------------------------------
    def A_of(self, theta: np.ndarray) -> np.ndarray:
        """A(θ) = A0 + Σ_i A_i θ_i, eq. (2)."""
        return self.A0 + np.tensordot(np.asarray(theta, float), self.A, axes=1)

    def B_of(self, theta: np.ndarray) -> np.ndarray:
        """B(θ) = B0 + Σ_i B_i θ_i, eq. (2)."""
        return self.B0 + np.tensordot(np.asarray(theta, float), self.B, axes=1)

    def regressor(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """D(x, u) = [A_1 x + B_1 u, ..., A_p x + B_p u], shape (n, p) (regressor of Section 2 of the paper)."""
        return (self.A @ np.asarray(x, float) + self.B @ np.asarray(u, float)).T

    def step(self, x: np.ndarray, u: np.ndarray, theta: np.ndarray, w: np.ndarray) -> np.ndarray:
        """x⁺ = A(θ) x + B(θ) u + w, eq. (1)."""
        return self.A_of(theta) @ x + self.B_of(theta) @ u + w

    def theta_vertices(self) -> np.ndarray:
        """Vertices of Θ, shape (v_p, p)."""
        return polytope.vertices(self.H_theta, self.h_theta)

    def w_vertices(self) -> np.ndarray:
        """Vertices of W, shape (v_w, n)."""
        return polytope.vertices(self.H_w, np.ones(self.H_w.shape[0]))

    def in_Z(self, x: np.ndarray, u: np.ndarray) -> float:
        """max_i (F x + G u − 1)_i: <= 0 means (x, u) ∈ Z, eq. (4)."""
        return float(np.max(self.F @ x + self.G @ u - 1.0))

    def with_changes(self, **changes: Any) -> Problem:
        """A copy with some fields replaced (validated again). Names of states (inputs) are dropped when
        the new matrices change n (m) and no new names are given."""
        data = {f: getattr(self, f) for f in self.__dataclass_fields__}
        data.update(changes)
        if "states" not in changes and np.shape(data["A0"])[:1] != (self.n,):
            data["states"] = ()
        if "inputs" not in changes and np.ndim(data["B0"]) == 2 and np.shape(data["B0"])[1] != self.m:
            data["inputs"] = ()
        return Problem(**data)

    # -- constructors of the engineering forms (model/problem_builder.py) ---------------------
    @classmethod
    def from_matrices(cls, A0: Any, B0: Any, A: Any = None, B: Any = None, **forms: Any) -> Problem:
        """A problem from matrices, bounds by name, box W and Θ, optionally a continuous-time model
        (discretised by zero-order hold); see :func:`amcp_drake.model.problem_builder.problem_fields`
        for every keyword. The result holds the normalised rows of (3)-(4) and Assumption 1."""
        from amcp_drake.model.problem_builder import problem_fields

        return cls(**problem_fields(A0=A0, B0=B0, A=A, B=B, **forms)[0])

    @classmethod
    def from_drake_systems(cls, systems: Any, **forms: Any) -> Problem:
        """A problem from Drake ``LinearSystem``/``AffineSystem`` objects, one per parameter vertex:
        ``systems[0]`` at θ = 0, ``systems[i]`` at θ = e_i (A_i = A(e_i) − A(0), likewise B_i); see
        :func:`amcp_drake.model.problem_builder.from_system_family`."""
        from amcp_drake.model.problem_builder import drake_matrices, from_system_family

        return from_system_family(cls, drake_matrices(systems), **forms)

    @classmethod
    def from_control(cls, systems: Any, **forms: Any) -> Problem:
        """A problem from python-control ``StateSpace`` objects, one per parameter vertex (the
        convention of :meth:`from_drake_systems`)."""
        from amcp_drake.model.problem_builder import control_matrices, from_system_family

        return from_system_family(cls, control_matrices(systems), **forms)


def _stack(field_name: str, value: Any, shape: tuple[int, int]) -> np.ndarray:
    reject_booleans(field_name, value, f"a list of {shape[0]}x{shape[1]} matrices of real numbers")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ProblemError(field_name, f"a list of {shape[0]}x{shape[1]} matrices", "ragged or non-numeric data") from None
    if arr.ndim == 2 and shape[1] == 1 and arr.shape[1] == shape[0]:
        arr = arr[:, :, None]
    if arr.ndim != 3 or arr.shape[1:] != shape:
        raise ProblemError(field_name, f"a list of {shape[0]}x{shape[1]} matrices", f"an array of shape {arr.shape}")
    require_finite(field_name, arr)
    return arr


def _require_bounded(field_name: str, H: np.ndarray, h: np.ndarray, what: str) -> None:
    center, radius = polytope.chebyshev_center(H, h)
    if radius == float("-inf") or (np.isfinite(radius) and radius <= 1e-12):
        raise ProblemError(field_name, f"{what} non-empty with non-empty interior", f"Chebyshev radius {radius:.3g}")
    if not polytope.is_bounded(H, h):
        raise ProblemError(field_name, f"{what} bounded", "an unbounded set",
                           "Add rows so that the set is closed in every direction.")


@dataclass(frozen=True, eq=False)
class Scenario:
    """A closed-loop experiment on a problem: initial state, true parameter, disturbance.

    ``theta_star`` is a constant θ* (p,) or, for time-varying parameters (Section 4.1, system (24)),
    a sequence θ*_0 … θ*_T of shape (T+1, p) (or (T, p): the last value is held) with T = ``steps``;
    every θ*_k must lie in Θ, and a file's ``online.d_theta`` must bound its rate (Assumption 17).
    ``disturbance`` is one of ``"uniform"`` (i.i.d. uniform on W), ``"vertices"`` (i.i.d. on the
    vertices of W), ``"zero"`` (drawn with ``seed``), or the explicit sequence w_0 … w_{T-1} as an
    array of ``steps`` rows, each a point of W (Assumption 1; errors name the row,
    ``scenario.disturbance[k]``); ``seed`` is then unused. A campaign replay holds such an array.
    """

    x0: np.ndarray
    theta_star: np.ndarray
    steps: int = 50
    disturbance: str | np.ndarray = "uniform"
    seed: int = 0

    @property
    def explicit_disturbance(self) -> bool:
        """True when ``disturbance`` is an explicit sequence w_k (rows), not a kind drawn from a seed."""
        return not isinstance(self.disturbance, str)

    @property
    def time_varying(self) -> bool:
        """True when ``theta_star`` is a sequence θ*_k."""
        return np.ndim(self.theta_star) == 2

    def validate_for(self, problem: Problem) -> Scenario:
        """Check dimensions and θ* ∈ Θ (every θ*_k of a sequence) against ``problem``; return self."""
        x0 = as_vector("scenario.x0", self.x0, size=problem.n)
        steps = as_positive_int("scenario.steps", self.steps, 1)
        raw = np.asarray(self.theta_star, dtype=object)
        if raw.ndim == 2 and raw.shape[0] > 1:
            theta_star = as_matrix("scenario.theta_star", self.theta_star, cols=problem.p)
            if theta_star.shape[0] not in (steps, steps + 1):
                raise ProblemError("scenario.theta_star", f"a vector of length {problem.p} or a sequence of "
                                   f"{steps + 1} (or {steps}) rows θ*_0..θ*_T for steps = {steps}",
                                   f"{theta_star.shape[0]} rows")
            rows = [(f"scenario.theta_star[{k}]", th) for k, th in enumerate(theta_star)]
        else:
            theta_star = as_vector("scenario.theta_star", self.theta_star, size=problem.p)
            rows = [("scenario.theta_star", theta_star)]
        for name, th in rows:
            violation = polytope.max_violation(problem.H_theta, problem.h_theta, th)
            if violation > THETA_HAT0_TOL:
                raise ProblemError(name, "a point of Theta (Assumption 1 / 17)", f"outside by {violation:.3g}")
        if self.explicit_disturbance:
            object.__setattr__(self, "disturbance", _disturbance_rows(self.disturbance, steps, problem))
        elif self.disturbance not in DISTURBANCE_KINDS:
            raise ProblemError("scenario.disturbance", f"one of {sorted(DISTURBANCE_KINDS)} or an array of "
                               f"{steps} rows w_k of length {problem.n}", repr(self.disturbance))
        as_positive_int("scenario.seed", self.seed, 0)
        object.__setattr__(self, "x0", x0)
        object.__setattr__(self, "theta_star", theta_star)
        return self

    def max_theta_rate(self) -> float:
        """max_k ‖θ*_(k+1) − θ*_k‖ (0 for a constant θ*)."""
        return float(np.max(theta_steps(self.theta_star), initial=0.0))

    def theta_star_for(self, steps: int) -> np.ndarray:
        """The θ* argument of :func:`~amcp_drake.online.simulate.simulate` for a run of ``steps`` steps: the
        constant θ*, or the first steps+1 rows of the sequence (ProblemError when it is shorter)."""
        if not self.time_varying:
            return self.theta_star
        rows = self.theta_star.shape[0]
        if rows >= steps + 1:
            return self.theta_star[: steps + 1]
        if rows == steps:
            return self.theta_star
        raise ProblemError("steps", f"at most {rows} (scenario.theta_star is a sequence of {rows} rows)", str(steps))

    def disturbance_for(self, steps: int) -> str | np.ndarray:
        """The ``disturbance`` argument of :func:`~amcp_drake.online.simulate.simulate` for a run of ``steps``
        steps: the kind, or the first ``steps`` rows of the explicit sequence (ProblemError when it is
        shorter)."""
        if not self.explicit_disturbance:
            return self.disturbance
        rows = len(self.disturbance)
        if steps > rows:
            raise ProblemError("steps", f"at most {rows} (scenario.disturbance is a sequence of {rows} rows)",
                               str(steps))
        return np.asarray(self.disturbance, float)[:steps]


def _disturbance_rows(value: Any, steps: int, problem: Problem) -> np.ndarray:
    """An explicit disturbance sequence (``scenario.disturbance``): exactly ``steps`` rows, each a
    finite vector of length n in W = {w | H_w w <= 1} (Assumption 1), checked row by row."""
    if isinstance(value, np.ndarray):
        rows = list(value) if value.ndim >= 1 else None
    else:
        rows = list(value) if isinstance(value, (list, tuple)) else None
    if rows is None:
        raise ProblemError("scenario.disturbance", f"one of {sorted(DISTURBANCE_KINDS)} or an array of {steps} "
                           f"rows w_k of length {problem.n}", f"{type(value).__name__} {value!r}"[:200])
    if len(rows) != steps:
        raise ProblemError("scenario.disturbance", f"{steps} rows w_0..w_{steps - 1} (one per step, steps = {steps})",
                           f"{len(rows)} rows")
    out = np.empty((steps, problem.n))
    ones = np.ones(len(problem.H_w))
    for k, row in enumerate(rows):
        w = as_vector(f"scenario.disturbance[{k}]", row, size=problem.n)
        violation = float(np.max(problem.H_w @ w - ones))
        if violation > DISTURBANCE_W_TOL:
            raise ProblemError(f"scenario.disturbance[{k}]", "a point of W (H_w w <= 1, Assumption 1)",
                               f"{w.tolist()}, outside by {violation:.3g}")
        out[k] = w
    return out


def theta_steps(theta_star: np.ndarray) -> np.ndarray:
    """‖θ*_(k+1) − θ*_k‖ for each k of a sequence (rows); empty for a constant θ*."""
    theta_star = np.asarray(theta_star, float)
    if theta_star.ndim != 2:
        return np.zeros(0)
    return np.linalg.norm(np.diff(theta_star, axis=0), axis=1)


def check_theta_rate(theta_star: np.ndarray, d_theta: float, field: str = "theta_star") -> None:
    """Assumption 17 for a sequence θ*_k (rows): ‖θ*_(k+1) − θ*_k‖ <= d_θ (ProblemError otherwise;
    a constant θ* always passes)."""
    rates = theta_steps(theta_star)
    if rates.size and float(np.max(rates)) > d_theta + THETA_RATE_TOL:
        k = int(np.argmax(rates))
        raise ProblemError(field, f"a sequence with ‖θ*_(k+1) − θ*_k‖ <= d_theta = {d_theta:g} "
                           "(Assumption 17; set the online option d_theta)", f"rate {rates[k]:.3g} at k = {k}")


DISTURBANCE_KINDS = frozenset({"uniform", "vertices", "zero"})

#: Values of ``DesignOptions.state_units`` (offline/units.py).
STATE_UNITS = ("normalised", "as written")
#: λ of the contractive template when x0_template = "contractive" and x0_lambda is not given.
DEFAULT_X0_LAMBDA = 0.9


def default_x0_facets(n: int) -> int:
    """Facets of the ``"mrpi"`` template when ``design.x0_facets`` is not given: 8 (the paper's
    Example 1 and every earlier design of this project) while 8 >= 2n, i.e. n <= 4, else 2n (the
    ±e_i box, the fewest directions :func:`~amcp_drake.offline.templates.template_directions` takes)."""
    return max(8, 2 * int(n))


@dataclass(frozen=True, eq=False)
class DesignOptions:
    """Choices for the offline design ((11), (14), (16), Appendix A.1). Every choice the paper leaves open is a field here.

    * ``x0_facets``: number of facet directions of the ``"mrpi"`` tube shape X0 (2-D: equally spaced
      angles; n-D: ±e_i, then ±(e_i ± e_j)/√2, ...). X0 is the template outer approximation of the
      minimal robust positively invariant set of x⁺ = A_cl(θ)x + w, θ ∈ Θ (the paper's suggestion for X0).
      None (default): :func:`default_x0_facets` of the dimension (8 up to n = 4, 2n above), so a
      file without a ``design`` section is valid at every n; the other templates do not use it.
    * ``K``, ``P``: user-given gain and terminal weight, verified instead of designed.
    * ``lmi_margin``: ε of the LMI S ⪰ εI and the strictness of (16), in the scaled coordinates of
      ``backends/gain_scaling.py`` (where the mean vertex Riccati solution is I), so relative to the
      cost-to-go and independent of the units of x and u.
    * ``mu_state_bound``: when Z is unbounded in x, the box |x_i| <= bound used to evaluate
      sup ‖D(x,u)‖² in (11); required then. ``mu_fraction``: μ = fraction / sup ‖D‖² (< 1: strict).
    * ``centre_dynamics``: A_z, the centre dynamics z⁺ = A_z z of the terminal recursion (Appendix A.1): ``"nominal"`` = A_cl(θ̂0), ``"zero"`` = 0.
    * ``terminal_max_iter``: iteration cap of the terminal set recursion.
    * ``terminal_set``: ``"recursion"`` (Appendix A.1, docs/explanation/paper.md §5), ``"scaled"`` (the copy
      {H_x z + α1 <= ᾱ1} of offline/terminal.py, as many rows as X0, centre dynamics z⁺ = 0) or
      ``"auto"`` (default: the recursion up to n = 3, the scaled copy above).
    * ``theta_extra_directions``: extra facet normals (k, p) for the fixed-complexity shape H_θ of (9).
    * ``x0_template``: the cross-section template (offline/templates.py, docs/decisions.md "X0 templates"):
      ``"auto"`` (default: the order of offline/auto.py, first design passing every design check),
      ``"mrpi"`` (minimal-RPI outer approximation with ``x0_facets`` directions), ``"contractive"``
      (maximal ``x0_lambda``-contractive set in Z under u = Kx, scaled to be robustly invariant),
      ``"given"`` (``x0_H``, rows of X0 = {x | x0_H x <= 1}), ``"parallelotope"`` ({‖T x‖∞ <= s}
      with a gain K from a linear program making it λ-contractive; offline/parallelotope.py),
      ``"preimage"`` (normals of the nominal closed loop's maximal ``x0_lambda``-contractive set, the least
      robustly invariant template over Θ's vertices; offline/preimage.py).
    * ``x0_lambda``: λ of the contractive template (None: 0.9 for "contractive"; auto tries its list);
      λ₀ of the preimage template's directions (None: 0.97).
    * ``x0_H`` (u, n): the user's X0 for ``"given"``.
    * ``x0_max_facets``: most rows of the ``"contractive"`` and ``"preimage"`` X0 (their iteration stops
      as "too complex" past it) and of the ``"mrpi"`` candidates the automatic mode tries; None
      (default): each template's own cap. The automatic mode first tries every candidate under a
      smaller cap from n = 4 on (offline/auto.py, docs/decisions.md "X0 templates and the automatic design").
    * ``gain_R_scale`` (>= 1): the gain LMI (16) is solved with R multiplied by this (a lower-gain K,
      whose P still satisfies (16) with the true R); 1 = the LMI of the paper.
    * ``state_units``: ``"normalised"`` (default): the design is computed in the state units where
      W's extents are equal and mapped back, so the same system in other diagonal units gets the same
      design (offline/units.py; no change where W's extents are already equal); ``"as written"``: in
      the units of the file (kept by the recorded regression problems, which pin the designs they were recorded with).
    """

    x0_facets: int | None = None
    K: np.ndarray | None = None
    P: np.ndarray | None = None
    lmi_margin: float = 1e-6
    mu_state_bound: float | None = None
    mu_fraction: float = 0.95
    centre_dynamics: str = "nominal"
    terminal_max_iter: int = 60
    theta_extra_directions: np.ndarray | None = None
    mrpi_max_iter: int = 500
    x0_template: str = "auto"
    x0_lambda: float | None = None
    x0_H: np.ndarray | None = None
    gain_R_scale: float = 1.0
    state_units: str = "normalised"
    x0_max_facets: int | None = None
    terminal_set: str = "auto"

    def validate_for(self, problem: Problem) -> DesignOptions:
        """Check values and shapes against ``problem``; return self."""
        if self.x0_facets is not None:
            as_positive_int("design.x0_facets", self.x0_facets, 2 * problem.n)
        if self.x0_max_facets is not None:
            as_positive_int("design.x0_max_facets", self.x0_max_facets, 2 * problem.n)
        if self.K is not None:
            object.__setattr__(self, "K", as_matrix("design.K", self.K, rows=problem.m, cols=problem.n))
        if self.P is not None:
            P = as_matrix("design.P", self.P, rows=problem.n, cols=problem.n)
            require_positive_definite("design.P", P)
            object.__setattr__(self, "P", P)
        if (self.K is None) != (self.P is None) and self.P is not None:
            raise ProblemError("design.K", "K given whenever P is given", "P without K")
        if not (isinstance(self.lmi_margin, (int, float)) and 0 < self.lmi_margin < 1):
            raise ProblemError("design.lmi_margin", "a number in (0, 1)", repr(self.lmi_margin))
        if self.mu_state_bound is not None and not (isinstance(self.mu_state_bound, (int, float))
                                                    and np.isfinite(self.mu_state_bound) and self.mu_state_bound > 0):
            raise ProblemError("design.mu_state_bound", "a positive finite number", repr(self.mu_state_bound))
        if not (isinstance(self.mu_fraction, (int, float)) and 0 < self.mu_fraction < 1):
            raise ProblemError("design.mu_fraction", "a number in (0, 1) (1/μ > sup‖D‖² is strict)", repr(self.mu_fraction))
        if self.state_units not in STATE_UNITS:
            raise ProblemError("design.state_units", f"one of {list(STATE_UNITS)}", repr(self.state_units))
        if self.terminal_set not in ("auto", "recursion", "scaled"):
            raise ProblemError("design.terminal_set", "one of ['auto', 'recursion', 'scaled']", repr(self.terminal_set))
        if self.centre_dynamics not in ("nominal", "zero"):
            raise ProblemError("design.centre_dynamics", "'nominal' or 'zero'", repr(self.centre_dynamics))
        as_positive_int("design.terminal_max_iter", self.terminal_max_iter, 1)
        as_positive_int("design.mrpi_max_iter", self.mrpi_max_iter, 1)
        if self.theta_extra_directions is not None:
            object.__setattr__(self, "theta_extra_directions",
                               as_matrix("design.theta_extra_directions", self.theta_extra_directions, cols=problem.p))
        self._validate_template(problem)
        return self

    def facets_for(self, n: int) -> int:
        """The facet count of the ``"mrpi"`` template at dimension n: ``x0_facets`` when given, else
        :func:`default_x0_facets` (n)."""
        return int(self.x0_facets) if self.x0_facets is not None else default_x0_facets(n)

    def _validate_template(self, problem: Problem) -> None:
        kinds = ("auto", "mrpi", "contractive", "given", "parallelotope", "preimage")
        if not isinstance(self.x0_template, str) or self.x0_template not in kinds:
            raise ProblemError("design.x0_template", f"one of {list(kinds)}", repr(self.x0_template))
        if self.x0_lambda is not None and not (isinstance(self.x0_lambda, (int, float))
                                               and not isinstance(self.x0_lambda, bool) and 0 < self.x0_lambda < 1):
            raise ProblemError("design.x0_lambda", "a number in (0, 1) (the contraction factor λ)", repr(self.x0_lambda))
        if self.x0_template == "given":
            if self.x0_H is None:
                raise ProblemError("design.x0_H", "the rows of X0 = {x | H x <= 1} (x0_template is 'given')", "nothing",
                                   "Give design.x0_H or choose another design.x0_template.")
        if self.x0_H is not None:
            if self.x0_template not in ("given", "auto"):
                raise ProblemError("design.x0_H", f"no value unless x0_template is 'given' (it is {self.x0_template!r})",
                                   "a matrix")
            H = as_matrix("design.x0_H", self.x0_H, cols=problem.n)
            if H.shape[0] < problem.n + 1:
                raise ProblemError("design.x0_H", f"at least n + 1 = {problem.n + 1} rows (a bounded X0)", f"{H.shape[0]} rows")
            object.__setattr__(self, "x0_H", H)
        if isinstance(self.gain_R_scale, bool) or not (isinstance(self.gain_R_scale, (int, float))
                                                       and np.isfinite(self.gain_R_scale) and self.gain_R_scale >= 1):
            raise ProblemError("design.gain_R_scale", "a finite number >= 1 (R is scaled up, never down, so that (16) "
                               "holds with the true R)", repr(self.gain_R_scale))


@dataclass(frozen=True, eq=False)
class ProblemSpec:
    """Everything a problem file holds: the problem, design options, a default scenario and the
    default online options (``online``: an :class:`~amcp_drake.model.options.OnlineOptions`, or None
    for the defaults; the CLIs start from it). ``notes``: what loading changed (e.g. redundant rows
    removed, :func:`~amcp_drake.model.limits.remove_redundant_rows`); the CLIs print them."""

    problem: Problem
    design: DesignOptions = field(default_factory=DesignOptions)
    scenario: Scenario | None = None
    online: Any = None
    notes: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        self.design.validate_for(self.problem)
        if self.scenario is not None:
            self.scenario.validate_for(self.problem)
            d_theta = getattr(self.online, "d_theta", 0.0) if self.online is not None else 0.0
            check_theta_rate(self.scenario.theta_star, d_theta, "scenario.theta_star")
