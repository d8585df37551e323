"""Seeded bugs (mutants) and a runner that checks that the property checks catch them.

Each mutant is a context manager that monkeypatches the real code for the duration of a run
(nothing is edited on disk): the controller's methods (``AdaptiveMPC``), the data handed to the
backend's tube QP (``TubeMPCData``), the offline design seen by the controller, or a constraint
of the Drake programs (removed by its description just before the solve). The runner simulates
targeted scenarios (boundary initial states, vertex disturbances, θ* at a vertex, several online
options) under each mutant and reports which claims fail.

Mutants marked ``breaks=False`` cannot violate any claim: they only make the controller more
conservative or change its performance; the runner reports them as "not caught (expected)".
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field, replace
from unittest.mock import patch

import numpy as np

from amcp_drake.model.check_result import CheckResult
from amcp_drake.model.examples import lorenzen2019_spec
from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem import DesignOptions, Problem, ProblemSpec
from amcp_drake.model.status import SolveStatus
from amcp_drake.offline.design import design
from amcp_drake.online import controller as controller_module
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.simulate import disturbance_sequence

from . import claims
from .cases import Case, run
from .feasible import TubeGeometry, max_ray_length
from .strategies import BOUNDARY_BACKOFF


# -- patch helpers ---------------------------------------------------------------------------------
@contextmanager
def _after_init(change: Callable[[AdaptiveMPC], None]) -> Iterator[None]:
    """Run ``change(controller)`` at the end of every AdaptiveMPC.__init__."""
    original = AdaptiveMPC.__init__

    def init(self, *args, **kwargs):
        original(self, *args, **kwargs)
        change(self)

    with patch.object(AdaptiveMPC, "__init__", init):
        yield


def _tube_data(**edits: Callable[[np.ndarray], np.ndarray]) -> AbstractContextManager:
    """Edit fields of the TubeMPCData given to the backend (both backends) and rebuild the QP."""

    def change(ctrl: AdaptiveMPC) -> None:
        ctrl.data = replace(ctrl.data, **{k: f(np.asarray(getattr(ctrl.data, k))) for k, f in edits.items()})
        ctrl.mpc = ctrl.backend.tube_mpc(ctrl.data)

    return _after_init(change)


def _qp_inputs(edit: Callable[[AdaptiveMPC, np.ndarray, np.ndarray, np.ndarray], tuple]) -> AbstractContextManager:
    """Rewrite the (x_k, h_θk, θ̂_k) handed to the tube QP at every step (both backends)."""

    def change(ctrl: AdaptiveMPC) -> None:
        solve = ctrl.mpc.solve

        def mutated(x, h_theta, theta_hat, H_theta=None, **kwargs):  # kwargs: u0_bounds, refine
            return solve(*edit(ctrl, x, h_theta, theta_hat), H_theta, **kwargs)

        ctrl.mpc.solve = mutated

    return _after_init(change)


def _deviation_rows() -> str:
    """The description of the Drake plain form's rows that define the tube centres' deviations e_l (imported on use)."""
    from amcp_drake.backends.drake_tube import NOMINAL_DEVIATION_FORM

    return NOMINAL_DEVIATION_FORM


@contextmanager
def _drop_drake_constraint(description: str) -> Iterator[None]:
    """Remove every Drake constraint with this description just before it is solved."""
    from amcp_drake.backends import drake_, set_update_vertices

    original = drake_._Solver.solve

    def solve(self, prog, extra_options=None):
        for binding in list(prog.GetAllConstraints()):
            if binding.evaluator().get_description() == description:
                prog.RemoveConstraint(binding)
        return original(self, prog, extra_options)

    # the Drake backend answers (9) by vertices where it can: the LP, and with it this
    # mutant, would then never run; the mutant forces the LP so that it mutates what it names
    with patch.object(drake_._Solver, "solve", solve), \
            patch.object(set_update_vertices.VertexSetUpdate, "solve", lambda self, *args: None):
        yield


def _scaled_delta(H: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The controller's row scaling and margin of Δ_k (so mutants differ only in their bug)."""
    norms = np.linalg.norm(H, axis=1)
    keep = norms >= controller_module.DELTA_ROW_MIN_NORM
    return H[keep] / norms[keep, None], h[keep] / norms[keep] + controller_module.DELTA_MARGIN


