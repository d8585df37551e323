"""Generators and numpy checks for the Section 4 options: the min-max cost (19),
persistent excitation (docs/explanation/paper.md §8) and time-varying parameters (Section 4.1), on random systems.

The generators reuse :mod:`amcp_properties.strategies` (designed problems, θ*, boundary initial
states, disturbances) and add the option: ``cost="minmax"``; ``pe_window``/``pe_level`` for m = 1
(the level drawn relative to what the input box allows, so that the constraint binds); ``d_theta``
with a θ*_k sequence that moves at the full rate d_θ and is reflected at the faces of Θ (so θ*_k
reaches the boundary of Θ and of Θ_k).

The checks (``check_*``) take a :class:`~amcp_drake.online.simulate.Trajectory` and return
:class:`~amcp_drake.model.check_result.CheckResult` objects; they use numpy only and read the recorded
contract of :class:`~amcp_drake.online.controller.StepRecord` (``cost``, ``z``, ``alpha``, ``v``,
``pe_status``, ``pe_level``, ``pe_dim``, ``pe_bounds``, ``h_theta_stages``), never the controller's
internals. Each check accepts an optional override (a wrong cost formula, a tampered record) so
that the negative controls of the test module exercise the very same code path.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
from dataclasses import dataclass, field

import numpy as np
from hypothesis import strategies as st

from amcp_drake.model import polytope
from amcp_drake.model.check_result import CheckResult, judge
from amcp_drake.model.errors import InconsistentDataError
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import ProblemSpec
from amcp_drake.model.status import SolveStatus
from amcp_drake.model.tolerances import COST_REL_TOL, PE_BOUND_TOL, PE_LEVEL_TOL, SET_TOL
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import Trajectory, simulate
from amcp_drake.studies.random_problems import complete_spec

from . import profiles
from .cases import Case, Memo
from .feasible import TubeGeometry, max_ray_length
from .nversion import second_method
from .strategies import _grid, designed_problems, disturbances, initial_states, theta_stars

# -- sizes per profile ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Section4Sizes:
    examples: int   # examples per option and backend
    steps: int      # closed-loop steps (min-max, time-varying)
    pe_steps: int   # PE runs (the constraint starts after P − 1 + n steps)
    max_N: int      # horizon bound of the generated problems (the min-max form is an SOCP)


#: ci: 40 examples per option (why: the docstring of test_section4_options.py)
SIZES = {"ci": Section4Sizes(examples=40, steps=12, pe_steps=18, max_N=6),
         "thorough": Section4Sizes(examples=60, steps=24, pe_steps=36, max_N=8)}


def sizes() -> Section4Sizes:
    return SIZES[profiles.name()]


# -- tolerances ----------------------------------------------------------------------------------------
# model.tolerances, shared with the certificate's claims of the same ids: SET_TOL for θ*_k ∈ Θ_k and
# θ*_{k+l} ∈ Θ_{l|k} (unit rows, distance); COST_REL_TOL for record.cost vs the numpy evaluation of (19),
# |cost − J| <= COST_REL_TOL·max(1, |J|) (Clarabel stops at a relative duality gap of 1e-8; the epigraph
# values t_l then exceed the max over the vertices by at most the gap); PE_LEVEL_TOL for λ_min of the
# realised window Gram >= pe_level − PE_LEVEL_TOL·max(1, pe_level) (the QP meets the bound on u_0 to ~1e-8,
# dλ_min/du_k <= 2‖ū_k‖ <= ~10 here); PE_BOUND_TOL for u_k within record.pe_bounds (times max(1, |bound|)).
#: Coverage thresholds (the brief's): a row of Z "active" when max(F x + G u) > 1 − ACTIVE_MARGIN;
#: θ*_k "near the boundary" of Θ_k within NEAR_BOUNDARY (distance on unit rows); the PE constraint
#: "binds" at an enforced step when λ_min <= pe_level·(1 + BINDING_REL).
ACTIVE_MARGIN = 0.05
NEAR_BOUNDARY = 0.05
BINDING_REL = 1e-4

PE_STATUSES = ("off", "inactive", "satisfied", "enforced", "enforced_partial", "enforced_necessary", "fallback")


# -- cases -----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Section4Case(Case):
    """A :class:`Case` whose options carry a Section 4 option; ``theta_seq`` (steps+1, p) is the
    θ*_k sequence of a time-varying run (None: constant ``theta_star``)."""

    theta_seq: np.ndarray | None = None

    def key(self) -> str:
        h = hashlib.sha1(super().key().encode())
        h.update(repr(self.options).encode())
        if self.theta_seq is not None:
            h.update(np.ascontiguousarray(self.theta_seq, float).tobytes())
        return h.hexdigest()

    def to_spec(self) -> ProblemSpec:
        """The complete problem file of this case: its options as the ``online`` section, its θ*
        (the θ*_k sequence of a time-varying case) and the explicit disturbance array in the
        scenario, so that ``amcp certify problem.json`` repeats the run."""
        return complete_spec(self, theta_star=self.theta_seq)


class Section4Runner(Memo):
    """Memoised runs of :class:`Section4Case` (the property test and its negative control see the
    same examples under the ci seed, so each run is simulated once per backend)."""

    def __init__(self, size: int = 64) -> None:
        super().__init__(size)

    def run(self, case: Section4Case, backend: str) -> Trajectory:
        return self.get((case.key(), backend), lambda: _simulate(case, backend))


def _simulate(case: Section4Case, backend: str) -> Trajectory:
    """One run of ``case`` (a θ* sequence when the case has one); Θ_{k-1} ∩ Δ_k = ∅ ends it early."""
    ctrl = AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options)
    theta = case.theta_seq if case.theta_seq is not None else case.theta_star
    try:
        return simulate(ctrl, case.x0, theta, case.steps, disturbance=case.w, seed=case.seed)
    except InconsistentDataError as exc:
        return exc.trajectory


RUNNER = Section4Runner()


def _base(draw, steps: int, **problem_kwargs):
    gen = draw(designed_problems(**problem_kwargs))
    pr = gen.problem
    theta_star, theta_kind = draw(theta_stars(pr))
    x0, x0_kind, s_max = draw(initial_states(pr, gen.design))
    w, w_kind, seed = draw(disturbances(pr, steps))
    update = draw(st.sampled_from(("fixed", "window")))
    window = draw(st.integers(1, 6))
    labels = dict(gen.labels, theta_star=theta_kind, x0=x0_kind, disturbance=w_kind, update=update)
    return gen, theta_star, x0, s_max, w, seed, update, window, labels


@st.composite
def minmax_cases(draw, steps: int, max_N: int = 6):
    """Random designed problem, boundary/near-boundary x0, cost (19)."""
    gen, theta_star, x0, s_max, w, seed, update, window, labels = _base(draw, steps, max_N=max_N)
    options = OnlineOptions(update=update, window=window, cost="minmax")
    return Section4Case(spec=gen.spec, design=gen.design, x0=x0, theta_star=theta_star, w=w, options=options,
                        labels=dict(labels, option="minmax"), seed=seed, ray_length=s_max)


#: ‖[A_i B_i]‖₂·p of the baseline cases (the suite's default range is [0.01, 0.12]).
BASELINE_DELTA = (0.08, 0.3)


@st.composite
def baseline_cases(draw, steps: int, max_N: int = 6):
    """Random designed problem with a large parametric uncertainty (δ ∈ BASELINE_DELTA, where Θ_k
    shrinking can change the optimum of (20)), boundary/near-boundary x0, the adaptive update (9)
    (fixed or over a window); :func:`robust_twin` gives the same case with update "none"."""
    gen, theta_star, x0, s_max, w, seed, update, window, labels = _base(draw, steps, max_N=max_N,
                                                                        delta_range=BASELINE_DELTA)
    options = OnlineOptions(update=update, window=window)
    return Section4Case(spec=gen.spec, design=gen.design, x0=x0, theta_star=theta_star, w=w, options=options,
                        labels=dict(labels, option="baseline"), seed=seed, ray_length=s_max)


def example1_baseline_case(steps: int = 12) -> Section4Case:
    """Example 1 (x0 = [2, 3], θ* = [0.8, 0.2, −0.5], uniform w, seed 0) with update (9): the paper's
    system, where the parametric uncertainty dominates and adaptation enlarges the feasible region."""
    from amcp_drake.model.examples import lorenzen2019_spec
    from amcp_drake.offline.design import design
    from amcp_drake.online.simulate import disturbance_sequence

    spec = lorenzen2019_spec()
    sc = spec.scenario
    w = disturbance_sequence(spec.problem, "uniform", steps, 0)
    return Section4Case(spec=spec, design=design(spec.problem, spec.design, backend="drake"), x0=np.asarray(sc.x0),
                        theta_star=np.asarray(sc.theta_star), w=w, options=OnlineOptions(update="fixed"),
                        labels={"option": "baseline", "problem": "lorenzen2019"}, seed=0)


def robust_twin(case: Section4Case) -> Section4Case:
    """The same case under the robust baseline (update "none")."""
    return dataclasses.replace(case, options=dataclasses.replace(case.options, update="none"),
                               labels=dict(case.labels, update="none"))


def baseline_is_constant(traj) -> CheckResult:
    """Robust baseline: every record has Θ_k = Θ_0 (the design's H_θ, h_θ0) and θ̂_k = θ̂0."""
    d, pr = traj.design, traj.problem
    worst = 0.0
    for r in traj.records:
        if r.H_theta.shape != d.H_theta.shape:
            return judge("baseline constant", "Θ_k ≡ Θ_0, θ̂_k ≡ θ̂0", -np.inf, 0.0, f"step {r.k}: shape changed")
        worst = max(worst, float(np.max(np.abs(r.H_theta - d.H_theta))), float(np.max(np.abs(r.h_theta - d.h_theta0))),
                    float(np.max(np.abs(r.theta_hat - pr.theta_hat0))))
    return judge("baseline constant", "Θ_k ≡ Θ_0, θ̂_k ≡ θ̂0 at every step", -worst, 0.0,
                 "margin = −max |change| (exact: nothing is updated)")


#: Optimal costs of the QP (20) on Θ_k vs on Θ_0 at the same x_k and θ̂_k, relative to max(1, |J|):
#: both are Clarabel optima (duality gap <= 1e-8), so 1e-6 leaves two orders of magnitude.
MONOTONE_TOL = 1e-6


#: Steps probed per run (spread over those where Θ_k shrank). At each, (20) is solved at x_k and at
#: multiples s·x_k around s_0, the largest multiple at which (20) on Θ_0 is feasible
#: (feasible.max_ray_length, the vertex-form LP): just inside (s_0(1 − INSIDE)), where the tube
#: constraints bind and Θ_k ⊆ Θ_0 can lower the optimum, and just outside (PROBE_OUTSIDE·s_0), where
#: only the adaptive QP may be feasible.
PROBE_STEPS = 3
PROBE_OUTSIDE = 1.05
INSIDE = 1e-3


@dataclass
class Probe:
    """(20) at one state x = scale·x_k with θ̂_k on Θ_k (adaptive) and on Θ_0 (robust), same backend."""

    k: int
    scale: float
    status_adaptive: SolveStatus
    cost_adaptive: float | None
    status_robust: SolveStatus
    cost_robust: float | None


def probe_theta0_vs_theta_k(traj, case: Section4Case, backend: str) -> list[Probe]:
    """At up to PROBE_STEPS steps where Θ_k shrank, solve (20) with the recorded θ̂_k on Θ_k and on Θ_0
    (the design's offsets h_θ0) at x_k, just inside and just outside the robust feasible ray."""
    H0, h0 = np.asarray(case.design.H_theta, float), np.asarray(case.design.h_theta0, float)
    shrunk = [r for r in traj.records if r.h_theta.shape == h0.shape and np.any(r.h_theta < h0 - 1e-6)
              and np.linalg.norm(r.x) > 1e-9]
    if not shrunk:
        return []
    picks = [shrunk[i] for i in sorted(set(np.linspace(0, len(shrunk) - 1, PROBE_STEPS).round().astype(int)))]
    ctrl = AdaptiveMPC(case.problem, case.design, backend=backend, options=case.options)
    geometry0 = TubeGeometry.build(case.problem, case.design, polytope.vertices(H0, h0))
    out = []
    for r in picks:
        x = np.asarray(r.x, float)
        s0 = max_ray_length(geometry0, x)
        scales = [1.0, s0 * (1.0 - INSIDE), PROBE_OUTSIDE * s0] if np.isfinite(s0) and s0 > 0 else [1.0]
        for scale in scales:
            a = ctrl.mpc.solve(scale * x, r.h_theta, r.theta_hat, r.H_theta)
            b = ctrl.mpc.solve(scale * x, h0, r.theta_hat, H0)
            out.append(Probe(r.k, scale, a.status, a.cost, b.status, b.cost))
    return out


def adaptation_never_hurts(probes: list[Probe], swap: bool = False) -> CheckResult:
    """Θ_k ⊆ Θ_0 makes 𝔻(x, Θ_0) ⊆ 𝔻(x, Θ_k) (the tube conditions (5b) for the larger set imply them
    for the smaller; (15) is exact by Farkas' lemma): wherever (20) on Θ_0 is feasible, (20) on Θ_k is
    feasible with no larger optimum (same x, θ̂_k, objective). ``swap`` exchanges the roles
    (negative control)."""
    worst, where = np.inf, "no probe with a feasible QP on Θ_0"
    for p in probes:
        if p.status_robust is not SolveStatus.OPTIMAL:
            continue
        if p.status_adaptive is not SolveStatus.OPTIMAL:
            return judge("adaptation never hurts", "feasible on Θ_0 ⇒ feasible on Θ_k", -np.inf, MONOTONE_TOL,
                         f"step {p.k}, x = {p.scale}·x_k: Θ_0 optimal, Θ_k {p.status_adaptive.value}")
        small, large = (p.cost_robust, p.cost_adaptive) if swap else (p.cost_adaptive, p.cost_robust)
        m = (large - small) / max(1.0, abs(large))
        if m < worst:
            worst, where = m, f"step {p.k}, x = {p.scale}·x_k: J(Θ_k) {p.cost_adaptive!r}, J(Θ_0) {p.cost_robust!r}"
    return judge("adaptation never hurts", "J*(x, Θ_k) <= J*(x, Θ_0) wherever (20) on Θ_0 is feasible",
                 worst, MONOTONE_TOL, where)


def strict_gains(probes: list[Probe]) -> dict[str, bool]:
    """Coverage: some probe where Θ_k shrank; where only the adaptive QP is feasible; where its
    optimum is strictly lower."""
    return {"theta_shrunk": bool(probes),
            "only_adaptive_feasible": any(p.status_adaptive is SolveStatus.OPTIMAL
                                          and p.status_robust is not SolveStatus.OPTIMAL for p in probes),
            "cheaper": any(p.status_adaptive is SolveStatus.OPTIMAL and p.status_robust is SolveStatus.OPTIMAL
                           and p.cost_adaptive < p.cost_robust - 1e-4 * max(1.0, abs(p.cost_robust))
                           for p in probes)}


def input_half_width(problem) -> float:
    """Half-width of the input box of Z along u (m = 1): min over the rows with F = 0 of 1/|G|."""
    rows = np.all(problem.F == 0.0, axis=1) & (np.abs(problem.G[:, 0]) > 0)
    return float(np.min(1.0 / np.abs(problem.G[rows, 0])))


@st.composite
def pe_cases(draw, steps: int, max_N: int = 6):
    """m = 1; window P ∈ {n+1, …, n+3}; level ρ = f·P·ū² with ū the input box half-width and, in 3
    of 4 cases, f ∈ [0.005, 0.6] (from easily reachable to beyond what the inputs can give, which
    exercises the ladder's lower rungs), else f ∈ [10, 30]: unattainable at every rung even at 1/8 of
    its level (ρ_1/8 > P ū²), so every step after the history is "fallback" (regime label)."""
    gen, theta_star, x0, s_max, w, seed, update, window, labels = _base(draw, steps, max_m=1, max_N=max_N)
    pr = gen.problem
    P = pr.n + 1 + draw(st.integers(0, 2))
    regime = draw(st.sampled_from(("attainable", "attainable", "attainable", "unattainable")))
    frac = draw(_grid(0.005, 0.6, 0.005)) if regime == "attainable" else draw(_grid(10.0, 30.0, 1.0))
    labels = dict(labels, pe_regime=regime)
    level = max(frac * P * input_half_width(pr) ** 2, 1e-4)
    options = OnlineOptions(update=update, window=window, pe_window=P, pe_level=float(level))
    return Section4Case(spec=gen.spec, design=gen.design, x0=x0, theta_star=theta_star, w=w, options=options,
                        labels=dict(labels, option="pe", pe_window=str(P), pe_fraction=str(frac)), seed=seed,
                        ray_length=s_max)


def _ray(H: np.ndarray, h: np.ndarray, theta: np.ndarray, d: np.ndarray) -> float:
    """max{s >= 0 | H (θ + s d) <= h} for θ ∈ {Hθ <= h} (inf when unbounded)."""
    rates = H @ d
    pos = rates > 1e-12
    if not np.any(pos):
        return np.inf
    return float(max(np.min((h[pos] - H[pos] @ theta) / rates[pos]), 0.0))


def drifting_sequence(H: np.ndarray, h: np.ndarray, theta0: np.ndarray, rate: float, steps: int, rng,
                      mode: str) -> np.ndarray:
    """θ*_0..θ*_steps in {Hθ <= h}, ‖θ*_{k+1} − θ*_k‖ <= rate: each step moves by ``rate`` along a
    direction ("line": one direction, "walk": a new random direction each step) and stops at the
    boundary of Θ; the direction is then reflected at the face hit (unit rows), so that θ* slides
    along and bounces off the faces."""
    Hn = H / np.linalg.norm(H, axis=1)[:, None]
    hn = h / np.linalg.norm(H, axis=1)
    p = len(theta0)
    seq = [np.asarray(theta0, float)]
    d = rng.standard_normal(p)
    d /= np.linalg.norm(d)
    for _ in range(steps):
        if mode == "walk":
            d = rng.standard_normal(p)
            d /= np.linalg.norm(d)
        th = seq[-1]
        s = min(rate, _ray(Hn, hn, th, d))
        new = th + s * d
        if s < rate:  # hit a face: reflect d at the most active face
            i = int(np.argmax(Hn @ new - hn))
            d = d - 2.0 * (Hn[i] @ d) * Hn[i]
            d /= np.linalg.norm(d)
        seq.append(new)
    return np.array(seq)


@st.composite
def time_varying_cases(draw, steps: int, max_N: int = 6):
    """d_θ ∈ [0.01, 0.15] (Θ has half-widths 0.2-1.5), θ*_0 anywhere in Θ, a drifting sequence at the
    full rate (line or random walk) reflected into Θ."""
    gen, theta_star, x0, s_max, w, seed, update, window, labels = _base(draw, steps, max_N=max_N)
    pr = gen.problem
    d_theta = draw(_grid(0.01, 0.15, 0.01))
    mode = draw(st.sampled_from(("line", "walk")))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    seq = drifting_sequence(pr.H_theta, pr.h_theta, theta_star, d_theta, steps, rng, mode)
    options = OnlineOptions(update=update, window=window, d_theta=float(d_theta))
    return Section4Case(spec=gen.spec, design=gen.design, x0=x0, theta_star=seq[0], w=w, options=options,
                        labels=dict(labels, option="time-varying", drift=mode), seed=seed, ray_length=s_max,
                        theta_seq=seq)


# -- checks ---------------------------------------------------------------------------------------------


def all_qps_optimal(traj) -> CheckResult:
    """Recursive feasibility in the run's own terms: the run completed and every QP was optimal."""
    bad = [r.k for r in traj.records if r.status is not SolveStatus.OPTIMAL]
    ok = traj.stop_reason == "completed" and not bad and len(traj.u) == len(traj.w)
    return judge("Theorem 14 (i) run", "every QP of the run solved to optimality (recursive feasibility)",
                 0.0 if ok else -np.inf, 0.0, f"stop: {traj.stop_reason}; non-optimal steps {bad}")


def z_margin(traj) -> float:
    """max_k max_i (F x_k + G u_k)_i (1 = on the boundary of Z)."""
    pr = traj.problem
    if len(traj.u) == 0:
        return float("nan")
    return float(np.max(traj.x[:len(traj.u)] @ pr.F.T + traj.u @ pr.G.T))


def _unit(H, h):
    norms = np.linalg.norm(H, axis=1)
    return H / norms[:, None], h / norms


def theta_distances(traj) -> np.ndarray:
    """Signed distance of θ*_k inside Θ_k (unit rows) per record (negative: outside)."""
    out = []
    for r in traj.records:
        H, h = _unit(np.asarray(r.H_theta, float), np.asarray(r.h_theta, float))
        out.append(float(np.min(h - H @ traj.theta_star_at(r.k))))
    return np.array(out)


@second_method("theta_star_in_Theta_k")
def theta_star_in_theta_k(traj) -> CheckResult:
    """Theorem 14 (ii) / Proposition 19: θ*_k ∈ Θ_k at every k; an inconsistent-data stop fails."""
    claim = "θ*_k ∈ Θ_k for all k (Theorem 14 (ii) / Proposition 19)"
    if traj.stop_reason.startswith("inconsistent"):
        return judge("θ*_k ∈ Θ_k", claim, -np.inf, SET_TOL, traj.stop_reason)
    dist = theta_distances(traj)
    k = int(np.argmin(dist))
    return judge("θ*_k ∈ Θ_k", claim, float(dist[k]), SET_TOL, f"min distance inside Θ_k at step {k}")


def predicted_sets_contain_future(traj, stages_of=None) -> CheckResult:
    """(26): θ*_{k+l} ∈ Θ_{l|k} = {H_θk θ <= record.h_theta_stages[l]} for every k, l with k + l <=
    steps. ``stages_of(record)`` overrides the recorded stage offsets (negative control)."""
    claim = "θ*_{k+l} ∈ Θ_{l|k} (record.h_theta_stages[l]) for all k, l (26)"
    worst, where = np.inf, "no stage checked"
    T = len(np.atleast_2d(traj.theta_star)) - 1
    for r in traj.records:
        stages = r.h_theta_stages if stages_of is None else stages_of(r)
        if stages is None:
            return judge("Θ_{l|k}", claim, -np.inf, SET_TOL, f"step {r.k}: no h_theta_stages recorded")
        stages = np.asarray(stages, float)
        if stages.shape != (traj.problem.N, len(r.h_theta)):
            return judge("Θ_{l|k}", claim, -np.inf, SET_TOL, f"step {r.k}: stages of shape {stages.shape}")
        for l in range(len(stages)):
            if r.k + l > T:
                break
            H, h = _unit(np.asarray(r.H_theta, float), stages[l])
            m = float(np.min(h - H @ traj.theta_star_at(r.k + l)))
            if m < worst:
                worst, where = m, f"step {r.k}, stage {l}"
    return judge("Θ_{l|k}", claim, worst, SET_TOL, f"min distance of θ*_(k+l) inside Θ_(l|k) at {where}")


def future_leaves_theta_k(traj) -> bool:
    """True when some θ*_{k+l} (l >= 1, used by the QP) lies outside Θ_k itself: the dilation of the
    predicted sets (26) was needed on this run (not vacuous)."""
    return not predicted_sets_contain_future(traj, stages_of=lambda r: np.tile(r.h_theta, (traj.problem.N, 1))).passed


def minmax_cost(design, problem, z, alpha, v, reduce=np.max) -> float:
    """(19) from a recorded decision: Σ_{l<N} max_j (‖x^j_l‖²_Q + ‖u^j_l‖²_R) + max_j ‖x^j_N‖²_P,
    x^j_l = z_l + α_l x^j (x^j the vertices of X0), u^j_l = K x^j_l + v_l. ``reduce`` replaces the max
    over vertices (negative controls)."""
    Xv = np.asarray(design.X0_vertices, float)
    K, P = np.asarray(design.K, float), np.asarray(design.P, float)
    z, alpha, v = np.asarray(z, float), np.asarray(alpha, float), np.asarray(v, float)
    N = len(v)
    X = z[:, None, :] + alpha[:, None, None] * Xv[None, :, :]           # (N+1, nv, n)
    U = X[:N] @ K.T + v[:, None, :]                                   # (N, nv, m)
    stage = np.einsum("ljn,nm,ljm->lj", X[:N], problem.Q, X[:N]) + np.einsum("ljn,nm,ljm->lj", U, problem.R, U)
    terminal = np.einsum("jn,nm,jm->j", X[N], P, X[N])
    return float(np.sum(reduce(stage, axis=1)) + reduce(terminal))


@second_method("cost_value")  # of a min–max run
def minmax_cost_matches(traj, formula=None, cost_of=None) -> CheckResult:
    """record.cost equals (19) evaluated by numpy from the recorded z, α, v at every step.
    ``formula`` (a function of (design, problem, z, alpha, v)) and ``cost_of(record)`` override the
    evaluation and the recorded cost (negative controls)."""
    formula = formula or minmax_cost
    worst, where = np.inf, "no optimal step"
    for r in traj.records:
        if r.status is not SolveStatus.OPTIMAL:
            continue
        J = formula(traj.design, traj.problem, r.z, r.alpha, r.v)
        cost = r.cost if cost_of is None else cost_of(r)
        m = -abs(cost - J) / max(1.0, abs(J))
        if m < worst:
            worst, where = m, f"step {r.k}: record.cost {cost!r}, numpy (19) {J!r}"
    return judge("(19) cost", "record.cost = Σ_l max_j stage_j + max_j terminal_j, eq. (19)", worst, COST_REL_TOL,
                 f"−relative error {where}")


def window_gram(u: np.ndarray, k: int, dim: int, window: int) -> np.ndarray | None:
    """Σ_{j=k−window+1}^{k} ū_j ū_jᵀ, ū_j = [u_j; u_{j−1}; …; u_{j−dim+1}] (None without the history)."""
    u = np.asarray(u, float).reshape(-1)
    first = k - window + 1 - (dim - 1)
    if first < 0 or k >= len(u):
        return None
    stacked = np.array([[u[j - i] for i in range(dim)] for j in range(k - window + 1, k + 1)])
    return stacked.T @ stacked


def applied_inputs(traj) -> np.ndarray:
    """u_0, u_1, … (m = 1) of the run, including the input of a final record that was computed but
    not applied (simulate records a step at x_T): traj.u, extended by record.u where it is longer."""
    u = list(np.asarray(traj.u, float)[:, 0])
    for r in traj.records:
        if r.k >= len(u) and r.u is not None and r.k == len(u):
            u.append(float(np.asarray(r.u)[0]))
    return np.array(u)


def pe_realised(traj) -> list[tuple[int, str, float, float]]:
    """(k, status, realised λ_min, recorded level) for every step whose status enforces a level:
    "enforced" (dim n + 1), "enforced_necessary" (Σ_window u_j², dim 1), "enforced_partial" (pe_dim)."""
    P, n = traj.options.pe_window, traj.problem.n
    u = applied_inputs(traj)
    out = []
    for r in traj.records:
        if not r.pe_status.startswith("enforced"):
            continue
        dim = {"enforced": n + 1, "enforced_necessary": 1}.get(r.pe_status, r.pe_dim)
        level = r.pe_level if r.pe_level is not None else np.nan
        G = window_gram(u, r.k, int(dim) if dim is not None else 0, P) if dim else None
        lam = float(np.linalg.eigvalsh(G)[0]) if G is not None else -np.inf
        out.append((r.k, r.pe_status, lam, float(level)))
    return out


@second_method("pe_level")
def pe_levels_met(traj, realised=None) -> CheckResult:
    """At every enforced step the realised window Gram of the trajectory's inputs has λ_min >=
    record.pe_level (up to PE_LEVEL_TOL); ``realised`` overrides :func:`pe_realised` (negative controls)."""
    rows = pe_realised(traj) if realised is None else realised
    worst, where = np.inf, "no enforced step"
    for k, status, lam, level in rows:
        m = (lam - level) / max(1.0, abs(level)) if np.isfinite(level) else -np.inf
        if m < worst:
            worst, where = m, f"step {k} ({status}): λ_min {lam!r}, record.pe_level {level!r}"
    return judge("PE level", "λ_min(window Gram) >= record.pe_level at every enforced step", worst, PE_LEVEL_TOL, where)


#: Inputs of a PE run that never enforced the constraint vs the run without PE: the same QPs (20) on
#: the same data, so only solver non-determinism could separate them (none observed: 0.0).
SAME_INPUT_TOL = 1e-8


def without_pe(case: Section4Case) -> Section4Case:
    """The same case with the PE option off."""
    return dataclasses.replace(case, options=dataclasses.replace(case.options, pe_window=None),
                               labels=dict(case.labels, option="pe_off"))


def same_inputs(traj, reference) -> CheckResult:
    """docs/explanation/paper.md §8 fallback: a step where no input meets both (20) and the PE constraint solves (20) alone,
    so a run that never enforced PE applies the inputs of the run without PE."""
    if traj.stop_reason != reference.stop_reason or len(traj.u) != len(reference.u):
        return judge("PE fallback = (20) alone", "a run without enforced PE steps equals the run without PE",
                     -np.inf, SAME_INPUT_TOL, f"stop {traj.stop_reason!r} after {len(traj.u)} steps vs "
                     f"{reference.stop_reason!r} after {len(reference.u)}")
    diff = float(np.max(np.abs(traj.u - reference.u))) if len(traj.u) else 0.0
    return judge("PE fallback = (20) alone", "a run without enforced PE steps equals the run without PE", -diff,
                 SAME_INPUT_TOL, "margin = −max_k |u_k − u_k(no PE)|")


@second_method("pe_bounds")
def pe_bounds_respected(traj, bounds_of=None) -> CheckResult:
    """u_k within record.pe_bounds at every step that records bounds; enforced steps record bounds.
    (The status set itself is not checked: it may grow while the PE rule evolves.)"""
    worst, where = np.inf, "no bounds recorded"
    for r in traj.records:
        b = r.pe_bounds if bounds_of is None else bounds_of(r)
        if r.pe_status.startswith("enforced") and b is None:
            return judge("PE bounds", "enforced steps record their bounds", -np.inf, PE_BOUND_TOL, f"step {r.k}")
        if b is None or r.u is None:
            continue
        lo, hi = b
        u = float(r.u[0])
        m = min((u - lo) / max(1.0, abs(lo)) if np.isfinite(lo) else np.inf,
                (hi - u) / max(1.0, abs(hi)) if np.isfinite(hi) else np.inf)
        if m < worst:
            worst, where = m, f"step {r.k}: u {u!r} in [{lo!r}, {hi!r}]"
    return judge("PE bounds", "u_k within record.pe_bounds", worst, PE_BOUND_TOL, where)


def pe_binding_steps(traj) -> int:
    """Enforced steps at which the PE constraint binds (λ_min within BINDING_REL of the level)."""
    return sum(lam <= level * (1 + BINDING_REL) + 1e-12 for _, _, lam, level in pe_realised(traj))


def tampered(traj, **record_changes) -> Trajectory:
    """A copy of ``traj`` with every record's attributes changed by functions record -> value."""
    out = copy.copy(traj)
    out.records = []
    for r in traj.records:
        r2 = copy.copy(r)
        for name, fn in record_changes.items():
            setattr(r2, name, fn(r))
        out.records.append(r2)
    return out


@dataclass
class OptionCoverage:
    """Per (option, backend) counts of runs with each feature (for the minimum-coverage assertions)."""

    runs: int = 0
    counts: dict = field(default_factory=dict)

    def add(self, flags: dict[str, bool]) -> None:
        self.runs += 1
        for k, v in flags.items():
            self.counts[k] = self.counts.get(k, 0) + int(bool(v))

    def fraction(self, name: str) -> float:
        return self.counts.get(name, 0) / self.runs if self.runs else float("nan")

    def line(self) -> str:
        return f"{self.runs} runs: " + ", ".join(f"{k} {self.fraction(k):.2f}" for k in sorted(self.counts))
