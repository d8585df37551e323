"""Section 4 options on RANDOM systems, both backends: the min-max cost (19) (Remark 13),
persistent excitation (docs/explanation/paper.md §8) and time-varying parameters (Section 4.1, Proposition 19).

Generators (:mod:`amcp_properties.section4`) reuse the suite's designed problems, θ* and
boundary initial states; every check is numpy only against the recorded StepRecord contract.

* min-max: every QP optimal (recursive feasibility), the tube constraints of 𝔻(x_k, Θ_k) re-checked
  at the recorded decision (claims.recursive_feasibility), (x_k, u_k) ∈ Z, θ* ∈ Θ_k, and
  record.cost = (19) evaluated from the recorded z, α, v (relative 1e-6).
* PE (m = 1): runs complete with every QP optimal, (x, u) ∈ Z, λ_min of the realised window Gram
  >= record.pe_level at "enforced" steps (dimension n + 1), Σ_window u_j² >= record.pe_level at
  "enforced_necessary" steps (and the pe_dim Gram at "enforced_partial"), u_k within record.pe_bounds;
  a run whose level is unattainable (every step "inactive" or "fallback") applies exactly the
  inputs of the run without PE (docs/explanation/paper.md §8: the fallback solves (20) alone).
* robust baseline (update "none", Θ_k ≡ Θ_0, θ̂_k ≡ θ̂0): every QP optimal, (x, u) ∈ Z, nothing
  updated; and what adaptation buys, as a claim: Θ_k ⊆ Θ_0 ⇒ 𝔻(x, Θ_0) ⊆ 𝔻(x, Θ_k), so wherever
  (20) on Θ_0 is feasible (probed at recorded x_k and along their rays to the robust feasible
  boundary) (20) on Θ_k is feasible with no larger optimum. Random problems use δ ∈ [0.08, 0.3]
  (parametric uncertainty larger than the suite's default); a strict gain is still rare there (3 of
  24 runs: their Z box ends the ray), so Example 1 is checked too, where it is strict.
* time-varying: θ*_k drifting at the full rate d_θ, reflected at the faces of Θ; θ*_k ∈ Θ_k
  (Proposition 19), θ*_{k+l} ∈ Θ_{l|k} (record.h_theta_stages, (26)), (x, u) ∈ Z, every QP optimal.

Negative controls (one test per option): a wrong cost formula and a tampered record.cost are
rejected; a tampered pe_level (at steps where the constraint binds) and tampered pe_bounds are
rejected; undilated predicted sets and a tampered Θ_k are rejected.

Coverage per (option, backend) is printed with the suite's coverage table (labels) and asserted
by test_section4_coverage_is_not_vacuous (thresholds MIN_COVERAGE, ci profile).

Runtime (ci profile: 40 examples per option and backend, 12-step runs, 18-step PE
runs, N <= 6; 2-core machine; both backends, this file alone): 95 s at 24 examples (pytest), of which
~35 s are the baseline runs and probes (the robust ray length is one vertex-form LP,
feasible.max_ray_length); 179 s wall, 118 s CPU at 40 on a loaded machine; the
negative controls reuse the runs (Section4Runner).

Why 40: Hypothesis' examples are correlated (the ci seed's 24 time-varying examples held
five near-copies), and after the units-free gain LMI changed which generated problems design, the ci
seed's 24 time-varying runs needed the dilation (26) in 4 (17 % < the 20 % minimum), while six other
seeds gave 33-75 % (mean 51 %). At 40 examples the ci seed gives 38 % (time-varying), and every
other option's coverage passes on both backends.

Coverage measured (ci, both backends alike; at 24 examples): PE 24 runs: "enforced" reached in 71 %,
"enforced_necessary" in 58 %, the PE constraint binding (λ_min = level) in 75 %, Z active
(max(Fx+Gu) > 0.95) in 88 %, fallback in 25 % (the unattainable regime of the generator; before it
was added, fallback was never reached). Time-varying 24 runs: θ*_k within 0.05 of ∂Θ_k in 88 %,
θ*_{k+l} outside Θ_k itself (the dilation (26) needed) in 50 %, Z active in 92 %. Min-max: Z active
and α > 0 in every run checked.

Min-max history: with the first (rotated-cone) form of (19) the min-max QP ended
"optimal_inaccurate" on 18 of 38 generated cases (Drake) and 1 of 30 (cvxpy), and
test_minmax_cost_closed_loop failed on both backends (CI of stop 10). Fixed in the library (second-
order-cone form and the Clarabel retry ladder, docs/decisions.md "Min–max cost (19)"), not here:
the test's requirement (every QP optimal) is unchanged.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import event, given, note, settings

from amcp_drake.model.status import SolveStatus
from amcp_drake.studies.random_problems import theta_shrank

from . import nversion, profiles, section4
from .coverage import RunFeatures
from .failures import require

#: Set to print every example's claim margins (to measure tolerances).
DEBUG_ENV = "AMCP_SECTION4_DEBUG"
S = section4.sizes()
MINMAX = section4.minmax_cases(steps=S.steps, max_N=S.max_N)
PE = section4.pe_cases(steps=S.pe_steps, max_N=S.max_N)
TIME_VARYING = section4.time_varying_cases(steps=S.steps, max_N=S.max_N)
BASELINE = section4.baseline_cases(steps=S.steps, max_N=S.max_N)
RUN = section4.RUNNER
#: (option, backend) -> OptionCoverage, filled by the property tests, asserted at the end.
STATS: dict[tuple[str, str], section4.OptionCoverage] = {}
#: Minimum fractions of runs per option (ci and thorough): the properties are not vacuous.
MIN_COVERAGE = {
    "minmax": {"Z_active": 0.25, "alpha_positive": 0.75},
    "pe": {"pe_enforced": 0.25, "pe_any_enforced": 0.5, "pe_binding": 0.25, "pe_fallback": 0.05},
    "time_varying": {"theta_near_boundary": 0.25, "dilation_needed": 0.2},
    # random problems rarely show a strict gain (measured 3 of 24 runs): their Z box, not the tube's
    # parametric growth, ends the feasible ray; Example 1 shows it deterministically (test below)
    "baseline": {"theta_shrunk": 0.5, "cheaper": 0.04},
}


def examples(test):
    return profiles.shared_seed(settings(max_examples=S.examples)(test))


def _observe(case, traj, test, backend, coverage, option, flags):
    """Coverage: the suite's recorder (labels carry the option's flags), events, and STATS."""
    flags = dict(flags, completed=traj.stop_reason == "completed")
    zmax = section4.z_margin(traj)
    dist = section4.theta_distances(traj)
    labels = dict(case.labels, **{k: str(bool(v)) for k, v in flags.items()})
    f = RunFeatures(constraints_active=bool(zmax >= 1.0 - 1e-3), max_constraint=zmax,
                    theta_shrank=theta_shrank(traj),
                    theta_star_distance=max(float(np.min(dist)), 0.0) if len(dist) else np.inf,
                    completed=flags["completed"], labels=labels)
    coverage.record(f"{test}[{backend}]", f)
    STATS.setdefault((option, backend), section4.OptionCoverage()).add(flags)
    for k, v in flags.items():
        event(f"{option}: {k} = {bool(v)}")
    pr = case.problem
    note(f"case: n={pr.n} m={pr.m} p={pr.p} N={pr.N} options={case.options} labels={case.labels}")
    note(f"x0={np.array2string(case.x0, precision=6)} run: {traj.stop_reason}, {len(traj.u)} steps")


def _common(traj, test, backend, case, extra=()):
    """The shared claims, then the option's own (``extra``) on the (possibly partial) run, and
    only then "every QP optimal": a run that stops early is still checked on its recorded steps."""
    results = [*nversion.check(("state_input_constraints", "theta_star_in_Theta_k"), traj), *extra]
    if os.environ.get(DEBUG_ENV):
        print(f"[{test} {backend}] " + "; ".join(f"{r.name}: {r.margin}" for r in results))
    for result in results:
        require(result, test=test, backend=backend, case=case, traj=traj)
    require(section4.all_qps_optimal(traj), test=test, backend=backend, case=case, traj=traj)
    for result in nversion.check("recursive_feasibility", traj):
        require(result, test=test, backend=backend, case=case, traj=traj)


# -- min-max cost (19) ---------------------------------------------------------------------------------


@examples
@given(case=MINMAX)
def test_minmax_cost_closed_loop(case, backend, coverage):
    """Cost (19): recursive feasibility, (x, u) ∈ Z, θ* ∈ Θ_k, record.cost = (19) by numpy."""
    traj = RUN.run(case, backend)
    alpha_pos = any(r.alpha is not None and np.max(r.alpha) > 1e-3 for r in traj.records)
    _observe(case, traj, "test_minmax_cost_closed_loop", backend, coverage, "minmax",
             {"Z_active": section4.z_margin(traj) > 1.0 - section4.ACTIVE_MARGIN, "alpha_positive": alpha_pos})
    # record.cost is (19) of the recorded plan (amcp_drake.backends.minmax_cost); that the plan minimises
    # (19) is the certificate's KKT claim (tests/test_certify_optimality.py), not checked here
    _common(traj, "section4_minmax", backend, case, nversion.check("cost_value", traj))


def _mean_over_vertices(design, problem, z, alpha, v):
    return section4.minmax_cost(design, problem, z, alpha, v, reduce=np.mean)


def _sum_of_maxima_without_terminal(design, problem, z, alpha, v):
    z = np.asarray(z, float)
    return section4.minmax_cost(design, problem, z, alpha, v) - section4.minmax_cost(
        design, problem, z[-1:], np.asarray(alpha, float)[-1:], np.zeros((0, problem.m)))


@examples
@given(case=MINMAX)
def test_minmax_negative_controls(case, backend):
    """The cost check rejects a wrong formula (mean instead of max over the tube vertices; terminal
    term dropped) and a record.cost tampered by 1e-4 (relative)."""
    traj = RUN.run(case, backend)
    solved = [r for r in traj.records if r.cost is not None]
    if not solved:
        event("minmax negative control: no solved step")
        return
    assert not section4.minmax_cost_matches(traj, cost_of=lambda r: r.cost * (1 + 1e-4) + 1e-4).passed
    # a wrong formula is a negative control only where it differs from (19) on the recorded decisions
    # (by 10x the check's tolerance): with α > 0 but equal stage costs at every tube vertex (n = 1,
    # a symmetric tube; found by the thorough profile) the mean over the vertices equals the max
    for wrong in (_mean_over_vertices, _sum_of_maxima_without_terminal):
        if _differs_from_19(traj, wrong):
            event(f"minmax negative control: {wrong.__name__} run")
            assert not section4.minmax_cost_matches(traj, formula=wrong).passed


def _differs_from_19(traj, formula) -> bool:
    """Whether ``formula`` differs from (19) (section4.minmax_cost) by more than 10x the claim's
    tolerance at some optimal step of ``traj`` (both evaluated here, from the recorded z, α, v)."""
    for r in traj.records:
        if r.status is not SolveStatus.OPTIMAL or r.z is None:
            continue
        right = section4.minmax_cost(traj.design, traj.problem, r.z, r.alpha, r.v)
        if abs(formula(traj.design, traj.problem, r.z, r.alpha, r.v) - right) > 10 * section4.COST_REL_TOL * max(1.0, abs(right)):
            return True
    return False


# -- persistent excitation --------------------------------------------------------------------------------


@examples
@given(case=PE)
def test_persistent_excitation_closed_loop(case, backend, coverage):
    """PE (m = 1): recursive feasibility, (x, u) ∈ Z, the realised window Gram reaches
    record.pe_level at enforced steps, u_k within record.pe_bounds."""
    traj = RUN.run(case, backend)
    statuses = {r.pe_status for r in traj.records}
    _observe(case, traj, "test_persistent_excitation_closed_loop", backend, coverage, "pe",
             {"pe_enforced": "enforced" in statuses,
              "pe_any_enforced": any(s.startswith("enforced") for s in statuses),
              "pe_necessary": "enforced_necessary" in statuses, "pe_fallback": "fallback" in statuses,
              "pe_binding": section4.pe_binding_steps(traj) > 0,
              "Z_active": section4.z_margin(traj) > 1.0 - section4.ACTIVE_MARGIN})
    note(f"pe statuses: {[r.pe_status for r in traj.records]}")
    # the certificate's PE claims have nothing to check (not_run) when no step enforced PE: then the re-checks alone
    enforced = any(s.startswith("enforced") for s in statuses)
    checks = (nversion.check(("pe_level", "pe_bounds"), traj) if enforced
              else [section4.pe_levels_met(traj), section4.pe_bounds_respected(traj)])
    if statuses <= {"inactive", "fallback"}:
        # no step enforced PE: every QP was (20) alone, so the run is the run without PE
        checks.append(section4.same_inputs(traj, RUN.run(section4.without_pe(case), backend)))
    _common(traj, "section4_pe", backend, case, checks)


def _moved_past_bound(traj, k):
    """A copy of ``traj`` whose u_k is moved out of record.pe_bounds (past the finite bound it sits on)."""
    r = traj.records[k]
    lo, hi = r.pe_bounds
    u = float(r.u[0])
    delta = 0.05 * max(abs(u), 1e-3)
    near_hi = np.isfinite(hi) and (not np.isfinite(lo) or abs(u - hi) <= abs(u - lo))
    moved = hi + delta if near_hi else lo - delta
    out = section4.tampered(traj, u=lambda rec: np.array([moved]) if rec.k == k else rec.u)
    if k < len(traj.u):
        out.u = traj.u.copy()
        out.u[k] = moved
    return out


@examples
@given(case=PE)
def test_persistent_excitation_negative_controls(case, backend):
    """The PE checks reject a pe_level raised by 1e-3 (relative) at steps where the constraint binds,
    an input moved past its PE bound at a binding step, and bounds shifted to exclude the applied u_k."""
    traj = RUN.run(case, backend)
    rows = section4.pe_realised(traj)
    binding = [row for row in rows if row[2] <= row[3] * (1 + section4.BINDING_REL) + 1e-12]
    if binding:
        raised = [(k, s, lam, level * (1 + 1e-3) + 1e-6) for k, s, lam, level in binding]
        assert not section4.pe_levels_met(traj, realised=raised).passed
        # the Gram uses the applied u_k: an input moved past its PE bound (out of the recorded
        # interval, by 5 %) at a binding step is caught at one binding step at least
        assert any(not section4.pe_levels_met(_moved_past_bound(traj, k)).passed for k, *_ in binding)
    if {r.pe_status for r in traj.records} <= {"inactive", "fallback"} and len(traj.u):
        # the fallback comparison sees an input moved by 1e-6
        moved = section4.tampered(traj)
        moved.u = traj.u + 1e-6
        assert not section4.same_inputs(moved, RUN.run(section4.without_pe(case), backend)).passed
    if any(r.pe_bounds is not None for r in traj.records):
        def shifted(r):
            if r.pe_bounds is None or r.u is None:  # a step without an applied input has nothing to shift
                return None
            u = float(r.u[0])
            return (u + 1e-3, np.inf)
        assert not section4.pe_bounds_respected(traj, bounds_of=shifted).passed


# -- time-varying parameters ------------------------------------------------------------------------------


@examples
@given(case=TIME_VARYING)
def test_time_varying_parameters_closed_loop(case, backend, coverage):
    """d_θ > 0: θ*_k ∈ Θ_k (Proposition 19), θ*_{k+l} ∈ Θ_{l|k} (26), (x, u) ∈ Z, recursive feasibility."""
    seq = case.theta_seq
    rate = float(np.max(np.linalg.norm(np.diff(seq, axis=0), axis=1)))
    prior = float(np.max(case.problem.H_theta @ seq.T - case.problem.h_theta[:, None]))
    assert rate <= case.options.d_theta + 1e-12 and prior <= 1e-12, (rate, prior)  # the generator's contract
    traj = RUN.run(case, backend)
    dist = section4.theta_distances(traj)
    _observe(case, traj, "test_time_varying_parameters_closed_loop", backend, coverage, "time_varying",
             {"theta_near_boundary": len(dist) > 0 and float(np.min(dist)) <= section4.NEAR_BOUNDARY,
              "dilation_needed": section4.future_leaves_theta_k(traj),
              "Z_active": section4.z_margin(traj) > 1.0 - section4.ACTIVE_MARGIN})
    _common(traj, "section4_time_varying", backend, case, [section4.predicted_sets_contain_future(traj)])


@examples
@given(case=TIME_VARYING)
def test_time_varying_negative_controls(case, backend):
    """The membership checks reject Θ_k shrunk just past θ*_k, and predicted sets without the
    dilation (26) whenever θ* leaves Θ_k within the horizon (counted by the coverage test)."""
    traj = RUN.run(case, backend)
    if not traj.records:
        return
    dist = section4.theta_distances(traj)
    k = int(np.argmin(dist))
    H = np.asarray(traj.records[k].H_theta, float)
    shift = (dist[k] + 1e-5) * np.linalg.norm(H, axis=1)
    bad = section4.tampered(traj, h_theta=lambda r: r.h_theta - shift if r.k == k else r.h_theta)
    assert not section4.theta_star_in_theta_k(bad).passed
    if section4.future_leaves_theta_k(traj):
        undilated = lambda r: np.tile(r.h_theta, (traj.problem.N, 1))  # noqa: E731
        assert not section4.predicted_sets_contain_future(traj, stages_of=undilated).passed


# -- robust baseline (update "none") and what adaptation buys ---------------------------------------------


@examples
@given(case=BASELINE)
def test_robust_baseline_and_adaptation_never_hurts(case, backend, coverage):
    """update "none": recursive feasibility, (x, u) ∈ Z, θ* ∈ Θ_k = Θ_0, and nothing is updated. The
    adaptive run of the same case: wherever (20) on Θ_0 is feasible at (x_k, θ̂_k), (20) on Θ_k ⊆ Θ_0
    is feasible with an optimum no larger (the feasible set 𝔻(x, Θ) grows as Θ shrinks); probed at
    x_k, 2x_k and 4x_k of up to 3 steps where Θ_k shrank (larger states activate the tube constraints)."""
    robust = RUN.run(section4.robust_twin(case), backend)
    _common(robust, "section4_baseline", backend, case, [section4.baseline_is_constant(robust)])
    traj = RUN.run(case, backend)
    probes = section4.probe_theta0_vs_theta_k(traj, case, backend)
    gains = section4.strict_gains(probes)
    _observe(case, traj, "test_robust_baseline_and_adaptation_never_hurts", backend, coverage, "baseline",
             dict(gains, Z_active=section4.z_margin(robust) > 1.0 - section4.ACTIVE_MARGIN))
    require(section4.adaptation_never_hurts(probes), test="section4_baseline_monotone", backend=backend, case=case,
            traj=traj)
    if gains["cheaper"]:  # negative control: the reversed inequality is caught
        assert not section4.adaptation_never_hurts(probes, swap=True).passed


def test_adaptation_gain_on_example1(backend):
    """On Example 1 the gain is strict: at some probed state the adaptive QP (Θ_k) is feasible where
    the robust one (Θ_0) is not, or has a strictly lower optimum, and never the reverse."""
    case = section4.example1_baseline_case()
    traj = RUN.run(case, backend)
    probes = section4.probe_theta0_vs_theta_k(traj, case, backend)
    gains = section4.strict_gains(probes)
    print(f"example 1 baseline probes [{backend}]: {len(probes)} probes, {gains}")
    assert section4.all_qps_optimal(traj).passed
    assert section4.adaptation_never_hurts(probes).passed
    assert gains["only_adaptive_feasible"] or gains["cheaper"], gains
    assert not section4.adaptation_never_hurts(probes, swap=True).passed or not gains["cheaper"]


# -- coverage ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("option", sorted(MIN_COVERAGE))
def test_section4_coverage_is_not_vacuous(option, backend):
    """Runs after the property tests of the same backend (pytest groups the session-scoped backend
    parameter): each option's generated runs reached the interesting cases."""
    stats = STATS.get((option, backend))
    if stats is None or stats.runs == 0:
        pytest.skip(f"no {option} runs on {backend} in this session (property test deselected)")
    print(f"section 4 coverage {option} [{backend}]: {stats.line()}")
    low = {k: stats.fraction(k) for k, minimum in MIN_COVERAGE[option].items() if stats.fraction(k) < minimum}
    assert not low, f"{option} [{backend}] coverage below minimum: {low} ({stats.line()})"
