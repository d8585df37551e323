"""Hypothesis strategies that BUILD valid closed-loop experiments (no filtering on validity).

Every generated problem meets Assumption 1 by construction (W and Θ bounded polytopes, 0 in the
interior of W, θ̂0 and θ* in Θ); Assumptions 8 and 11 and (16) are then obtained from the
project's offline design (:func:`amcp_drake.offline.design.design`), which can still fail (no robust
gain, X0 not contractive, X_f empty). Such a failure is a *generator rejection*: it is counted
in :data:`GENERATOR_STATS` and reported by the suite, and the generator is tuned so that it is
rare (systems are "nice" by construction: ‖A0‖∞ < 1 most of the time, small ‖[A_i B_i]‖, W small
relative to Z).

Numbers are drawn on coarse grids (``_grid``) so that shrunk counterexamples are readable and the
shrinker moves towards simple values; rare nasty cases sit behind ``draw(booleans())``.

Layers:

* :func:`problem_specs` -> :class:`GeneratedProblem` (a :class:`ProblemSpec` plus labels);
* :func:`designed_problems` -> :class:`DesignedProblem` (adds the offline design, Drake backend);
* :func:`theta_stars`, :func:`initial_states`, :func:`disturbances`, :func:`online_options`;
* :func:`closed_loop_cases` -> :class:`~amcp_properties.cases.Case`, everything for one run.
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter, OrderedDict
from dataclasses import dataclass, field

import numpy as np
from hypothesis import event, reject
from hypothesis import strategies as st

from amcp_drake.model.errors import DesignError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec
from amcp_drake.model.problem_io import spec_to_dict
from amcp_drake.offline.design import OfflineDesign, design
from amcp_drake.online.simulate import disturbance_sequence

from .cases import Case
from .feasible import TubeGeometry, max_ray_length

#: Initial states "on" the boundary of the feasible set of (20) are placed at this fraction of
#: the LP's maximal ray length: HiGHS' primal feasibility tolerance is 1e-7 (absolute), so the LP
#: optimum may overshoot the true boundary by ~1e-7; backing off by 1e-5 (relative, for ray
#: lengths of order 1-10) keeps the point inside for the backends' QPs (Clarabel, 1e-8) while it
#: is still on the boundary for every practical purpose.
BOUNDARY_BACKOFF = 1e-5
#: Offline designs kept in memory (a design costs 0.1-2 s; the same problems recur across tests
#: because every test of the ci profile uses the same seed).
DESIGN_CACHE_SIZE = 256
#: The offline design of every generated case uses this backend; both online backends then run
#: on the same design (so that they can be compared, and the boundary LP refers to one design).
DESIGN_BACKEND = "drake"


class GeneratorStats:
    """Counts of generator outcomes (attempts, accepted, rejections by reason)."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        self.messages: list[str] = []
        self.distinct: dict[str, str] = {}  # problem digest -> "accepted" or the rejection reason

    def outcome(self, digest: str, result: str) -> None:
        self.distinct[digest] = result

    def distinct_rejection_rate(self) -> float:
        """Rejected / all distinct generated problems (each problem counted once)."""
        if not self.distinct:
            return float("nan")
        return sum(v != "accepted" for v in self.distinct.values()) / len(self.distinct)

    def add(self, key: str) -> None:
        self.counts[key] += 1

    @property
    def attempts(self) -> int:
        return self.counts["design attempts"]

    @property
    def rejections(self) -> int:
        return sum(v for k, v in self.counts.items() if k.startswith("rejected:"))

    def rejection_rate(self) -> float:
        """Rejected designs / design attempts (nan before any attempt)."""
        return self.rejections / self.attempts if self.attempts else float("nan")


#: Generator statistics of this process (read by the suite summary).
GENERATOR_STATS = GeneratorStats()


