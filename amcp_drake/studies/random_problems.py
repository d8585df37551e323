"""Random uncertain systems and closed-loop scenarios meeting the paper's assumptions, drawn with
plain numpy from an explicit :class:`numpy.random.Generator` (campaigns and benchmarks
draw here; the Hypothesis strategies of ``amcp_properties`` draw the *structure* — dimensions and
flags, :class:`ProblemShape` and the scenario kinds — and call these functions for the numbers).

Every problem meets Assumption 1 by construction (W and Θ bounded polytopes, 0 in the interior
of W, θ̂0 and θ* in Θ); Assumptions 8 and 11 and (16) come from the offline design, which can still
fail (:class:`~amcp_drake.model.errors.DesignError`): :func:`random_case` then draws again from the same
generator, so a campaign stays a deterministic function of its (seed, index).

Numbers sit on coarse grids (:func:`grid`) so that problems print readably.
Any change that alters what a given generator state draws must bump ``GENERATOR_VERSION`` in
:mod:`amcp_drake.studies.campaign` (stores made with other draws are then never resumed).

The hard cases are *built*, behind explicit parameters, never filtered for:

* θ* at a vertex of Θ, on a facet (the ray from 0 to ∂Θ), or inside (:func:`random_theta_star`);
* disturbances at the vertices of W (``"vertices"``), uniform on W, or zero;
* **pinning** (:mod:`amcp_drake.studies.pinning`): the first disturbance w_0 is the vertex of W
  that, with θ* on ∂Θ, makes Θ_1 = Θ ∩ Δ_1 collapse to {θ*} (θ* a vertex) or into the facet's
  hyperplane, or (``"thin"``) leaves it thinner than the solvers' tolerances; for p <= n, where
  the first regressor D(x_0, u_0) has full column rank. With input uncertainty u_0 is the
  controller's first input (generator version 5; before, only problems with B_i = 0 were pinned);
* very active constraints: x_0 on the boundary of the feasible set of (20) (an LP along a random
  ray, :mod:`amcp_drake.studies.tube_feasibility`), and ``tight_state_box`` (state bounds of 0.5-1.5
  instead of 1-4, so state rows of Z bind together with the input rows).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from amcp_drake.model import polytope
from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec, Scenario
from amcp_drake.model.state_units import scale_states
from amcp_drake.offline.design import OfflineDesign, design
from amcp_drake.online.controller import DELTA_MARGIN
from amcp_drake.online.simulate import disturbance_sequence
from amcp_drake.studies.pinning import active_theta_rows, pin_first_disturbance
from amcp_drake.studies.tube_feasibility import TubeGeometry, max_ray_length

#: Initial states "on" the boundary of the feasible set of (20) are placed at this fraction of
#: the LP's maximal ray length: HiGHS' primal feasibility tolerance is 1e-7 (absolute), so the LP
#: optimum may overshoot the true boundary by ~1e-7; backing off by 1e-5 (relative, for ray
#: lengths of order 1-10) keeps the point inside for the backends' QPs (Clarabel, 1e-8) while it
#: is still on the boundary for every practical purpose.
BOUNDARY_BACKOFF = 1e-5
#: A campaign draws at most this many problems per index before giving up (the offline design
#: rejects about 1 in 10 generated problems; 20 failures in a row mean a broken generator).
MAX_DESIGN_ATTEMPTS = 20
#: The offline design of every generated case uses this backend; both online backends then run on
#: the same design (so that they can be compared, and the boundary LP refers to one design).
DESIGN_BACKEND = "drake"

THETA_STAR_KINDS = ("vertex", "facet", "interior")
INITIAL_STATE_KINDS = ("boundary", "near boundary", "interior")
DISTURBANCE_KINDS = ("vertices", "uniform", "zero")


# -- numbers on grids ------------------------------------------------------------------------------


def grid(rng: np.random.Generator, lo: float, hi: float, step: float) -> float:
    """A float uniform on the grid {lo, lo+step, ..., hi}."""
    return round(int(rng.integers(round(lo / step), round(hi / step) + 1)) * step, 10)


def grid_matrix(rng: np.random.Generator, rows: int, cols: int, lo: float = -1.0, hi: float = 1.0,
                step: float = 0.05) -> np.ndarray:
    """A (rows, cols) matrix of independent :func:`grid` entries."""
    ints = rng.integers(round(lo / step), round(hi / step) + 1, size=(rows, cols))
    return np.round(ints * step, 10)


def unit_vector(rng: np.random.Generator, dim: int) -> np.ndarray:
    """A unit vector from a grid vector of step 0.1 (e_1 when the grid vector is zero)."""
    vec = grid_matrix(rng, 1, dim, -1.0, 1.0, 0.1)[0]
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


def ray_to_boundary(H: np.ndarray, h: np.ndarray, d: np.ndarray) -> float:
    """max{t >= 0 | H (t d) <= h} for a set with 0 in its interior (closed form, no LP)."""
    rates = H @ d
    positive = rates > 1e-12
    return float(np.min(h[positive] / rates[positive])) if np.any(positive) else 0.0


def _box_with_cuts(rng: np.random.Generator, lower: np.ndarray, upper: np.ndarray,
                   cuts: bool) -> tuple[np.ndarray, np.ndarray]:
    """{lower <= x <= upper} (lower < 0 < upper), intersected with 1-3 random half-spaces
    a·x <= b, b = fraction · (support of the box along a) > 0, when ``cuts``: a general polytope
    that keeps 0 in its interior."""
    dim = len(lower)
    H = np.vstack([np.eye(dim), -np.eye(dim)])
    h = np.concatenate([upper, -lower])
    if cuts:
        for _ in range(int(rng.integers(1, 4))):
            a = unit_vector(rng, dim)
            support = float(np.sum(np.where(a > 0, a * upper, a * lower)))
            H = np.vstack([H, a])
            h = np.append(h, grid(rng, 0.3, 0.9, 0.05) * support)
    return H, h


# -- problems --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ProblemShape:
    """The structure of a random problem: dimensions and flags (what a Hypothesis strategy draws
    and shrinks); :func:`random_problem` draws the numbers.

    * ``expansive``: ρ = ‖A0‖∞ in [1.02, 1.12] instead of [0.2, 0.95]; ``unstable_mode`` (with
      ``expansive``): A0's template M is shifted by ‖M‖₂ I, a real unstable mode for sure.
    * ``theta_cuts`` / ``w_cuts``: Θ / W is a box cut by 1-3 random half-spaces instead of a box.
    * ``mixed_row``: Z has a row a·x + g·u <= 1 besides its state and input boxes.
    * ``tight_state_box``: state bounds 0.5-1.5 instead of 1-4 (state and input rows bind together).
    * ``coupled_Q``: Q = diag + L Lᵀ instead of diagonal.
    * ``theta_hat0_off_centre``: θ̂0 on a ray towards ∂Θ instead of 0.
    * ``input_uncertainty``: B_i drawn like A_i; False: B_i = 0, so D(x, u) = D(x).
    * ``zero_centre``: the tube centre dynamics A_z of docs/explanation/paper.md §5 is 0 instead of A_cl(θ̂0).
    * ``delta_range``: range of δ = p·‖[A_i B_i]‖₂ (the size of the parametric uncertainty).
    * ``scaled_states``: the problem is written in the state coordinates x̃ = T x, T = diag(10^s_i),
      s_i drawn from :data:`STATE_SCALE_EXPONENTS` (not all 0): the same system in badly scaled
      units (:func:`scale_states`).
    """

    n: int = 2
    m: int = 1
    p: int = 2
    N: int = 5
    expansive: bool = False
    unstable_mode: bool = False
    theta_cuts: bool = False
    w_cuts: bool = False
    mixed_row: bool = False
    tight_state_box: bool = False
    coupled_Q: bool = False
    theta_hat0_off_centre: bool = False
    input_uncertainty: bool = True
    zero_centre: bool = False
    delta_range: tuple[float, float] = (0.01, 0.12)
    scaled_states: bool = False

    def __post_init__(self) -> None:
        for name in ("n", "m", "p", "N"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ProblemError(f"shape.{name}", "an integer >= 1", repr(value))
        lo, hi = self.delta_range
        if not 0.0 < lo <= hi:
            raise ProblemError("shape.delta_range", "0 < low <= high", repr(self.delta_range))

    @property
    def can_pin(self) -> bool:
        """Pinning needs the first regressor D(x_0, u_0) (n, p) of full column rank: p <= n
        (with input uncertainty u_0 is the controller's first input, :mod:`~amcp_drake.studies.pinning`)."""
        return self.p <= self.n


def random_shape(rng: np.random.Generator, max_n: int = 3, max_m: int = 2, max_p: int = 3, min_N: int = 2,
                 max_N: int = 10, min_p: int = 1, min_n: int = 1) -> ProblemShape:
    """A :class:`ProblemShape` with the probabilities of the Hypothesis strategy
    ``amcp_properties.strategies.problem_shapes`` (one boolean: 1/2; two: 1/4); n uniform on
    ``min_n`` … ``max_n`` (the default 1 … 3 draws what it always drew)."""
    if not 1 <= min_n <= max_n:
        raise ProblemError("state dimensions", "1 <= min_n <= max_n", f"{min_n}..{max_n}")
    coin = lambda: bool(rng.integers(2))  # a fair coin, read like draw(booleans())
    n = int(rng.integers(min_n, max_n + 1))
    m = int(rng.integers(1, max_m + 1))
    input_uncertainty = coin()
    low_p = min(min_p, max_p)
    p = int(rng.integers(low_p, max(low_p, max_p if input_uncertainty else min(max_p, n)) + 1))
    N = int(rng.integers(min_N, max_N + 1))
    expansive = coin() and coin()
    return ProblemShape(n=n, m=m, p=p, N=N, expansive=expansive, unstable_mode=expansive and coin(),
                        theta_cuts=coin(), w_cuts=coin(), mixed_row=coin(), tight_state_box=coin() and coin(),
                        coupled_Q=coin(), theta_hat0_off_centre=coin(), input_uncertainty=input_uncertainty,
                        zero_centre=coin(), scaled_states=coin() and coin())


def random_problem(rng: np.random.Generator, shape: ProblemShape) -> tuple[ProblemSpec, dict[str, str]]:
    """A problem of the given shape meeting Assumption 1, with its design options and labels.

    * A0 = ρ M/‖M‖∞ (the ∞-norm keeps the template iteration of X0 convergent: scaled by the
      spectral norm instead, 13 % of the problems were rejected for n = 3, with the ∞-norm 0 % of
      300); B0 of norm 0.3-1; ‖[A_i B_i]‖₂ = δ/p with δ drawn from ``shape.delta_range``.
    * Θ: a box lo < 0 < hi (half-widths 0.2-1.5), cut or not; W: a box with half-widths
      0.005-0.06 (asymmetric), cut or not, as {H_w w <= 1}.
    * Z: a state box within 1-4 (0.5-1.5 when tight) and an input box within 0.3-2.
    * ``shape.scaled_states``: all of the above in unit-sized coordinates, then rewritten in
      x̃ = T x (:func:`scale_states`); the exponents are drawn last, so the unscaled numbers are those
      of the same seed without the flag.
    """
    n, m, p = shape.n, shape.m, shape.p
    labels = {"n": str(n), "m": str(m), "p": str(p), "N": str(shape.N)}

    rho = grid(rng, 1.02, 1.12, 0.02) if shape.expansive else grid(rng, 0.2, 0.95, 0.05)
    M = grid_matrix(rng, n, n)
    if shape.expansive and shape.unstable_mode:
        M = M + np.linalg.norm(M, 2) * np.eye(n)
    A0 = _scaled(M, rho, np.eye(n), norm=np.inf)
    labels["open loop"] = "unstable" if np.max(np.abs(np.linalg.eigvals(A0))) >= 1.0 else "stable"
    e11 = np.zeros((n, m))
    e11[0, 0] = 1.0
    B0 = _scaled(grid_matrix(rng, n, m), grid(rng, 0.3, 1.0, 0.05), e11)

    delta = grid(rng, shape.delta_range[0], shape.delta_range[1], 0.01)
    A_list, B_list = [], []
    cols = n + m if shape.input_uncertainty else n
    for _ in range(p):
        fallback = np.zeros((n, cols))
        fallback[0, 0] = 1.0
        AB = _scaled(grid_matrix(rng, n, cols), delta / p, fallback)
        A_list.append(AB[:, :n])
        B_list.append(AB[:, n:] if shape.input_uncertainty else np.zeros((n, m)))
    labels["uncertainty"] = "A and B" if shape.input_uncertainty else "A only"

    lo = -np.array([grid(rng, 0.2, 1.5, 0.1) for _ in range(p)])
    hi = np.array([grid(rng, 0.2, 1.5, 0.1) for _ in range(p)])
    H_theta, h_theta = _box_with_cuts(rng, lo, hi, shape.theta_cuts)
    labels["Theta"] = "polytope" if shape.theta_cuts else "box"

    w_lo = -np.array([grid(rng, 0.005, 0.06, 0.005) for _ in range(n)])
    w_hi = np.array([grid(rng, 0.005, 0.06, 0.005) for _ in range(n)])
    H_w, h_w = _box_with_cuts(rng, w_lo, w_hi, shape.w_cuts)
    H_w = H_w / h_w[:, None]  # W = {H_w w <= 1}
    labels["W"] = "polytope" if shape.w_cuts else "box"

    x_range = (0.5, 1.5) if shape.tight_state_box else (1.0, 4.0)
    x_up = np.array([grid(rng, *x_range, 0.5) for _ in range(n)])
    x_lo = np.array([grid(rng, *x_range, 0.5) for _ in range(n)])
    u_up = np.array([grid(rng, 0.3, 2.0, 0.1) for _ in range(m)])
    u_lo = np.array([grid(rng, 0.3, 2.0, 0.1) for _ in range(m)])
    F = np.vstack([np.eye(n) / x_up[:, None], -np.eye(n) / x_lo[:, None], np.zeros((2 * m, n))])
    G = np.vstack([np.zeros((2 * n, m)), np.eye(m) / u_up[:, None], -np.eye(m) / u_lo[:, None]])
    if shape.mixed_row:
        row = unit_vector(rng, n + m) / grid(rng, 0.5, 2.0, 0.25)
        F = np.vstack([F, row[:n]])
        G = np.vstack([G, row[n:]])
    labels["Z"] = ("tight box" if shape.tight_state_box else "box") + (" + mixed row" if shape.mixed_row else "")

    Q = np.diag([grid(rng, 0.2, 2.0, 0.1) for _ in range(n)])
    if shape.coupled_Q:
        L = grid_matrix(rng, n, n, -0.5, 0.5, 0.1)
        Q = Q + L @ L.T
    R = np.diag([grid(rng, 0.05, 2.0, 0.05) for _ in range(m)])

    theta_hat0 = np.zeros(p)
    if shape.theta_hat0_off_centre:  # θ̂0 = λ·(point on ∂Θ along a grid direction) ∈ Θ
        d = unit_vector(rng, p)
        theta_hat0 = grid(rng, 0.0, 1.0, 0.1) * ray_to_boundary(H_theta, h_theta, d) * d
    labels["theta_hat0"] = "off-centre" if shape.theta_hat0_off_centre else "0"

    problem = Problem(A0=A0, B0=B0, A=np.array(A_list), B=np.array(B_list), H_w=H_w, H_theta=H_theta,
                      h_theta=h_theta, F=F, G=G, Q=Q, R=R, N=shape.N, theta_hat0=theta_hat0, name="generated")
    # the mrpi template the facet count is drawn for, up to n = 3; from n = AUTO_TEMPLATE_N on the automatic
    # design (bounded-complexity templates first; the fixed mrpi directions rarely fit the closed loop
    # there). The facet draw is made either way, so the later draws of a seed do not depend on n.
    facets = {1: (2,), 2: (4, 6, 8), 3: (6,)}.get(n, (2 * n,))
    drawn_facets = int(facets[rng.integers(len(facets))])
    template = ({"x0_template": "auto", "x0_facets": None} if n >= AUTO_TEMPLATE_N
                else {"x0_template": "mrpi", "x0_facets": drawn_facets})
    options = DesignOptions(**template, centre_dynamics="zero" if shape.zero_centre else "nominal",
                            mu_fraction=grid(rng, 0.5, 0.99, 0.01))
    labels["state scaling"] = UNSCALED
    if shape.scaled_states:
        exponents = rng.choice(STATE_SCALE_EXPONENTS, size=n)
        if not np.any(exponents):
            exponents[0] = STATE_SCALE_EXPONENTS[-1]
        problem = scale_states(problem, 10.0 ** exponents)
        labels["state scaling"] = ", ".join(f"1e{int(e)}" for e in exponents)
    return ProblemSpec(problem, options), labels


#: From this state dimension on, generated problems use the automatic design (``x0_template = "auto"``):
#: every fixed mrpi template of 2n facets diverged on the generated systems with n = 4 … 6 measured,
#: the automatic order (parallelotope and contractive templates first from n = 4) designs them.
AUTO_TEMPLATE_N = 4
#: The state dimensions drawn by default (campaigns without ``--state-dims``, the property suite's ci profile).
DEFAULT_STATE_DIMS = (1, 3)
#: The largest state dimension a campaign or the property suite may draw.
MAX_STATE_DIM = 8

#: Exponents e of the state scales 10^e of ``ProblemShape.scaled_states`` (units from 1/100 to 100 of
#: the drawn ones: a position in m next to a velocity in cm/s is a factor 100).
STATE_SCALE_EXPONENTS = (-2, -1, 0, 1, 2)
#: The "state scaling" label of a problem in the units it was drawn in.
UNSCALED = "1"


def built_scaled(labels: dict) -> bool | None:
    """Whether a generated problem was built in badly scaled state units (its "state scaling" label;
    exact, since the scaling is what was built); None for labels without it (not a generated problem)."""
    return None if "state scaling" not in labels else labels["state scaling"] != UNSCALED


# -- scenario pieces -------------------------------------------------------------------------------


def random_theta_star(rng: np.random.Generator, problem: Problem, kind: str) -> np.ndarray:
    """θ* ∈ Θ: a vertex of Θ (uniform over the vertices), a point on a facet (the ray from 0 along
    a random grid direction to ∂Θ), or an interior point (0-95 % of that ray)."""
    if kind not in THETA_STAR_KINDS:
        raise ProblemError("theta_star kind", f"one of {THETA_STAR_KINDS}", repr(kind))
    H, h = problem.H_theta, problem.h_theta
    if kind == "vertex":
        verts = problem.theta_vertices()
        return verts[int(rng.integers(len(verts)))]
    d = unit_vector(rng, problem.p)
    scale = 1.0 if kind == "facet" else grid(rng, 0.0, 0.95, 0.05)
    return scale * ray_to_boundary(H, h, d) * d


class GenerationError(DesignError):
    """The generator could not build a scenario for a designed problem (the boundary LP failed)."""


def random_initial_state(rng: np.random.Generator, problem: Problem, offline: OfflineDesign,
                         kind: str) -> tuple[np.ndarray, float]:
    """x_0 on the boundary of {x | 𝔻(x, Θ_0) ≠ ∅} (less :data:`BOUNDARY_BACKOFF`), near it
    (90-99.5 % of the way) or inside (10-90 %), along a random ray from 0; returns (x_0, ray length).
    The ray length is an LP of :mod:`amcp_drake.studies.tube_feasibility` (no luck involved)."""
    if kind not in INITIAL_STATE_KINDS:
        raise ProblemError("x0 kind", f"one of {INITIAL_STATE_KINDS}", repr(kind))
    d = unit_vector(rng, problem.n)
    geo = TubeGeometry.build(problem, offline, offline.theta_vertices)
    # from n = AUTO_TEMPLATE_N on with the exact row maxima over X0's vertices (tube_feasibility): the
    # rows at every vertex do not fit in memory there; below, the LP as it always was (the same draws)
    s_max = max_ray_length(geo, d, row_maxima=problem.n >= AUTO_TEMPLATE_N)
    if not np.isfinite(s_max) or s_max <= 0.0:
        raise GenerationError(f"boundary LP along {d} returned {s_max}")
    fraction = {"boundary": lambda: 1.0 - BOUNDARY_BACKOFF, "near boundary": lambda: grid(rng, 0.9, 0.995, 0.005),
                "interior": lambda: grid(rng, 0.1, 0.9, 0.05)}[kind]()
    return fraction * s_max * d, s_max


def random_disturbances(rng: np.random.Generator, problem: Problem, steps: int, kind: str,
                        zero_from: int | None = None) -> tuple[np.ndarray, int]:
    """w_0..w_{steps-1} of a kind of :func:`~amcp_drake.online.simulate.disturbance_sequence` (i.i.d. on
    the vertices of W, uniform on W, or zero) with a seed drawn from ``rng``, zero from
    ``zero_from`` on (Corollary 16); returns (w, seed) so that a problem file can name the seed."""
    if kind not in DISTURBANCE_KINDS:
        raise ProblemError("disturbance kind", f"one of {DISTURBANCE_KINDS}", repr(kind))
    seed = int(rng.integers(2**31))
    w = disturbance_sequence(problem, kind, steps, seed)
    if zero_from is not None:
        w = w.copy()
        w[zero_from:] = 0.0
    return w, seed


#: The set updates drawn, equally likely: (9) and the moving window twice each, the exact update (7)
#: once (1/5 of the runs). Steps of (7) cost ~10x those of (9) (the redundancy LPs
#: and, in the plain form, a program with every row of its own H_θk): with 1/3 of the runs the ci
#: property profile took 585 s of CPU instead of 263 s (measured on one machine at the same load, with
#: an exact update slower than today's; docs/decisions.md).
UPDATE_DRAWS = ("fixed", "window", "fixed", "window", "exact")


def random_online_options(rng: np.random.Generator) -> OnlineOptions:
    """A set update of :data:`UPDATE_DRAWS` (as ``amcp_properties.strategies.online_options``; (7)
    from generator version 2 on), a moving window of 1-10 (Remark 4), projection onto Θ (12)
    or Θ_k (Remark 7). The last draws of :func:`random_case`: the problems and scenarios of a seed are
    those of version 1."""
    return OnlineOptions(update=UPDATE_DRAWS[int(rng.integers(len(UPDATE_DRAWS)))], window=int(rng.integers(1, 11)),
                         projection=("Theta", "Theta_k")[int(rng.integers(2))])


# -- a whole case ----------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RandomCase:
    """One closed-loop experiment. ``w`` (T, n) is the whole disturbance sequence (T steps);
    ``zero_from`` is the step from which w = 0 (None: never forced); ``seed`` generated ``w``
    (before pinning changed w_0); ``ray_length`` is the distance from 0 to the feasible-set
    boundary along x0's direction."""

    spec: ProblemSpec
    design: OfflineDesign
    x0: np.ndarray
    theta_star: np.ndarray
    w: np.ndarray
    options: OnlineOptions
    labels: dict = field(default_factory=dict)
    seed: int = 0
    zero_from: int | None = None
    ray_length: float = float("nan")

    @property
    def problem(self) -> Problem:
        return self.spec.problem

    @property
    def steps(self) -> int:
        return len(self.w)

    def design_key(self) -> str:
        """Hash of the problem and its design (identifies a controller)."""
        h = hashlib.sha1()
        for name in ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "Q", "R", "theta_hat0"):
            h.update(np.ascontiguousarray(getattr(self.problem, name)).tobytes())
        h.update(str(self.problem.N).encode())
        for name in ("K", "P", "H_x", "H_T", "h_T", "H_theta", "h_theta0"):
            h.update(np.ascontiguousarray(getattr(self.design, name)).tobytes())
        h.update(repr(self.design.mu).encode())
        return h.hexdigest()

    def key(self) -> str:
        """Hash of everything that determines a run."""
        h = hashlib.sha1(self.design_key().encode())
        for arr in (self.x0, self.theta_star, self.w):
            h.update(np.ascontiguousarray(arr, float).tobytes())
        h.update(repr((self.options.update, self.options.window, self.options.projection)).encode())
        return h.hexdigest()

    def to_spec(self) -> ProblemSpec:
        """The complete problem file of this case (:func:`complete_spec`)."""
        return complete_spec(self)


