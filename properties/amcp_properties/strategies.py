"""Hypothesis strategies that BUILD valid closed-loop experiments (no filtering on validity).

The numbers come from the library's plain-numpy generator :mod:`amcp_drake.studies.random_problems`
(which campaigns use too); these strategies draw the *structure* — dimensions, flags, kinds of
θ*, x0 and disturbance, pinning — and one seed per piece, so that shrinking moves towards small
dimensions, the simple flags and seed 0, and a drawn case is reproducible from its structure and
seeds alone. Rare nasty cases sit behind ``draw(booleans())``.

Every generated problem meets Assumption 1 by construction (W and Θ bounded polytopes, 0 in the
interior of W, θ̂0 and θ* in Θ); Assumptions 8 and 11 and (16) are then obtained from the
project's offline design (:func:`amcp_drake.offline.design.design`), which can still fail (no robust
gain, X0 not contractive, X_f empty). Such a failure is a *generator rejection*: it is counted
in :data:`GENERATOR_STATS` and reported by the suite, and the generator is tuned so that it is
rare (systems are "nice" by construction: ‖A0‖∞ < 1 most of the time, small ‖[A_i B_i]‖, W small
relative to Z).

Hard cases, built: θ* on a facet (of a problem with p >= 2) / at a vertex of Θ (3/8 each); w_0 at the vertex of W
that pins Θ_1 to {θ*} or into a facet's hyperplane (``pin="point"``), or leaves it thinner than
the solvers' tolerances (``pin="thin"``), in 3/4 of the runs whose problem allows it (p <= n, θ* on ∂Θ;
with input uncertainty w_0 is chosen for the controller's first input u_0, :mod:`amcp_drake.studies.pinning`); x0 on the boundary of the feasible set of (20); tight state boxes.

A drawn case whose run is estimated above the per-run memory bound
(:data:`amcp_properties.cases.RUN_MEMORY_MB`, the estimate of ``amcp certify``'s ``--max-memory``) is
refused before the run and counted per n (:func:`refuse_oversized_run`; the suite prints the refusals).

Layers:

* :func:`problem_shapes` -> :class:`~amcp_drake.studies.random_problems.ProblemShape`;
* :func:`problem_specs` -> :class:`GeneratedProblem` (a :class:`ProblemSpec` plus labels);
* :func:`designed_problems` -> :class:`DesignedProblem` (adds the offline design, Drake backend);
* :func:`theta_stars`, :func:`initial_states`, :func:`disturbances`, :func:`pins`, :func:`online_options`;
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

from amcp_drake.model.errors import DesignError, ProblemError
from amcp_drake.model.limits import check_run_size
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import Problem, ProblemSpec
from amcp_drake.model.problem_io import spec_to_dict
from amcp_drake.offline.budget import DEFAULT_CANDIDATE_SECONDS, DesignBudget
from amcp_drake.offline.design import OfflineDesign, design
from amcp_drake.studies.pinning import pin_first_disturbance
from amcp_drake.studies.random_problems import (
    BOUNDARY_BACKOFF,
    DESIGN_BACKEND,
    DISTURBANCE_KINDS,
    INITIAL_STATE_KINDS,
    THETA_STAR_KINDS,
    UPDATE_DRAWS,
    GenerationError,
    ProblemShape,
    random_disturbances,
    random_initial_state,
    random_problem,
    random_theta_star,
)

from . import profiles
from .cases import RUN_MEMORY_MB, Case, run_formulation

__all__ = ["BOUNDARY_BACKOFF", "DESIGN_BACKEND", "GENERATOR_STATS", "closed_loop_cases", "designed_problems",
           "disturbances", "initial_states", "online_options", "pins", "problem_shapes", "problem_specs",
           "refuse_oversized_run", "theta_stars"]

#: Offline designs kept in memory (a design costs 0.1-2 s; the same problems recur across tests
#: because every test of the ci profile uses the same seed).
DESIGN_CACHE_SIZE = 256


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

    def by_dimension(self) -> dict[int, tuple[int, int]]:
        """n -> (design attempts, accepted) of the problems drawn with n states."""
        dims = sorted({int(k.rpartition("=")[2]) for k in self.counts if k.startswith("draws n=")})
        return {n: (self.counts[f"draws n={n}"], self.counts[f"accepted n={n}"]) for n in dims}

    def refused_by_dimension(self) -> dict[int, tuple[int, int]]:
        """n -> (closed-loop cases sized, refused by the run's memory estimate) of the cases with n states
        (:func:`refuse_oversized_run`)."""
        dims = sorted({int(k.rpartition("=")[2]) for k in self.counts if k.startswith("sized n=")})
        return {n: (self.counts[f"sized n={n}"], self.counts[f"refused n={n}"]) for n in dims}

    def refusal_rate(self) -> float:
        """Refused / sized closed-loop cases (nan before any)."""
        sized = self.counts["sized cases"]
        return self.counts["refused: run size"] / sized if sized else float("nan")

    @property
    def attempts(self) -> int:
        return self.counts["design attempts"]

    @property
    def rejections(self) -> int:
        return sum(v for k, v in self.counts.items() if k.startswith("rejected:"))

    def to_state(self) -> dict:
        """The counts and distinct problems as plain JSON data (sent from a pytest-xdist worker)."""
        return {"counts": dict(self.counts), "distinct": dict(self.distinct)}

    def add_state(self, state: dict) -> None:
        """Add another process's :meth:`to_state` (counts summed; a problem drawn in both counted once)."""
        self.counts.update(state["counts"])
        self.distinct.update(state["distinct"])

    def rejection_rate(self) -> float:
        """Rejected designs / design attempts (nan before any attempt)."""
        return self.rejections / self.attempts if self.attempts else float("nan")


#: Generator statistics of this process (read by the suite summary).
GENERATOR_STATS = GeneratorStats()


def _grid(lo: float, hi: float, step: float) -> st.SearchStrategy[float]:
    """Floats on the grid {lo, lo+step, ..., hi}; shrinks towards the grid point nearest 0."""
    return st.integers(round(lo / step), round(hi / step)).map(lambda i: round(i * step, 10))


@dataclass(frozen=True, eq=False)
class GeneratedProblem:
    """A problem with its design options and the generator's labels (for coverage)."""

    spec: ProblemSpec
    labels: dict = field(default_factory=dict)
    shape: ProblemShape | None = None

    @property
    def problem(self) -> Problem:
        return self.spec.problem


@dataclass(frozen=True, eq=False)
class DesignedProblem(GeneratedProblem):
    """A generated problem with its offline design (K, P, X0, X_f, μ, ...)."""

    design: OfflineDesign | None = None


#: The state dimensions every profile draws (1 … SMALL_N); larger ones are the rarer draws of
#: :func:`problem_shapes` up to its ``max_n``.
SMALL_N = 3


def _seeds() -> st.SearchStrategy[int]:
    """The seed of the library's numpy generator for one piece (shrinks towards 0)."""
    return st.integers(0, 2**32 - 1)


@st.composite
def problem_shapes(draw, max_n: int = 3, max_m: int = 2, max_p: int = 3, min_N: int = 2, max_N: int = 10,
                   delta_range: tuple[float, float] = (0.01, 0.12), min_p: int = 1):
    """The structure of a random problem (:class:`amcp_drake.studies.random_problems.ProblemShape`):
    dimensions, then the flags, each behind ``draw(booleans())`` (two booleans for the rarer ones:
    expansive A0, tight state box, badly scaled state units). Without input uncertainty (B_i = 0, which the shrinker moves
    towards) p <= n, so that the first regressor D(x_0) can pin Θ_1 (:func:`closed_loop_cases`).
    The probabilities are those of :func:`amcp_drake.studies.random_problems.random_shape`, which draws
    n uniformly in a given range; here, with ``max_n`` > :data:`SMALL_N` (the thorough profile), n is
    drawn above SMALL_N only in a quarter of the problems (two booleans: each design there costs seconds),
    uniformly in SMALL_N + 1 … max_n; with ``max_n`` <= SMALL_N nothing more is drawn (the ci profile's
    examples are those it always drew)."""
    if max_n > SMALL_N and draw(st.booleans()) and draw(st.booleans()):
        n = draw(st.integers(SMALL_N + 1, max_n))
    else:
        n = draw(st.integers(1, min(max_n, SMALL_N)))
    m = draw(st.integers(1, max_m))
    input_uncertainty = draw(st.booleans())
    p = draw(st.integers(min(min_p, max_p), max(min(min_p, max_p), max_p if input_uncertainty else min(max_p, n))))
    N = draw(st.integers(min_N, max_N))
    expansive = draw(st.booleans()) and draw(st.booleans())
    unstable_mode = expansive and draw(st.booleans())
    return ProblemShape(n=n, m=m, p=p, N=N, expansive=expansive, unstable_mode=unstable_mode,
                        theta_cuts=draw(st.booleans()), w_cuts=draw(st.booleans()), mixed_row=draw(st.booleans()),
                        tight_state_box=draw(st.booleans()) and draw(st.booleans()), coupled_Q=draw(st.booleans()),
                        theta_hat0_off_centre=draw(st.booleans()), input_uncertainty=input_uncertainty,
                        zero_centre=draw(st.booleans()), delta_range=delta_range,
                        scaled_states=draw(st.booleans()) and draw(st.booleans()))


@st.composite
def problem_specs(draw, **shape_kwargs):
    """Random uncertain systems meeting Assumption 1, with a Z that binds: the shape from
    :func:`problem_shapes`, the numbers from :func:`amcp_drake.studies.random_problems.random_problem`
    (see there for the ranges) with a drawn seed."""
    shape = draw(problem_shapes(**shape_kwargs))
    spec, labels = random_problem(np.random.default_rng(draw(_seeds())), shape)
    return GeneratedProblem(spec, labels, shape)


def spec_digest(spec: ProblemSpec) -> str:
    """A stable hash of a problem file's content (cache key)."""
    return hashlib.sha1(json.dumps(spec_to_dict(spec), sort_keys=True).encode()).hexdigest()


def timed_from_n(profile: str) -> int:
    """The least state dimension whose designs get a time budget per candidate
    (:data:`~amcp_drake.offline.budget.DEFAULT_CANDIDATE_SECONDS` of CPU): every n in the thorough profile
    (its examples are random anyway; measured: a generated n = 1 problem whose terminal-set recursion
    grew to 1,047,173 rows and 5.5 GB without ending), above :data:`SMALL_N` otherwise, so that the ci
    profile's examples never depend on the machine's speed (its designs take 0.1-3 s)."""
    return 1 if profile == "thorough" else SMALL_N + 1


class _DesignCache:
    """LRU cache of offline designs by problem-file content; failures are cached too. Designs of
    ``timed_from`` states or more have a time budget per candidate (:func:`timed_from_n`); a design
    over it is a counted rejection ("CandidateTimeout")."""

    def __init__(self, size: int, timed_from: int = SMALL_N + 1) -> None:
        self.size = size
        self.timed_from = timed_from
        self.items: OrderedDict[str, OfflineDesign | DesignError] = OrderedDict()

    def get(self, spec: ProblemSpec) -> OfflineDesign:
        key = spec_digest(spec)
        if key not in self.items:
            timed = spec.problem.n >= self.timed_from
            budget = DesignBudget(candidate_seconds=DEFAULT_CANDIDATE_SECONDS) if timed else None
            try:
                self.items[key] = design(spec.problem, spec.design, backend=DESIGN_BACKEND, budget=budget)
            except DesignError as exc:
                self.items[key] = exc
            if len(self.items) > self.size:
                self.items.popitem(last=False)
        self.items.move_to_end(key)
        value = self.items[key]
        if isinstance(value, DesignError):
            raise value
        return value


DESIGNS = _DesignCache(DESIGN_CACHE_SIZE, timed_from_n(profiles.name()))


@st.composite
def designed_problems(draw, **kwargs):
    """:func:`problem_specs` plus the offline design; a DesignError is a counted rejection."""
    gen = draw(problem_specs(**kwargs))
    GENERATOR_STATS.add("design attempts")
    GENERATOR_STATS.add(f"draws n={gen.problem.n}")
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
    GENERATOR_STATS.add(f"accepted n={gen.problem.n}")
    GENERATOR_STATS.outcome(digest, "accepted")
    return DesignedProblem(gen.spec, gen.labels, gen.shape, d)


def theta_star_kinds() -> st.SearchStrategy[str]:
    """On a facet or at a vertex (3/8 each: the hard cases), or (two booleans, 1/4) inside Θ.
    "facet" comes first, where Hypothesis' generation leans and its shrinker goes."""
    return st.booleans().flatmap(lambda a: st.booleans().flatmap(
        lambda b: st.just("interior") if (a and b) else st.sampled_from(("facet", "vertex"))))


@st.composite
def theta_stars(draw, problem: Problem, kind: str | None = None):
    """θ* ∈ Θ of a ``kind`` (when None: vertex, facet or interior, 1/3 each, as the Section 4
    generators have always drawn it); numbers from
    :func:`amcp_drake.studies.random_problems.random_theta_star`."""
    kind = kind if kind is not None else draw(st.sampled_from(THETA_STAR_KINDS))
    assert kind in THETA_STAR_KINDS
    return random_theta_star(np.random.default_rng(draw(_seeds())), problem, kind), kind


@st.composite
def initial_states(draw, problem: Problem, offline: OfflineDesign):
    """x0 on the boundary of {x | 𝔻(x, Θ0) ≠ ∅} (boolean), near it (90-99.5 % of the way), or
    (two more booleans) in the interior, found by the vertex-form LP of
    :mod:`amcp_drake.studies.tube_feasibility` along a random ray from 0 (no luck involved)."""
    if not draw(st.booleans()):  # (False is what the shrinker moves towards: the boundary)
        kind = "boundary"
    elif draw(st.booleans()) and draw(st.booleans()):
        kind = "interior"
    else:
        kind = "near boundary"
    assert kind in INITIAL_STATE_KINDS
    try:
        x0, s_max = random_initial_state(np.random.default_rng(draw(_seeds())), problem, offline, kind)
    except GenerationError:
        GENERATOR_STATS.add("rejected: boundary LP")
        event("generator: boundary LP failed")
        reject()
    return x0, kind, s_max


def disturbance_kinds() -> st.SearchStrategy[str]:
    """Vertices of W first (the nastiest, and what shrinking moves towards), uniform, zero."""
    return st.sampled_from(DISTURBANCE_KINDS)


@st.composite
def disturbances(draw, problem: Problem, steps: int, kinds: st.SearchStrategy[str] | None = None,
                 zero_from: int | None = None):
    """w_0..w_{steps-1}: on the vertices of W, i.i.d. uniform on W, or zero (explicit seed);
    zero from step ``zero_from`` on when given (Corollary 16)."""
    kind = draw(kinds if kinds is not None else disturbance_kinds())
    w, seed = random_disturbances(np.random.default_rng(draw(_seeds())), problem, steps, kind, zero_from)
    return w, kind, seed


@st.composite
def pins(draw, shape: ProblemShape | None, theta_kind: str):
    """Whether w_0 pins Θ_1 (:func:`amcp_drake.studies.random_problems.pinning_disturbance`): "point"
    (zero volume) or "thin" (thinner than the solvers' tolerances), 3/8 each, or (two booleans) "none", when the
    problem allows it (p <= n) and θ* is on ∂Θ; "none" otherwise (nothing drawn)."""
    if shape is None or not shape.can_pin or theta_kind == "interior":
        return "none"
    if draw(st.booleans()) and draw(st.booleans()):
        return "none"
    return draw(st.sampled_from(("point", "thin")))


def online_options() -> st.SearchStrategy[OnlineOptions]:
    """(9) fixed complexity, moving window (Remark 4) or the exact update (7) (Theorem 14 holds for (7)
    or (9)) with the weights of
    :data:`~amcp_drake.studies.random_problems.UPDATE_DRAWS`; projection onto Θ (12) or Θ_k (Remark 7)."""
    return st.builds(OnlineOptions, update=st.sampled_from(UPDATE_DRAWS), window=st.integers(1, 10),
                     projection=st.sampled_from(("Theta", "Theta_k")))


def refuse_oversized_run(problem: Problem, spec: ProblemSpec, offline: OfflineDesign, steps: int,
                         options: OnlineOptions, max_memory_mb: float = RUN_MEMORY_MB,
                         stats: GeneratorStats | None = None) -> str | None:
    """The reason a drawn case's run is refused, or None: its estimated memory
    (:func:`amcp_drake.model.limits.check_run_size` with its design, options and steps) above
    ``max_memory_mb``. Every case sized and every refusal is counted per n in ``stats`` (default
    :data:`GENERATOR_STATS`), so the summary prints how many draws were refused, never dropping one silently."""
    stats = GENERATOR_STATS if stats is None else stats
    stats.add("sized cases")
    stats.add(f"sized n={problem.n}")
    try:
        check_run_size(problem, spec.design, steps, options, max_memory_mb,
                       option="amcp_properties.cases.RUN_MEMORY_MB", design=offline,
                       formulation=run_formulation(problem, offline, options))
    except ProblemError as exc:
        stats.add("refused: run size")
        stats.add(f"refused n={problem.n}")
        if len(stats.messages) < 100:
            stats.messages.append(str(exc))
        return str(exc)
    return None


@st.composite
def closed_loop_cases(draw, steps: int, kinds: st.SearchStrategy[str] | None = None,
                      zero_after: st.SearchStrategy[int] | None = None, max_memory_mb: float = RUN_MEMORY_MB,
                      **problem_kwargs):
    """Everything for one closed-loop run: a designed problem, θ*, x0, w (w_0 pinning Θ_1 when
    drawn, see :func:`pins`), online options.

    ``zero_after``: a strategy for the step after which w = 0 (Corollary 16, finite energy).
    ``max_memory_mb``: the per-run memory bound; a case whose run is estimated above it is refused
    (rejected and counted, :func:`refuse_oversized_run`) after every draw, so the draws before it are
    those of every earlier version.
    """
    # θ*'s kind first: a facet that is not a vertex needs p >= 2 (for p = 1 every boundary point is
    # a vertex), so "facet" draws a problem with p >= 2 (measured in the ci profile with the kind drawn
    # after the problem: facets in only 4-20 % of the runs, depending on the draws)
    theta_kind = draw(theta_star_kinds())
    if theta_kind == "facet":
        problem_kwargs = dict(problem_kwargs, min_p=max(2, problem_kwargs.get("min_p", 1)))
    gen = draw(designed_problems(**problem_kwargs))
    problem = gen.problem
    theta_star, theta_kind = draw(theta_stars(problem, theta_kind))
    x0, x0_kind, s_max = draw(initial_states(problem, gen.design))
    zero_from = draw(zero_after) if zero_after is not None else None
    w, w_kind, seed = draw(disturbances(problem, steps, kinds, zero_from))
    pin = draw(pins(gen.shape, theta_kind))
    if zero_from == 0:  # w = 0 from the start: nothing to pin with
        pin = "none"
    # "none" when D(x_0, u_0) lost rank at this x_0
    w, pin = pin_first_disturbance(problem, gen.design, x0, theta_star, w, pin)
    options = draw(online_options())
    if refuse_oversized_run(problem, gen.spec, gen.design, len(w), options, max_memory_mb) is not None:
        event(f"generator: run refused, estimated memory above {max_memory_mb:g} MiB (n={problem.n})")
        reject()
    labels = dict(gen.labels, theta_star=theta_kind, x0=x0_kind, disturbance=w_kind, pin=pin,
                  update=options.update, projection=options.projection)
    return Case(spec=gen.spec, design=gen.design, x0=x0, theta_star=theta_star, w=w, options=options,
                labels=labels, seed=seed, zero_from=zero_from, ray_length=s_max)