def _grid(lo: float, hi: float, step: float) -> st.SearchStrategy[float]:
    """Floats on the grid {lo, lo+step, ..., hi}; shrinks towards the grid point nearest 0."""
    return st.integers(int(round(lo / step)), int(round(hi / step))).map(lambda i: round(i * step, 10))


def _matrix(draw, rows: int, cols: int, lo: float = -1.0, hi: float = 1.0, step: float = 0.05) -> np.ndarray:
    values = draw(st.lists(_grid(lo, hi, step), min_size=rows * cols, max_size=rows * cols))
    return np.array(values, float).reshape(rows, cols)


def _unit(draw, dim: int) -> np.ndarray:
    """A unit vector from a grid vector (e_1 when the grid vector is zero)."""
    vec = _matrix(draw, 1, dim, -1.0, 1.0, 0.1)[0]
    norm = np.linalg.norm(vec)
    if norm == 0.0:
        vec = np.zeros(dim)
        vec[0] = 1.0
        return vec
    return vec / norm


def _scaled(M: np.ndarray, size: float, fallback: np.ndarray, norm=2) -> np.ndarray:
    """M rescaled to induced ``norm`` (2: spectral, inf: max row sum) ``size`` (``fallback`` when M is zero)."""
    s = np.linalg.norm(M, norm)
    return size * (M / s if s > 0 else fallback)


def _box_with_cuts(draw, lower: np.ndarray, upper: np.ndarray, polytope: bool) -> tuple[np.ndarray, np.ndarray]:
    """{lower <= x <= upper} (lower < 0 < upper), intersected with 1-3 random half-spaces
    a·x <= b, b = fraction · (support of the box along a) > 0, when ``polytope``: a general
    polytope that keeps 0 in its interior."""
    dim = len(lower)
    H = np.vstack([np.eye(dim), -np.eye(dim)])
    h = np.concatenate([upper, -lower])
    if polytope:
        for _ in range(draw(st.integers(1, 3))):
            a = _unit(draw, dim)
            support = float(np.sum(np.where(a > 0, a * upper, a * lower)))
            H = np.vstack([H, a])
            h = np.append(h, draw(_grid(0.3, 0.9, 0.05)) * support)
    return H, h


@dataclass(frozen=True, eq=False)
class GeneratedProblem:
    """A problem with its design options and the generator's labels (for coverage)."""

    spec: ProblemSpec
    labels: dict = field(default_factory=dict)

    @property
    def problem(self) -> Problem:
        return self.spec.problem


@dataclass(frozen=True, eq=False)
class DesignedProblem(GeneratedProblem):
    """A generated problem with its offline design (K, P, X0, X_f, μ, ...)."""

    design: OfflineDesign | None = None