def _delta_sign_error(self, s, x_prev, u_prev, x):
    """Δ_k with d_k = x_k − A0 x_{k−1} − B0 u_{k−1} (the sign of (6) flipped)."""
    pr = self.problem
    D = pr.regressor(x_prev, u_prev)
    d = x - pr.A0 @ x_prev - pr.B0 @ u_prev
    return _scaled_delta(-pr.H_w @ D, 1.0 + pr.H_w @ d)


def _delta_regressor_now(self, s, x_prev, u_prev, x):
    """Δ_k with the regressor D(x_k, u_{k−1}) (taken one step late)."""
    pr = self.problem
    D = pr.regressor(x, u_prev)
    d = pr.A0 @ x_prev + pr.B0 @ u_prev - x
    return _scaled_delta(-pr.H_w @ D, 1.0 + pr.H_w @ d)


def _lms(sign: float = 1.0, project: bool = True, regressor_now: bool = False):
    """A projected LMS (12) with a seeded bug: gain sign, no projection, or D(x_k, u_{k−1})."""

    def update(self, s, x_prev, u_prev, x, record):
        pr = self.problem
        D = pr.regressor(x if regressor_now else x_prev, u_prev)
        x_pred = pr.A_of(s.theta_hat) @ x_prev + pr.B_of(s.theta_hat) @ u_prev
        theta_tilde = s.theta_hat + sign * self.design.mu * D.T @ (x - x_pred)
        record.theta_tilde = theta_tilde
        record.projection_status = SolveStatus.OPTIMAL
        if not project or np.all(pr.H_theta @ theta_tilde <= pr.h_theta):
            s.theta_hat = theta_tilde
            return True
        result = self.backend.project(theta_tilde, pr.H_theta, pr.h_theta)
        record.projection_status = result.status
        if result.status is SolveStatus.OPTIMAL:
            s.theta_hat = np.asarray(result.theta, float)
        return result.status is SolveStatus.OPTIMAL  # AdaptiveMPC.step goes on when True

    return update


def _update_from_prior(method):
    """LP (9) fed h_θ0 instead of h_{θ,k−1} (the recursion of (9) lost)."""

    def update(self, s, H_delta, h_delta, record):
        s.h_theta = np.array(self.design.h_theta0)
        return method(self, s, H_delta, h_delta, record)

    return update


def _skip_update(self, s, H_delta, h_delta, record):
    record.set_status = SolveStatus.OPTIMAL
    return True  # AdaptiveMPC.step goes on when True


# -- the mutants ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Mutant:
    """A seeded bug. ``breaks``: whether it can violate a claim; ``backends``: where it applies."""

    name: str
    bug: str
    patch: Callable[[], AbstractContextManager]
    breaks: bool = True
    backends: tuple[str, ...] = ("drake", "cvxpy")
    why_not: str = ""