def complete_spec(case, theta_star=None) -> ProblemSpec:
    """The complete problem file of a case: problem, design options, the ``online`` options of the
    run, and a scenario with x0, θ*, steps and the explicit disturbance array ``case.w`` (a pinning
    w_0 included), so that the file alone determines the run (``amcp certify problem.json`` repeats
    it). ``case`` needs ``spec``, ``x0``, ``theta_star``, ``w`` and ``options``; ``seed`` (which
    drew ``w``) is kept for the record; ``theta_star`` replaces ``case.theta_star`` (a θ*_k
    sequence). Campaign replays and property-suite failures are written so."""
    w = np.asarray(case.w, float)
    theta = case.theta_star if theta_star is None else theta_star
    scenario = Scenario(x0=np.asarray(case.x0, float), theta_star=np.asarray(theta, float), steps=len(w),
                        disturbance=w, seed=int(getattr(case, "seed", 0)) % (2**31))
    return ProblemSpec(case.spec.problem, case.spec.design, scenario, online=case.options)


def random_case(rng: np.random.Generator, steps: int, max_N: int = 10,
                state_dims: tuple[int, int] = DEFAULT_STATE_DIMS, budget=None) -> RandomCase:
    """A designed problem and a scenario, everything drawn from ``rng`` with the probabilities of
    ``amcp_properties.strategies.closed_loop_cases`` (θ* on a facet (then p >= 2) / at a vertex 3/8
    each, inside 1/4; x0 on
    the boundary 1/2; pinning 3/4 of the runs that allow it, half of them thin). A problem the
    offline design rejects is replaced by the next draw (at most :data:`MAX_DESIGN_ATTEMPTS`);
    ``labels["design attempts"]`` says how many it took. ``state_dims`` = (min n, max n) of the drawn
    problems (the default draws what it always drew); ``budget`` (a
    :class:`~amcp_drake.offline.budget.DesignBudget`) bounds every design's memory and time per candidate
    (None: the default memory limit, no time budget)."""
    coin = lambda: bool(rng.integers(2))  # noqa: E731 - read like draw(booleans())
    rejected: list[str] = []
    for attempt in range(1, MAX_DESIGN_ATTEMPTS + 1):
        theta_kind = "interior" if coin() and coin() else ("facet", "vertex")[int(rng.integers(2))]
        shape = random_shape(rng, max_N=max_N, min_p=2 if theta_kind == "facet" else 1, min_n=state_dims[0],
                             max_n=state_dims[1])
        spec, labels = random_problem(rng, shape)
        try:
            offline = design(spec.problem, spec.design, backend=DESIGN_BACKEND, budget=budget)
            problem = spec.problem
            theta_star = random_theta_star(rng, problem, theta_kind)
            x0_kind = "boundary" if rng.integers(2) == 0 else ("interior" if rng.integers(4) == 0 else "near boundary")
            x0, s_max = random_initial_state(rng, problem, offline, x0_kind)
        except DesignError as exc:
            rejected.append(rejection_reason(shape, exc))
            continue
        w_kind = DISTURBANCE_KINDS[int(rng.integers(3))]
        w, seed = random_disturbances(rng, problem, steps, w_kind)
        pin = "none"
        if shape.can_pin and theta_kind != "interior":
            pin = "none" if coin() and coin() else ("point", "thin")[int(rng.integers(2))]
        # "none" when D(x_0, u_0) lost rank at this x_0 (the draws of every other case are unchanged)
        w, pin = pin_first_disturbance(problem, offline, x0, theta_star, w, pin)
        options = random_online_options(rng)
        labels = dict(labels, theta_star=theta_kind, x0=x0_kind, disturbance=w_kind, pin=pin,
                      update=options.update, projection=options.projection, **{"design attempts": str(attempt)})
        if rejected:
            labels["rejected draws"] = " | ".join(rejected)
        return RandomCase(spec=spec, design=offline, x0=x0, theta_star=theta_star, w=w, options=options,
                          labels=labels, seed=seed, ray_length=s_max)
    raise DesignError(f"random_case: the offline design rejected {MAX_DESIGN_ATTEMPTS} problems in a row: "
                      + " | ".join(rejected))