@st.composite
def problem_specs(draw, max_n: int = 3, max_m: int = 2, max_p: int = 3, min_N: int = 2, max_N: int = 10,
                  delta_range: tuple[float, float] = (0.01, 0.12)):
    """Random uncertain systems meeting Assumption 1, with a Z that binds.

    * A0 = ρ M/‖M‖∞ with ρ ∈ [0.2, 0.95], or (two booleans) ρ ∈ [1.02, 1.12], open-loop unstable
      for sure when M is shifted by ‖M‖₂ I (a third boolean). The ∞-norm (max row sum) keeps the
      template iteration of X0 convergent: scaled by the spectral norm instead, 13 % of the
      problems were rejected (X0 templates diverging for n = 3), with the ∞-norm 0 % of 300;
      B0 of norm 0.3-1; ‖[A_i B_i]‖₂ = δ/p with δ ∈ ``delta_range`` (default [0.01, 0.12], so the
      robust LMI is feasible; larger δ make the parametric uncertainty dominate W, at the price of
      more designs rejected).
    * Θ: a box lo < 0 < hi, or (boolean) the box cut by 1-3 random half-spaces; H_θ rows kept as drawn.
    * W: a box with half-widths 0.005-0.06 (asymmetric), or (boolean) such a box with cuts.
    * Z: a state box |x_i| within 1-4 and an input box within 0.3-2 (saturation is the binding
      constraint from boundary initial states), plus (boolean) one mixed row a·x + g·u <= 1.
    """
    n = draw(st.integers(1, max_n))
    m = draw(st.integers(1, max_m))
    p = draw(st.integers(1, max_p))
    N = draw(st.integers(min_N, max_N))
    labels: dict[str, str] = {"n": str(n), "m": str(m), "p": str(p), "N": str(N)}

    expansive = draw(st.booleans()) and draw(st.booleans())
    rho = draw(_grid(1.02, 1.12, 0.02)) if expansive else draw(_grid(0.2, 0.95, 0.05))
    M = _matrix(draw, n, n)
    if expansive and draw(st.booleans()):  # a real unstable mode for sure: M + its norm times I
        M = M + np.linalg.norm(M, 2) * np.eye(n)
    A0 = _scaled(M, rho, np.eye(n), norm=np.inf)
    labels["open loop"] = "unstable" if np.max(np.abs(np.linalg.eigvals(A0))) >= 1.0 else "stable"
    e11 = np.zeros((n, m))
    e11[0, 0] = 1.0
    B0 = _scaled(_matrix(draw, n, m), draw(_grid(0.3, 1.0, 0.05)), e11)

    delta = draw(_grid(delta_range[0], delta_range[1], 0.01))
    A_list, B_list = [], []
    for _ in range(p):
        AB = _matrix(draw, n, n + m)
        fallback = np.zeros((n, n + m))
        fallback[0, 0] = 1.0
        AB = _scaled(AB, delta / p, fallback)
        A_list.append(AB[:, :n])
        B_list.append(AB[:, n:])

    theta_poly = draw(st.booleans())
    lo = -np.array([draw(_grid(0.2, 1.5, 0.1)) for _ in range(p)])
    hi = np.array([draw(_grid(0.2, 1.5, 0.1)) for _ in range(p)])
    H_theta, h_theta = _box_with_cuts(draw, lo, hi, theta_poly)
    labels["Theta"] = "polytope" if theta_poly else "box"

    w_poly = draw(st.booleans())
    w_lo = -np.array([draw(_grid(0.005, 0.06, 0.005)) for _ in range(n)])
    w_hi = np.array([draw(_grid(0.005, 0.06, 0.005)) for _ in range(n)])
    H_w, h_w = _box_with_cuts(draw, w_lo, w_hi, w_poly)
    H_w = H_w / h_w[:, None]  # W = {H_w w <= 1}
    labels["W"] = "polytope" if w_poly else "box"

    x_up = np.array([draw(_grid(1.0, 4.0, 0.5)) for _ in range(n)])
    x_lo = np.array([draw(_grid(1.0, 4.0, 0.5)) for _ in range(n)])
    u_up = np.array([draw(_grid(0.3, 2.0, 0.1)) for _ in range(m)])
    u_lo = np.array([draw(_grid(0.3, 2.0, 0.1)) for _ in range(m)])
    F = np.vstack([np.eye(n) / x_up[:, None], -np.eye(n) / x_lo[:, None], np.zeros((2 * m, n))])
    G = np.vstack([np.zeros((2 * n, m)), np.eye(m) / u_up[:, None], -np.eye(m) / u_lo[:, None]])
    if draw(st.booleans()):
        row = _unit(draw, n + m) / draw(_grid(0.5, 2.0, 0.25))
        F = np.vstack([F, row[:n]])
        G = np.vstack([G, row[n:]])
        labels["Z"] = "box + mixed row"
    else:
        labels["Z"] = "box"

    Q = np.diag([draw(_grid(0.2, 2.0, 0.1)) for _ in range(n)])
    if draw(st.booleans()):
        L = _matrix(draw, n, n, -0.5, 0.5, 0.1)
        Q = Q + L @ L.T
    R = np.diag([draw(_grid(0.05, 2.0, 0.05)) for _ in range(m)])

    theta_hat0 = np.zeros(p)
    if draw(st.booleans()):  # θ̂0 = λ·(point on the boundary along a grid direction) ∈ Θ
        d = _unit(draw, p)
        theta_hat0 = draw(_grid(0.0, 1.0, 0.1)) * _ray_to_boundary(H_theta, h_theta, d) * d
        labels["theta_hat0"] = "off-centre"
    else:
        labels["theta_hat0"] = "0"

    problem = Problem(A0=A0, B0=B0, A=np.array(A_list), B=np.array(B_list), H_w=H_w, H_theta=H_theta,
                      h_theta=h_theta, F=F, G=G, Q=Q, R=R, N=N, theta_hat0=theta_hat0, name="generated")
    facets = {1: (2,), 2: (4, 6, 8), 3: (6,)}[n]
    options = DesignOptions(x0_template="mrpi", x0_facets=draw(st.sampled_from(facets)),
                            centre_dynamics=draw(st.sampled_from(("nominal", "zero"))),
                            mu_fraction=draw(_grid(0.5, 0.99, 0.01)))
    return GeneratedProblem(ProblemSpec(problem, options), labels)