MUTANTS: list[Mutant] = [
    Mutant("tube_lambda_nonneg_dropped", "Λ >= 0 dropped from (15c)-(15d) (the tube QP's multipliers)",
           lambda: _drop_drake_constraint("Lambda >= 0"), backends=("drake",)),
    Mutant("tube_centre_deviation_dropped", "the rows e_l = z_{l+1} − A_cl(0) z_l − B_0 v_l dropped from the Drake "
           "plain form ((15c) then binds nothing)", lambda: _drop_drake_constraint(_deviation_rows()),
           backends=("drake",)),
    Mutant("set_update_lambda_nonneg_dropped", "Λ >= 0 dropped from the set-membership LP (9)",
           lambda: _drop_drake_constraint("(9) Lambda >= 0"), backends=("drake",)),
    Mutant("x_k_not_in_first_tube_set", "(15b) x_k ∈ X_{0|k} dropped", lambda: _drop_drake_constraint("(15b) x_k in X_0|k"),
           backends=("drake",)),
    Mutant("w_bar_zero", "w̄ = 0 in (15c): the tube ignores the disturbance",
           lambda: _tube_data(w_bar=np.zeros_like)),
    Mutant("f_bar_dropped", "f̄ = 0 in (15a): constraints imposed on the tube centres only",
           lambda: _tube_data(f_bar=np.zeros_like)),
    Mutant("terminal_constraint_dropped", "(z_N, α_N) ∈ X_f dropped (H_T = 0, h_T = 0)",
           lambda: _tube_data(H_T=np.zeros_like, h_T=np.zeros_like)),
    Mutant("point_estimate_in_tube", "the tube uses the singleton {θ̂_k} instead of Θ_k (h = H_θ θ̂_k)",
           lambda: _qp_inputs(lambda c, x, h, t: (x, c.data.H_theta @ t, t))),
    Mutant("delta_sign_error", "sign error in Δ_k: d_k = x_k − A0 x_{k−1} − B0 u_{k−1}",
           lambda: patch.object(AdaptiveMPC, "_delta", _delta_sign_error)),
    Mutant("delta_regressor_wrong_step", "Δ_k built with the regressor D(x_k, u_{k−1}) instead of D(x_{k−1}, u_{k−1})",
           lambda: patch.object(AdaptiveMPC, "_delta", _delta_regressor_now)),
    Mutant("lms_sign_flipped", "projected LMS (12) with θ̃ = θ̂ − μ Dᵀ(x − x̂)",
           lambda: patch.object(AdaptiveMPC, "_update_estimate", _lms(sign=-1.0))),
    Mutant("lms_regressor_wrong_step", "LMS (12) with D(x_k, u_{k−1})",
           lambda: patch.object(AdaptiveMPC, "_update_estimate", _lms(regressor_now=True))),
    Mutant("mu_far_above_11", "μ 100 times the bound of (11)",
           lambda: _after_init(lambda c: setattr(c, "design", replace(c.design, mu=100.0 * c.design.mu)))),
    Mutant("projection_skipped", "θ̂_k = θ̃_k without the projection Π_Θ of (12)",
           lambda: patch.object(AdaptiveMPC, "_update_estimate", _lms(project=False))),
    Mutant("set_update_from_prior", "LP (9) with h_θ0 in place of h_{θ,k−1} (the update forgets Θ_{k−1})",
           lambda: patch.object(AdaptiveMPC, "_update_set", _update_from_prior(AdaptiveMPC._update_set))),
    Mutant("set_update_skipped", "Θ_k is never updated (Θ_k = Θ_0)",
           lambda: patch.object(AdaptiveMPC, "_update_set", _skip_update), breaks=False,
           why_not="conservative: Θ_0 ⊇ Θ_k keeps every claim true (the robust, non-adaptive baseline)"),
    Mutant("cost_with_prior_estimate", "the cost (17)-(18) uses θ̂_0 instead of θ̂_k",
           lambda: _qp_inputs(lambda c, x, h, t: (x, h, c.problem.theta_hat0)), breaks=False,
           why_not="performance only: the constraints (15) do not involve θ̂_k, the LMS still runs"),
]


# -- targeted scenarios -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Scenario:
    """A named closed-loop experiment for the mutant runner; ``zero_from`` enables Corollary 16."""

    name: str
    case: Case
    long: bool = False


#: State box for μ of Example 1 in the targeted scenarios (see targeted_scenarios).
MU_BOX_EXAMPLE1 = 16.0


def _boundary_x0(problem: Problem, offline, direction) -> np.ndarray:
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    geo = TubeGeometry.build(problem, offline, offline.theta_vertices)
    return (1.0 - BOUNDARY_BACKOFF) * max_ray_length(geo, d) * d


def _small_polytopic_problem() -> ProblemSpec:
    """n = 2, m = 1, p = 2: Θ a box cut by a half-plane, W a box cut by a half-plane, Z a state box,
    an input box and one mixed row (hand-written, in the class of the generator)."""
    H_theta = np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [0.6, 0.8]])
    h_theta = np.array([1.0, 1.0, 1.0, 1.0, 0.9])
    H_w = np.array([[1, 0], [0, 1], [-1, 0], [0, -1], [0.7071, 0.7071]]) / np.array([[0.05], [0.05], [0.05], [0.05], [0.05]])
    F = np.array([[1 / 3, 0], [0, 1 / 3], [-1 / 3, 0], [0, -1 / 3], [0, 0], [0, 0], [0.2, 0.3]])
    G = np.array([[0.0], [0.0], [0.0], [0.0], [1.0], [-1.0], [0.3]])
    problem = Problem(A0=[[0.8, 0.3], [-0.2, 0.7]], B0=[[0.2], [0.8]],
                      A=[[[0.05, 0.0], [0.02, 0.03]], [[0.0, 0.03], [-0.02, 0.0]]], B=[[[0.0], [0.04]], [[0.03], [0.0]]],
                      H_w=H_w, H_theta=H_theta, h_theta=h_theta, F=F, G=G, Q=np.eye(2), R=[[0.5]], N=6,
                      theta_hat0=[0.0, 0.0], name="mutant-target")
    return ProblemSpec(problem, DesignOptions(x0_template="mrpi", x0_facets=8))