#: Characters of a rejected draw's reason kept in the ``"rejected draws"`` label.
REJECTION_CHARS = 160


def rejection_reason(shape: ProblemShape, exc: Exception) -> str:
    """One rejected draw of :func:`random_case` as "n=5 m=2 p=3: AutoDesignError: <first line>" (the
    automatic design's first line is followed by the outcome of each candidate, counted by outcome)."""
    head = f"n={shape.n} m={shape.m} p={shape.p}: {type(exc).__name__}"
    attempts = getattr(exc, "attempts", None)
    if attempts:
        outcomes: dict[str, int] = {}
        for a in attempts:
            outcomes[a.outcome] = outcomes.get(a.outcome, 0) + 1
        last = attempts[-1]
        text = (", ".join(f"{count} {outcome}" for outcome, count in outcomes.items())
                + f"; last: {last.label}: {last.reason}")
    else:
        text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{head}: {text}"[:REJECTION_CHARS]


# -- did a run reach the hard cases? ---------------------------------------------------------------

#: Θ_k counts as lower-dimensional when the radius of the largest ball inside it (rows of unit norm)
#: is at most this. The controller widens every Δ_k by DELTA_MARGIN = 1e-6 in θ units (a numerical
#: guard, docs/decisions.md), so a set that the data pin to a point or a hyperplane keeps a radius of
#: 0.5-3 × 1e-6 (measured on pinned runs); 10 × the margin separates these from every set that
#: shrank by data alone (radii 1e-3-1 after 15-90 steps here).
LOWER_DIM_TOL = 10 * DELTA_MARGIN