def _ray_to_boundary(H: np.ndarray, h: np.ndarray, d: np.ndarray) -> float:
    """max{t >= 0 | H (t d) <= h} for a set with 0 in its interior (closed form, no LP)."""
    rates = H @ d
    positive = rates > 1e-12
    return float(np.min(h[positive] / rates[positive])) if np.any(positive) else 0.0


def spec_digest(spec: ProblemSpec) -> str:
    """A stable hash of a problem file's content (cache key)."""
    return hashlib.sha1(json.dumps(spec_to_dict(spec), sort_keys=True).encode()).hexdigest()


class _DesignCache:
    """LRU cache of offline designs by problem-file content; failures are cached too."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.items: OrderedDict[str, OfflineDesign | DesignError] = OrderedDict()

    def get(self, spec: ProblemSpec) -> OfflineDesign:
        key = spec_digest(spec)
        if key not in self.items:
            try:
                self.items[key] = design(spec.problem, spec.design, backend=DESIGN_BACKEND)
            except DesignError as exc:
                self.items[key] = exc
            if len(self.items) > self.size:
                self.items.popitem(last=False)
        self.items.move_to_end(key)
        value = self.items[key]
        if isinstance(value, DesignError):
            raise value
        return value


DESIGNS = _DesignCache(DESIGN_CACHE_SIZE)


@st.composite
def designed_problems(draw, **kwargs):
    """:func:`problem_specs` plus the offline design; a DesignError is a counted rejection."""
    gen = draw(problem_specs(**kwargs))
    GENERATOR_STATS.add("design attempts")
    digest = spec_digest(gen.spec)
    try:
        d = DESIGNS.get(gen.spec)
    except DesignError as exc:
        reason = type(exc).__name__
        GENERATOR_STATS.add(f"rejected: {reason}")
        GENERATOR_STATS.outcome(digest, reason)
        if len(GENERATOR_STATS.messages) < 100:
            GENERATOR_STATS.messages.append(str(exc))
        event(f"generator: design rejected ({reason})")
        reject()
    GENERATOR_STATS.add("accepted")
    GENERATOR_STATS.outcome(digest, "accepted")
    return DesignedProblem(gen.spec, gen.labels, d)


@st.composite
def theta_stars(draw, problem: Problem):
    """θ* ∈ Θ: a vertex or a boundary point (two booleans: 25 % each) or an interior point."""
    H, h = problem.H_theta, problem.h_theta
    if draw(st.booleans()):
        if draw(st.booleans()):
            verts = problem.theta_vertices()
            return verts[draw(st.integers(0, len(verts) - 1))], "vertex"
        d = _unit(draw, problem.p)
        return _ray_to_boundary(H, h, d) * d, "boundary"
    d = _unit(draw, problem.p)
    return draw(_grid(0.0, 0.95, 0.05)) * _ray_to_boundary(H, h, d) * d, "interior"


@st.composite
def initial_states(draw, problem: Problem, offline: OfflineDesign):
    """x0 on the boundary of {x | 𝔻(x, Θ0) ≠ ∅} (boolean), near it (90-99.5 % of the way), or
    (two more booleans) in the interior, found by the vertex-form LP of
    :mod:`amcp_properties.feasible` along a random ray from 0 (no luck involved)."""
    d = _unit(draw, problem.n)
    geo = TubeGeometry.build(problem, offline, offline.theta_vertices)
    s_max = max_ray_length(geo, d)
    if not np.isfinite(s_max) or s_max <= 0.0:
        GENERATOR_STATS.add("rejected: boundary LP")
        event("generator: boundary LP failed")
        reject()
    if not draw(st.booleans()):  # (False is what the shrinker moves towards: the boundary)
        return (1.0 - BOUNDARY_BACKOFF) * s_max * d, "boundary", s_max
    if draw(st.booleans()) and draw(st.booleans()):
        return draw(_grid(0.1, 0.9, 0.05)) * s_max * d, "interior", s_max
    return draw(_grid(0.9, 0.995, 0.005)) * s_max * d, "near boundary", s_max


def disturbance_kinds() -> st.SearchStrategy[str]:
    """Vertices of W first (the nastiest, and what shrinking moves towards), uniform, zero."""
    return st.sampled_from(("vertices", "uniform", "zero"))


@st.composite
def disturbances(draw, problem: Problem, steps: int, kinds: st.SearchStrategy[str] | None = None,
                 zero_from: int | None = None):
    """w_0..w_{steps-1}: i.i.d. uniform on W, on the vertices of W, or zero (explicit seed);
    zero from step ``zero_from`` on when given (Corollary 16)."""
    kind = draw(kinds if kinds is not None else disturbance_kinds())
    seed = draw(st.integers(0, 2**32 - 1))
    w = disturbance_sequence(problem, kind, steps, seed)
    if zero_from is not None:
        w = w.copy()
        w[zero_from:] = 0.0
    return w, kind, seed


def online_options() -> st.SearchStrategy[OnlineOptions]:
    """(9) fixed complexity or moving window (Remark 4); projection onto Θ (12) or Θ_k (Remark 7)."""
    return st.builds(OnlineOptions, update=st.sampled_from(("fixed", "window")), window=st.integers(1, 10),
                     projection=st.sampled_from(("Theta", "Theta_k")))


@st.composite
def closed_loop_cases(draw, steps: int, kinds: st.SearchStrategy[str] | None = None,
                      zero_after: st.SearchStrategy[int] | None = None, **problem_kwargs):
    """Everything for one closed-loop run: a designed problem, θ*, x0, w, online options.

    ``zero_after``: a strategy for the step after which w = 0 (Corollary 16, finite energy).
    """
    gen = draw(designed_problems(**problem_kwargs))
    problem = gen.problem
    theta_star, theta_kind = draw(theta_stars(problem))
    x0, x0_kind, s_max = draw(initial_states(problem, gen.design))
    zero_from = draw(zero_after) if zero_after is not None else None
    w, w_kind, seed = draw(disturbances(problem, steps, kinds, zero_from))
    options = draw(online_options())
    labels = dict(gen.labels, theta_star=theta_kind, x0=x0_kind, disturbance=w_kind,
                  update=options.update, projection=options.projection)
    return Case(spec=gen.spec, design=gen.design, x0=x0, theta_star=theta_star, w=w, options=options,
                labels=labels, seed=seed, zero_from=zero_from, ray_length=s_max)