def targeted_scenarios(steps: int = 30, seed: int = 0) -> list[Scenario]:
    """Example 1 from boundary states with θ* inside and at a vertex of Θ; a hand-written polytopic
    problem with θ* on a facet (moving window, projection onto Θ_k) and at vertices (one run with
    w = 0); vertex disturbances otherwise (explicit ``seed``); and one Example 1 run whose
    disturbance stops after 10 steps (Corollary 16, finite gain)."""
    out = []
    ex = lorenzen2019_spec()
    # Example 1's Z is unbounded in x1 and its μ holds only on |x_i| <= 3 (docs/explanation/paper.md §9); the feasible
    # set of (20) reaches |x| ≈ 15 along the paper's x0 direction, so the targeted runs use μ
    # computed on |x_i| <= MU_BOX_EXAMPLE1 to keep Lemma 5's precondition (11) true along them.
    paper, paper_design = ex, design(ex.problem, ex.design)
    ex = ProblemSpec(ex.problem, replace(ex.design, mu_state_bound=MU_BOX_EXAMPLE1), ex.scenario)
    ex_design = design(ex.problem, ex.design)
    small = _small_polytopic_problem()
    small_design = design(small.problem, small.design)
    specs = [
        ("example1 boundary, θ* of the paper", ex, ex_design, [2.0, 3.0], ex.scenario.theta_star, OnlineOptions()),
        ("example1 boundary, θ* at a vertex", paper, paper_design, [-1.0, -0.2], [1.0, -1.0, 1.0],
         OnlineOptions(projection="Theta_k")),
        ("polytopic, window, θ* on a facet", small, small_design, [1.0, -1.0], [0.6, 0.675],
         OnlineOptions(update="window", window=4, projection="Theta_k")),
        # θ̃ leaves Θ here (μ close to (11), θ* at a vertex): catches a missing projection
        ("polytopic, θ* at a vertex", small, small_design, [1.0, 1.0], [1.0, -1.0], OnlineOptions()),
        # w = 0 removes the slack Σ‖w‖² of Lemma 5, and the rotating A0 turns D(x_k, ·) away from
        # D(x_{k-1}, ·): catches an LMS step with the regressor of the wrong time
        ("polytopic, θ* at a vertex, w = 0", small, small_design, [1.0, -1.0], [-1.0, 1.0], OnlineOptions()),
    ]
    for name, spec, offline, direction, theta_star, options in specs:
        pr = spec.problem
        x0 = _boundary_x0(pr, offline, direction)
        kind = "zero" if name.endswith("w = 0") else "vertices"
        w = disturbance_sequence(pr, kind, steps, seed)
        case = Case(spec=spec, design=offline, x0=x0, theta_star=np.asarray(theta_star, float), w=w,
                    options=options, labels={"scenario": name, "disturbance": kind}, seed=seed)
        out.append(Scenario(name, case))
    pr = ex.problem
    w = disturbance_sequence(pr, "vertices", 70, seed)
    w[10:] = 0.0
    case = Case(spec=ex, design=ex_design, x0=_boundary_x0(pr, ex_design, [2.0, 3.0]),
                theta_star=np.asarray(ex.scenario.theta_star, float), w=w, options=OnlineOptions(),
                labels={"scenario": "example1, w = 0 after 10 steps", "disturbance": "vertices"}, seed=seed,
                zero_from=10)
    out.append(Scenario("example1, w = 0 after step 10", case, long=True))
    return out