def theta_star_face(problem: Problem, theta_star: np.ndarray) -> str:
    """Where θ* lies in Θ: "vertex" (the rows of H_θ active at θ* span R^p), "facet" (on ∂Θ, not
    at a vertex), or "interior"; active = normalised slack <= :data:`~amcp_drake.studies.pinning.ACTIVE_ROW_TOL`."""
    theta_star = np.asarray(theta_star, float)
    if theta_star.ndim != 1:
        return "time-varying"
    active = active_theta_rows(problem, theta_star)
    if not len(active):
        return "interior"
    return "vertex" if np.linalg.matrix_rank(problem.H_theta[active]) == problem.p else "facet"


#: Θ_k "shrank" below Θ_0 when a vertex of Θ_0 lies outside Θ_k by more than this (rows of unit
#: norm; the update's LPs and vertex solves are accurate to ~1e-9).
SHRINK_TOL = 1e-6


def _recorded_sets(traj) -> list[tuple[np.ndarray, np.ndarray]]:
    """(H_θk, h_θk) of every record k >= 1 that holds a set (a failed step may record none). Each record
    has its own H_θk: the exact update (7) appends and removes rows, (9) and the window keep those of Θ_0."""
    out = []
    for r in traj.records[1:]:
        H, h = np.asarray(r.H_theta, float), np.asarray(r.h_theta, float)
        if h.ndim == 1 and h.size and H.ndim == 2 and H.shape[0] == h.size:
            out.append((H, h))
    return out


