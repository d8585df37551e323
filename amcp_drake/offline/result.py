"""The result of the offline design (:class:`OfflineDesign`) and the two helpers the design and
its independent checks share: the closed-loop matrices at the vertices of Θ and sup ‖D(x,u)‖² of (11).

Kept apart from design.py so that the checks (offline/checks.py) and the automatic mode
(offline/auto.py) do not import the design code they judge or drive (no import cycle).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import ProblemError
from amcp_drake.model.problem import Problem


@dataclass(frozen=True, eq=False)
class OfflineDesign:
    """Result of :func:`design`. Shapes: n states, m inputs, p parameters, u facets of X0,
    v vertices of X0, v_p vertices of Θ, c rows of Z, r rows of X_f, q rows of H_θ.

    * ``K`` (m, n), ``P`` (n, n): Assumption 8 and (16).
    * ``H_x`` (u, n): X0 = {x | H_x x <= 1} (14); ``X0_vertices`` (v, n).
    * ``w_bar`` (u,): [w̄]_i = max_{w∈W} [H_x]_i w; ``f_bar`` (c,): [f̄]_i = max_{x∈X0} [F+GK]_i x.
    * ``h_bar`` (v_p, u): [h̄^k]_i = max_{x∈X0} [H_x]_i A_cl(θ^k) x (App. A.1); ``lambda_bar`` = max h̄.
    * ``A_z`` (n, n): centre dynamics z⁺ = A_z z of the terminal recursion (Appendix A.1).
    * ``H_T`` (r, n), ``h_T`` (r,): X_f = {(z, α) | H_T z + h_T α <= 1, α >= 0} (Assumption 11).
    * ``mu``: gain of (12); ``mu_sup`` = sup ‖D(x,u)‖₂² over ``mu_region`` (the (x,u) set used).
    * ``H_theta`` (q, p), ``h_theta0`` (q,): the fixed shape and initial offsets of (9), Θ ⊆ Θ0.
    * ``theta_vertices`` (v_p, p).
    """

    K: np.ndarray
    P: np.ndarray
    H_x: np.ndarray
    X0_vertices: np.ndarray
    w_bar: np.ndarray
    f_bar: np.ndarray
    h_bar: np.ndarray
    lambda_bar: float
    A_z: np.ndarray
    H_T: np.ndarray
    h_T: np.ndarray
    mu: float
    mu_sup: float
    mu_region: str
    H_theta: np.ndarray
    h_theta0: np.ndarray
    theta_vertices: np.ndarray
    terminal_iterations: int
    backend: str
    gain_source: str = "lmi"
    info: dict = field(default_factory=dict)
    #: the box |x_i| <= bound over which μ of (11) was computed when Z is unbounded in x (None: over Z);
    #: recorded with the design so that a trajectory carries what the certificate's (11) check needs
    mu_state_bound: float | None = None

    def to_dict(self) -> dict:
        """JSON-ready dict of every field."""
        out = {}
        for key in self.__dataclass_fields__:
            value = getattr(self, key)
            out[key] = value.tolist() if isinstance(value, np.ndarray) else value
        return out

    @classmethod
    def from_dict(cls, data: dict) -> OfflineDesign:
        """Inverse of :meth:`to_dict`."""
        kwargs = {}
        for key, f in cls.__dataclass_fields__.items():
            if key not in data:
                if key in ("gain_source", "info", "mu_state_bound"):
                    continue
                raise ProblemError(f"design.{key}", "a value", "nothing (missing)")
            value = data[key]
            kwargs[key] = np.asarray(value, float) if isinstance(value, list) else value
        return cls(**kwargs)


def closed_loop_vertices(problem: Problem, K: np.ndarray, theta_vertices: np.ndarray) -> np.ndarray:
    """A_cl(θ^k) = A(θ^k) + B(θ^k) K for every vertex θ^k of Θ, shape (v_p, n, n)."""
    return np.array([problem.A_of(t) + problem.B_of(t) @ K for t in theta_vertices])


def regressor_bound(problem: Problem, state_bound: float | None) -> tuple[float, str]:
    """sup ‖D(x,u)‖₂² over Z (or Z ∩ {|x_i| <= state_bound} when Z is unbounded in x).

    ‖D(x,u)‖₂ is convex in (x,u), so the supremum is attained at a vertex of that polytope,
    which are enumerated exactly (no optimisation solver is involved).
    """
    n, m = problem.n, problem.m
    H = np.hstack([problem.F, problem.G])
    h = np.ones(len(H))
    region = "Z"
    if not polytope.is_bounded(H, h):
        if state_bound is None:
            raise ProblemError("design.mu_state_bound", "a bound on |x_i| because Z is unbounded in x (needed for "
                               "sup ‖D(x,u)‖² in (11))", "nothing",
                               "Set design.mu_state_bound; the closed loop is then checked to stay inside that box.")
        Hb, hb = polytope.box(-state_bound * np.ones(n), state_bound * np.ones(n))
        H = np.vstack([H, np.hstack([Hb, np.zeros((2 * n, m))])])
        h = np.concatenate([h, hb])
        region = f"Z ∩ {{|x_i| <= {state_bound:g}}}"
        if not polytope.is_bounded(H, h):
            if np.any(problem.B != 0):
                raise ProblemError("Z.G", "Z bounded in the input u (needed for (11): D(x, u) depends on u through "
                                   "the B_i)", "an input direction without bound")
            return _state_regressor_bound(problem, Hb, hb, state_bound)
    verts = polytope.vertices(H, h)
    sup = max(float(np.linalg.norm(problem.regressor(vx[:n], vx[n:]), 2) ** 2) for vx in verts)
    if sup <= 0.0:
        raise ProblemError("system.A, system.B", "a regressor D(x,u) that is not identically zero on Z", "sup ‖D‖ = 0")
    return sup, region


def _state_regressor_bound(problem: Problem, H_box: np.ndarray, h_box: np.ndarray, state_bound: float) -> tuple[float, str]:
    """sup ‖D(x)‖₂² of (11) when every B_i = 0, so that D(x, u) = [A_1 x, ..., A_p x] does not depend on u
    and Z need not bound u (a known B: only A is uncertain).

    The supremum is taken over X_s = {x | the rows of Z without u} ∩ {|x_i| <= state_bound}, which
    contains the projection of Z ∩ {|x_i| <= state_bound} onto x: an upper bound of the supremum over Z
    (so μ of (11) is valid), equal to it when the rows of Z with u hold no x (input bounds) and admit
    some u. ‖D(x)‖₂ is convex, so the supremum is attained at a vertex of X_s (enumerated exactly)."""
    state_rows = np.all(problem.G == 0, axis=1)
    H = np.vstack([problem.F[state_rows], H_box])
    h = np.concatenate([np.ones(int(state_rows.sum())), h_box])
    zero_u = np.zeros(problem.m)
    sup = max(float(np.linalg.norm(problem.regressor(vx, zero_u), 2) ** 2) for vx in polytope.vertices(H, h))
    if sup <= 0.0:
        raise ProblemError("system.A", "a regressor D(x) that is not identically zero on Z", "sup ‖D‖ = 0")
    return sup, f"{{x | the rows of Z without u, |x_i| <= {state_bound:g}}} (B known: D does not depend on u)"
