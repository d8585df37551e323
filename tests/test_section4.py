"""Section 4 extensions: PE (Section 4.2, docs/explanation/paper.md §8), first-input bounds, the online
section of problem files and the CLI options. Time-varying parameters are tested in
properties/amcp_properties/test_time_varying.py."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.model.options import OnlineOptions
from amcp_drake.model.problem_io import spec_from_dict, spec_to_dict
from amcp_drake.model.status import SolveStatus
from amcp_drake.online import answers
from amcp_drake.online.controller import AdaptiveMPC
from amcp_drake.online.excitation import assumption20, pe_bounds, pe_measure, pe_quadratic, theta_diameter, xi_matrix
from amcp_drake.online.simulate import Trajectory, simulate

#: eigenvalue round-off allowed when the quadratic form is compared with the window Gram
EIG_TOL = 1e-9
#: the QP's bound on u_0 may be violated by the solver's feasibility tolerance
BOUND_TOL = 1e-7
#: cost agreement of the two backends on the same bounded QP (as in compare.TOLERANCES for "cost")
COST_RTOL = 1e-5


def _window_gram(u_all, k, dim, window):
    """Independent Σ_{j=k−window+1}^{k} ū ūᵀ with ū_j = [u_j; …; u_{j−dim+1}]."""
    rows = [np.asarray(u_all[j - dim + 1:j + 1], float)[::-1] for j in range(k - window + 1, k + 1)]
    return sum(np.outer(r, r) for r in rows)


def test_pe_quadratic_matches_eigenvalues(rng):
    """a u² + b u + c >= 0 ⇔ λ_min(Σ_window ū⁽ᵈ⁾ ū⁽ᵈ⁾ᵀ) >= level (docs/explanation/paper.md §8, step 2) for the
    rung d the ladder picks, on random histories; every rung of the ladder is reached."""
    n, window, checked, dims = 2, 4, 0, set()
    for _ in range(400):
        past = rng.normal(scale=rng.uniform(0.05, 2.0), size=window - 1 + n + int(rng.integers(0, 3)))
        quad = pe_quadratic(past, n, window, 0.3)
        dims.add(quad.dim)
        for u in rng.normal(scale=2.0, size=5):
            lam = np.linalg.eigvalsh(_window_gram(np.append(past, u), len(past), quad.dim, window))[0]
            q = quad.a * u * u + quad.b * u + quad.c
            if abs(lam - quad.level) > 1e-6 and abs(q) > 1e-6:
                assert (q >= 0) == (lam >= quad.level - EIG_TOL), (q, lam, quad)
                checked += 1
    assert checked > 200
    assert dims == {1, 2, 3}


def test_pe_ladder_rung_is_attainable_and_climbs():
    """A constraint met at rung d−1 makes rung d attainable at the next step (the lower block of the
    d-dimensional Gram at k is the (d−1)-dimensional Gram at k−1): from zero excitation the full
    dimension n + 1 is reached after n + 1 steps when every enforced bound is met with equality."""
    n, window, level = 2, 4, 0.5
    u = [0.0] * (window - 1 + n)
    dims = []
    for _ in range(8):
        quad = pe_quadratic(np.array(u), n, window, level)
        dims.append(quad.dim)
        bounds = pe_bounds(quad)
        u.append(0.0 if bounds is None else (bounds[-1][0] if np.isfinite(bounds[-1][0]) else bounds[-1][1]))
    assert dims[:3] == [1, 2, 3] and set(dims[3:]) == {3}, dims
    lam = np.linalg.eigvalsh(_window_gram(np.array(u), len(u) - 1, n + 1, window))[0]
    assert lam >= level - 1e-9


def test_pe_quadratic_reads_only_the_last_window_plus_n_inputs(rng):
    """The controller keeps only the last pe_window + n inputs (its history does not grow with k): the
    constraint from that tail is the one from the whole history, to the bit."""
    n, window = 3, 4
    for length in (window - 1 + n, window + n, window + n + 1, 40):
        past = rng.normal(size=length)
        whole, tail = pe_quadratic(past, n, window, 0.3), pe_quadratic(past[-(window + n):], n, window, 0.3)
        assert tail == whole, (length, tail, whole)


def test_pe_bounds_cases():
    from amcp_drake.online.excitation import PEQuadratic

    assert pe_bounds(None) is None
    assert pe_bounds(PEQuadratic(1.0, 0.0, -0.25, (-0.5, 0.5))) == [(-np.inf, -0.5), (0.5, np.inf)]
    assert pe_bounds(PEQuadratic(-1.0, 0.0, 0.25, (-0.5, 0.5))) == [(-0.5, 0.5)]
    assert pe_bounds(PEQuadratic(1.0, 0.0, 1.0, None)) is None      # always satisfied
    assert pe_bounds(PEQuadratic(-1.0, 0.0, -1.0, None)) == []      # never satisfied


def test_assumption20(example_spec):
    pr = example_spec.problem
    holds, sv = assumption20(pr)
    assert holds and len(sv) == pr.p
    assert xi_matrix(pr).shape == (pr.p, pr.n * (pr.n + pr.m))
    dependent = pr.with_changes(A=np.stack([pr.A[0], 2 * pr.A[0], pr.A[2]]), B=np.stack([pr.B[0], 2 * pr.B[0], pr.B[2]]))
    assert not assumption20(dependent)[0]


def test_pe_measure_direct(rng):
    D = rng.normal(size=(7, 2, 3))
    lo, hi = pe_measure(D, 3)
    assert len(lo) == 5
    ev = np.linalg.eigvalsh(sum(D[k].T @ D[k] for k in range(2, 5)))
    assert lo[2] == pytest.approx(ev[0]) and hi[2] == pytest.approx(ev[-1])


def test_theta_diameter_box():
    H = np.vstack([np.eye(3), -np.eye(3)])
    assert theta_diameter(H, np.ones(6)) == pytest.approx(2 * np.sqrt(3))


@pytest.mark.parametrize("side", ["upper", "lower"])
def test_u0_bounds_both_backends(example_spec, example_design, side):
    """The optional first-input bound of the plain QP (20) holds and both backends agree on the cost."""
    pr, d = example_spec.problem, example_design
    x = np.array([0.5, 0.5])  # the unconstrained u_0 is interior to |u| <= 1 here
    costs = []
    for backend in ("drake", "cvxpy"):
        ctrl = AdaptiveMPC(pr, d, backend=backend)
        free = ctrl.mpc.solve(x, d.h_theta0, pr.theta_hat0)
        u_free = float((d.K @ x + free.v[0])[0])
        bounds = (-np.inf, u_free - 0.1) if side == "upper" else (u_free + 0.1, np.inf)
        sol = ctrl.mpc.solve(x, d.h_theta0, pr.theta_hat0, u0_bounds=bounds)
        assert sol.status is SolveStatus.OPTIMAL
        u0 = float((d.K @ x + sol.v[0])[0])
        assert bounds[0] - BOUND_TOL <= u0 <= bounds[1] + BOUND_TOL
        assert sol.cost > free.cost  # the bound cuts off the unconstrained optimum
        costs.append(sol.cost)
        again = ctrl.mpc.solve(x, d.h_theta0, pr.theta_hat0)  # bounds are not sticky
        assert again.cost == pytest.approx(free.cost, rel=1e-6)
    assert costs[0] == pytest.approx(costs[1], rel=COST_RTOL)


def test_pe_run_enforces_window_constraint(example_spec, example_design, tmp_path):
    pr, sc = example_spec.problem, example_spec.scenario
    window, level = 5, 0.2
    ctrl = AdaptiveMPC(pr, example_design, options=OnlineOptions(update="fixed", pe_window=window, pe_level=level))
    traj = simulate(ctrl, sc.x0, sc.theta_star, 25, "uniform", seed=2)
    assert traj.stop_reason == "completed"
    u = traj.u[:, 0]
    enforced = 0
    for r in traj.records[:-1]:
        if not r.pe_status.startswith("enforced"):
            continue
        quad = pe_quadratic(u[:r.k], pr.n, window, level)
        assert (r.pe_dim, r.pe_level) == (quad.dim, quad.level)
        assert (r.pe_status == "enforced") == (r.pe_dim == pr.n + 1)
        lam = np.linalg.eigvalsh(_window_gram(u, r.k, r.pe_dim, window))[0]
        assert lam >= r.pe_level - 1e-6, (r.k, lam, r.pe_level)
        lo, hi = r.pe_bounds
        assert lo - BOUND_TOL <= u[r.k] <= hi + BOUND_TOL
        enforced += 1
    assert enforced > 5
    assert len(ctrl.state.u_hist) == window + pr.n  # the history the PE constraint needs, not all 25 inputs
    # the PE records survive a save/load round trip (one-sided bounds hold ±inf)
    path = traj.save(tmp_path / "t.json")
    back = Trajectory.load(path)
    assert [r.pe_bounds for r in back.records] == [r.pe_bounds for r in traj.records]
    assert back.options == traj.options


def test_pe_needs_scalar_input_and_plain(example_spec, example_design):
    from amcp_drake.model.errors import ProblemError

    with pytest.raises(ProblemError, match="plain"):
        AdaptiveMPC(example_spec.problem, example_design, options=OnlineOptions(pe_window=3), formulation="vertex")
    with pytest.raises(ProblemError):
        OnlineOptions(pe_window=0)


def test_online_section_round_trip(example_spec):
    data = spec_to_dict(example_spec)
    assert "online" not in data
    data["online"] = {"update": "window", "window": 5, "d_theta": 0.01}
    spec = spec_from_dict(data)
    assert spec.online == OnlineOptions(update="window", window=5, d_theta=0.01)
    assert spec_from_dict(spec_to_dict(spec)).online == spec.online
    from amcp_drake.model.errors import ProblemFileError

    data["online"] = {"bogus": 1}
    with pytest.raises(ProblemFileError):
        spec_from_dict(data)


def test_cli_run_uses_file_online_section_and_d_theta(example_spec, tmp_path):
    import json

    from amcp_drake.cli import main

    data = spec_to_dict(example_spec)
    data["online"] = {"update": "none"}
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    res = CliRunner().invoke(main, ["run", str(path), "--steps", "3"])
    assert res.exit_code == 0, res.output
    assert "update none" in res.output
    res = CliRunner().invoke(main, ["run", str(path), "--steps", "3", "--update", "fixed", "--d-theta", "0.01"])
    assert res.exit_code == 0, res.output
    assert "update fixed" in res.output
    res = CliRunner().invoke(main, ["run", "--steps", "3", "--d-theta", "0.01", "--formulation", "vertex"])
    assert res.exit_code == 2


#: the epigraph value Σ t_l equals the recomputed (19) at the solver's accuracy
MINMAX_RTOL = 1e-6


def _minmax_value(data, z, alpha, v):
    """(19) recomputed from (z, α, v): Σ_l max_j (‖x^j_l‖²_Q + ‖u^j_l‖²_R) + max_j ‖x^j_N‖²_P."""
    N, total = data.N, 0.0
    for l in range(N + 1):
        X = z[l][None, :] + alpha[l] * np.asarray(data.X0_vertices)
        if l < N:
            U = X @ data.K.T + v[l]
            vals = np.einsum("ji,ik,jk->j", X, data.Q, X) + np.einsum("ji,ik,jk->j", U, data.R, U)
        else:
            vals = np.einsum("ji,ik,jk->j", X, data.P, X)
        total += float(np.max(vals))
    return total


@pytest.mark.parametrize("x", [[2.0, 3.0], [0.5, -0.2], [-3.0, 4.0]])
def test_minmax_cost_both_backends(example_spec, example_design, x):
    pr, d = example_spec.problem, example_design
    x = np.asarray(x)
    costs = []
    for backend in ("drake", "cvxpy"):
        ctrl = AdaptiveMPC(pr, d, backend=backend, options=OnlineOptions(cost="minmax"))
        sol = ctrl.mpc.solve(x, d.h_theta0, pr.theta_hat0)
        assert sol.status is SolveStatus.OPTIMAL
        assert sol.cost == pytest.approx(_minmax_value(ctrl.data, sol.z, sol.alpha, sol.v), rel=MINMAX_RTOL)
        costs.append(sol.cost)
    assert costs[0] == pytest.approx(costs[1], rel=COST_RTOL)


@pytest.mark.parametrize("backend", ["drake", "cvxpy"])
def test_minmax_closed_loop_certifies(example_spec, example_design, backend):
    """20 steps include the instance (seed 0, step 12) where cvxpy+Clarabel needed the retry."""
    from amcp_drake.certificate.certify import certify

    sc = example_spec.scenario
    ctrl = AdaptiveMPC(example_spec.problem, example_design, backend=backend, options=OnlineOptions(cost="minmax"))
    traj = simulate(ctrl, sc.x0, sc.theta_star, 20, "uniform", seed=0, mu_state_bound=example_spec.design.mu_state_bound)
    assert traj.stop_reason == "completed"
    cert = certify(traj, example_spec)
    assert cert.passed, cert.ids("fail") + cert.ids("not_run")


def test_example2_builtin_runs_with_drift():
    """Example 2 (docs/explanation/paper.md §9): built in, with its online section; the documented drifting
    θ*_k run keeps θ*_k ∈ Θ_k, (x_k, u_k) ∈ Z and feasibility, and the PE constraint is enforced."""
    from amcp_drake.model.examples import get_example, lorenzen2019_ex2_theta_star
    from amcp_drake.offline.design import design

    spec = get_example("lorenzen2019_ex2")
    assert spec.online == OnlineOptions(update="fixed", d_theta=0.01, pe_window=3, pe_level=0.8)
    pr, sc = spec.problem, spec.scenario
    # the file holds the documented drift θ*_0..θ*_100, within the rate bound
    np.testing.assert_allclose(sc.theta_star, lorenzen2019_ex2_theta_star(100), rtol=0, atol=1e-15)
    assert sc.max_theta_rate() <= spec.online.d_theta
    seq = sc.theta_star_for(40)
    assert seq.shape == (41, 3) and seq[20, 0] < 0.8 - 0.1  # θ1 has drifted by step 20
    ctrl = AdaptiveMPC(pr, design(pr, spec.design), options=spec.online)
    traj = simulate(ctrl, sc.x0, seq, 40, "uniform", seed=0)
    assert traj.stop_reason == "completed"
    assert min(float(np.min((r.h_theta - r.H_theta @ traj.theta_star_at(r.k)) / np.linalg.norm(r.H_theta, axis=1)))
               for r in traj.records) >= -1e-7
    assert max(pr.in_Z(x, u) for x, u in zip(traj.x, traj.u)) <= 1e-7
    assert sum(r.pe_status == "enforced" for r in traj.records) > 20


def test_cli_pe_figure_writes_png_and_json(tmp_path):
    import json

    from amcp_drake.cli import main

    res = CliRunner().invoke(main, ["pe-figure", "--seeds", "1", "--steps", "12", "--pe-window", "3",
                                    "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    data = json.loads((tmp_path / "pe_diameter.json").read_text())
    assert (tmp_path / "pe_diameter.png").stat().st_size > 1000
    for label in ("no_pe", "pe"):
        d = data["runs"][label]["mean_diameter"]
        assert len(d) == 13 and d[0] == pytest.approx(2 * np.sqrt(3))
        assert all(b <= a + 1e-9 for a, b in zip(d, d[1:]))  # exact update (7): nested sets, non-increasing
    assert data["assumption20"]["holds"]


def test_cli_certify_and_compare_example2_with_its_drifting_theta_star(tmp_path):
    """Example 2 from the CLI: the problem file's θ*_k sequence, d_θ and PE options reach `certify`
    and `compare`. The certificate checks θ*_k ∈ Θ_k and the PE claims, lists Lemma 5 as not claimed
    (Section 4.1), and passes; the two backends agree step by step, PE status included."""
    import json

    from amcp_drake.cli import main

    out = tmp_path / "cert"
    res = CliRunner().invoke(main, ["certify", "--example", "lorenzen2019_ex2", "--steps", "25", "--out", str(out)])
    assert res.exit_code == 0, res.output
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["verdict"] == "pass"
    run = cert["run"]
    assert len(run["theta_star_sequence"]) == 26 and run["d_theta"] == 0.01 and run["pe_window"] == 3
    assert run["theta_star_sequence"][25][0] < run["theta_star_sequence"][0][0] - 0.05  # it drifts
    assert [c["id"] for c in run["not_claimed"]] == ["lemma5"]
    assert run["formulation"] == "plain"  # the default auto chooses the plain form: d_θ > 0 and PE need it
    statuses = {c["id"]: c["status"] for c in cert["claims"]}
    assert statuses["theta_star_in_Theta_k"] == statuses["pe_level"] == statuses["pe_bounds"] == "pass"
    assert "not claimed for this run" in res.output

    cmp_file = tmp_path / "cmp.json"
    res = CliRunner().invoke(main, ["compare", "--example", "lorenzen2019_ex2", "--steps", "12", "--quiet",
                                    "--out", str(cmp_file)])
    assert res.exit_code == 0, res.output
    data = json.loads(cmp_file.read_text())
    assert data["agree"] is True
    assert {"pe_status", "pe_level"} <= {d["quantity"] for d in data["differences"]}

    # a run longer than the file's θ* sequence is refused with the field named, before any output
    res = CliRunner().invoke(main, ["certify", "--example", "lorenzen2019_ex2", "--steps", "150",
                                    "--out", str(tmp_path / "long")])
    assert res.exit_code == 2 and "steps" in res.output and "101 rows" in res.output
    assert not (tmp_path / "long").exists()


def test_cli_certify_and_compare_take_the_robust_baseline(tmp_path):
    """`--update none` (robust baseline, Θ_k ≡ Θ) on certify and compare: the certificate records the
    mode, lists (12), Lemma 5 and its precondition as not claimed, and passes; the backends agree."""
    import json

    from amcp_drake.cli import main

    out = tmp_path / "cert"
    res = CliRunner().invoke(main, ["certify", "--update", "none", "--steps", "8", "--formulation", "plain",
                                    "--out", str(out)])  # the plain form: every Λ claim made, only the update's not
    assert res.exit_code == 0, res.output
    cert = json.loads((out / "certificate.json").read_text())
    assert cert["run"]["update"] == "none" and cert["verdict"] == "pass"
    assert [c["id"] for c in cert["run"]["not_claimed"]] == ["mu_precondition", "lms_update", "lemma5"]
    widths = cert["series"]["theta_width"]
    assert widths[0] == widths[-1]  # Θ_k ≡ Θ
    res = CliRunner().invoke(main, ["compare", "--update", "window", "--window", "3", "--projection", "Theta_k",
                                    "--steps", "6", "--quiet", "--out", str(tmp_path / "c.json")])
    assert res.exit_code == 0, res.output
    # a saved trajectory is re-checked as recorded: run options are refused with it
    res = CliRunner().invoke(main, ["certify", "--trajectory", str(out / "trajectory.json.gz"), "--update", "fixed",
                                    "--out", str(tmp_path / "again")])
    assert res.exit_code == 2 and "--update" in res.output


def test_a_wrong_optimal_under_a_pe_bound_is_dropped_and_the_loop_goes_on():
    """A generated case (PE, m = 1, window 2): a solver can call the QP with a PE bound "optimal"
    while (15c) is violated (Clarabel at step 4, with u_0 >= 0.6626: by 0.15). Taking such a
    candidate would fail its answer checks and stop the run (u = None), so a candidate is checked
    before it competes. With (15d) solved for p of the multipliers (backends/multiplier_basis.py),
    Clarabel answers this step correctly, so the data test checks the outcome (every step optimal
    and checked, PE enforced at step 4); the dropping itself is tested with a stub below."""
    from pathlib import Path

    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.replay import run_scenario

    spec = load_spec(Path(__file__).parent / "data" / "pe-wrong-optimal-problem.json")
    assert spec.online.pe_window == 2
    traj = run_scenario(spec, "drake", steps=8)
    assert traj.stop_reason == "completed" and all(answers.qp_applied(r) for r in traj.records)   # every step answered, checked
    assert traj.records[4].pe_status.startswith("enforced")


def test_a_pe_candidate_that_fails_its_checks_is_dropped_and_the_step_falls_back_to_20():
    """Every QP solved under a PE bound answers a wrong "optimal" (Λ negated, first try and the
    re-solve with refinement alike): each candidate fails its checks and is dropped, at every
    reduced level too, and the step falls back to (20) alone, whose answer is checked and applied."""
    import dataclasses
    from pathlib import Path

    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.model.status import SolveStatus
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.simulate import simulate

    spec = load_spec(Path(__file__).parent / "data" / "pe-wrong-optimal-problem.json")
    offline = design(spec.problem, spec.design, backend="drake")
    ctrl = AdaptiveMPC(spec.problem, offline, backend="drake", options=spec.online)
    real = ctrl.mpc

    class WrongUnderPEBound:
        REFINES = True
        wrong = 0

        def solve(self, *args, u0_bounds=None, **kwargs):
            sol = real.solve(*args, u0_bounds=u0_bounds, **kwargs)
            if u0_bounds is None or sol.status is not SolveStatus.OPTIMAL:
                return sol
            self.wrong += 1
            return dataclasses.replace(sol, Lambda=-np.asarray(sol.Lambda) - 1.0)

    ctrl.mpc = stub = WrongUnderPEBound()
    sc = spec.scenario
    traj = simulate(ctrl, sc.x0, sc.theta_star_for(8), 8, sc.disturbance_for(8), seed=sc.seed,
                    mu_state_bound=spec.design.mu_state_bound)
    dropped = [r for r in traj.records if (answers.of(r, "pe_candidate") or {}).get("kind") == "candidate_dropped"]
    assert stub.wrong >= 2 and dropped
    assert all(r.pe_status == "fallback" and r.status is SolveStatus.OPTIMAL for r in dropped)
    assert [r.status for r in traj.records] == [SolveStatus.OPTIMAL] * len(traj.records)


def test_a_first_try_outside_15c_is_solved_again_with_refinement_and_the_run_completes():
    """A generated case (PE, x_0 on the boundary of the feasible set): the first try of the plain
    QP at step 0 (iterative refinement off, for speed) can be 1.29e-6 outside (15c), and PE allows
    only the plain form, so such a first try is solved again with refinement rather than the step
    left "not solved" (mechanism: test_answer_checks, UnrefinedTube). With (15d) eliminated
    (backends/multiplier_basis.py) the first try on this data passes its checks; the data test
    checks the outcome: every step optimal, checked, and the tube claim holds."""
    from pathlib import Path

    from amcp_drake.model.problem_io import load_spec
    from amcp_drake.online.replay import run_scenario

    spec = load_spec(Path(__file__).parent / "data" / "unrefined-first-try-problem.json")
    traj = run_scenario(spec, "drake", steps=5)
    assert all(answers.qp_applied(r) for r in traj.records)   # every step answered, by a checked answer
    assert traj.stop_reason == "completed"
    pytest.importorskip("amcp_properties")
    from amcp_properties import claims

    assert claims.prediction_tube(traj).passed