def last_theta_k_radius(traj) -> float:
    """Chebyshev radius (rows of unit norm) of the last recorded Θ_k, k >= 1, of a trajectory
    (nan when no update was recorded; -inf when empty). The sets are nested (Lemma 3, a property
    of its own), so the last one is the thinnest; one LP per run keeps coverage cheap."""
    sets = _recorded_sets(traj)
    if not sets:
        return float("nan")
    H, h = polytope.normalize_rows(*sets[-1])
    return polytope.chebyshev_center(H, h)[1]


def theta_shrank(traj) -> bool:
    """Whether some recorded Θ_k, k >= 1, is smaller than Θ_0: a vertex of Θ_0 lies outside Θ_k by more
    than :data:`SHRINK_TOL` (rows of unit norm). Θ_k ⊆ Θ_0 (Lemma 3), so Θ_k = Θ_0 exactly when Θ_k
    holds every vertex of Θ_0 (it is convex). The test does not depend on the rows: (9) and the window
    lower the offsets of Θ_0's rows, the exact update (7) appends rows (a comparison of offsets on Θ_0's
    rows would never count a run of (7) as shrinking)."""
    r0 = traj.records[0]
    V = polytope.theta_vertices(np.asarray(r0.H_theta, float), np.asarray(r0.h_theta, float))
    if V is None:
        return False
    for H, h in _recorded_sets(traj):
        Hn, hn = polytope.normalize_rows(H, h)
        if float(np.max(V @ Hn.T - hn)) > SHRINK_TOL:
            return True
    return False


def hard_case_coverage(traj) -> dict[str, float]:
    """The hard-case coverage figures of one run (1.0 / 0.0, nan when not measurable), as the
    property suite reports them: ``theta_k_lower_dim`` (the last Θ_k has Chebyshev radius <=
    :data:`LOWER_DIM_TOL`), ``theta_star_vertex`` and ``theta_star_facet`` (:func:`theta_star_face`)."""
    radius = last_theta_k_radius(traj)
    face = theta_star_face(traj.problem, traj.theta_star)
    known = face in ("vertex", "facet", "interior")
    return {"theta_k_lower_dim": float("nan") if np.isnan(radius) else float(radius <= LOWER_DIM_TOL),
            "theta_star_vertex": float(face == "vertex") if known else float("nan"),
            "theta_star_facet": float(face == "facet") if known else float("nan")}