def check_all(traj, case: Case, long: bool) -> dict[str, CheckResult]:
    """Every claim check on one run (Assumption 11 on its design; Corollary 16 and (22) on long runs), and
    whether the backend's answers passed the answer checks (a mutant that only breaks answers the
    controller then replaces by a checked fallback is caught there, not by a claim)."""
    results = {
        "Theorem 14 (i)": claims.recursive_feasibility(traj),
        "Theorem 14 (ii) θ*": claims.theta_star_in_sets(traj),
        "Theorem 14 (ii) θ̂": claims.theta_hat_in_prior(traj),
        "Theorem 14 (iii)": claims.constraints_satisfied(traj),
        "Lemma 3": claims.set_inclusions(traj),
        "(11)": claims.lms_precondition(traj),
        "Lemma 5": claims.lms_inequality(traj),
        "Proposition 9": claims.prediction_tube(traj),
        "Assumption 11": claims.terminal_set_invariance(traj.problem, traj.design),
        "answer checks": claims.backend_answers(traj),
    }
    if long:
        results["Corollary 16"] = claims.convergence_after_disturbance(traj, case.zero_from)
        results["(22) finite gain"] = claims.finite_gain(traj)
    return results


@dataclass
class MutantReport:
    """Which claims failed under a mutant, per scenario."""

    mutant: Mutant
    backend: str
    failures: dict[str, list[str]] = field(default_factory=dict)  # claim -> scenarios where it failed
    errors: list[str] = field(default_factory=list)

    @property
    def caught(self) -> bool:
        return bool(self.failures)

    @property
    def verdict(self) -> str:
        if self.mutant.breaks:
            return "caught" if self.caught else "MISSED"
        return "flagged (unexpected)" if self.caught else "not caught (expected: cannot break a claim)"

    @property
    def ok(self) -> bool:
        return self.caught if self.mutant.breaks else True


def run_scenarios(backend: str, scenarios: list[Scenario]) -> dict[str, list[str]]:
    """Run the scenarios (under whatever patches are active) -> claim -> failing scenario names."""
    failures: dict[str, list[str]] = {}
    for sc in scenarios:
        traj = run(sc.case, backend)
        for claim, result in check_all(traj, sc.case, sc.long).items():
            if not result.passed:
                failures.setdefault(claim, []).append(sc.name)
    return failures


def run_mutants(backend: str = "drake", mutants: list[Mutant] | None = None,
                scenarios: list[Scenario] | None = None, progress: Callable[[str], None] | None = None
                ) -> tuple[dict[str, list[str]], list[MutantReport]]:
    """The baseline (no mutant: must pass everything) and one report per applicable mutant."""
    scenarios = scenarios or targeted_scenarios()
    baseline = run_scenarios(backend, scenarios)
    reports = []
    for m in mutants or MUTANTS:
        if backend not in m.backends:
            continue
        if progress:
            progress(m.name)
        report = MutantReport(m, backend)
        try:
            with m.patch():
                report.failures = run_scenarios(backend, scenarios)
        except Exception as exc:  # noqa: BLE001 - a crash under a mutant is reported, not hidden
            report.errors.append(f"{type(exc).__name__}: {exc}")
            report.failures = {"(crashed)": [str(exc)[:120]]}
        reports.append(report)
    return baseline, reports


def print_report(backends: list[str]) -> bool:
    """Run the mutants on each backend and print the table ``amcp verify --mutants`` shows; True
    when the unmutated baseline passes and every claim-breaking mutant is caught."""
    scenarios = targeted_scenarios()
    ok = True
    for backend in backends:
        print(f"\nmutants on the {backend} backend ({len(scenarios)} targeted scenarios):", flush=True)
        baseline, reports = run_mutants(backend, scenarios=scenarios)
        if baseline:
            ok = False
            print(f"  baseline (no mutant) FAILS: {baseline}; mutant results are not meaningful")
        print(f"  {'mutant':34s} {'verdict':12s} caught by")
        for r in reports:
            verdict = {"caught": "caught", "MISSED": "MISSED"}.get(r.verdict, "conservative" if not r.caught else "flagged")
            by = ", ".join(sorted(r.failures)) if r.caught else (r.mutant.why_not or "-")
            print(f"  {r.mutant.name:34s} {verdict:12s} {by}", flush=True)
            ok = ok and r.ok
    return ok


def main(argv: list[str] | None = None) -> int:
    """``python -m amcp_properties.mutants BACKEND...``: exit 0 when every claim-breaking mutant is
    caught (``amcp verify --mutants`` runs this in a child process, so that the library never
    imports the test package)."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m amcp_properties.mutants", description=main.__doc__)
    parser.add_argument("backends", nargs="+", choices=("drake", "cvxpy"))
    return 0 if print_report(parser.parse_args(argv).backends) else 1


if __name__ == "__main__":
    raise SystemExit(main())
