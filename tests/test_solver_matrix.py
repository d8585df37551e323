"""The solver conformance matrix (amcp_drake.studies.solver_matrix): classification (by hand-made
problems with known answers and stub solvers in real child processes), the corpus format, the verified
references, the Drake export and the reproducers."""

from __future__ import annotations

import gzip
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from amcp_drake.model.errors import ProblemFileError
from amcp_drake.studies.solver_matrix.corpus import CorpusProblem, load_corpus, load_problem, shipped_corpus_dir
from amcp_drake.studies.solver_matrix.runner import TOLERANCES, classify, context, run_matrix, run_one
from tests.guards import GUARD_SECONDS

ROOT = Path(__file__).resolve().parents[1]


def lp_x_geq_1(reference=None) -> CorpusProblem:
    """minimise x s.t. x >= 1: optimum x = 1, objective 1 (by hand)."""
    return CorpusProblem(id="x-geq-1", kind="support_lp", P=None, q=np.array([1.0]), r=0.0, A=sp.csr_matrix([[1.0]]),
                         lower=np.array([1.0]), upper=np.array([np.inf]), lb=np.array([-np.inf]), ub=np.array([np.inf]),
                         reference=reference if reference is not None else {"status": "optimal", "x": [1.0], "objective": 1.0})


def message(success, x, status="stub"):
    return {"outcome": {"success": success, "status": status, "x": x, "supported": True, "detail": {}}}


# -- classification: pure function, tolerances at their edges ------------------------------------------

@pytest.mark.parametrize("settings", ["default", "tight"])
def test_objective_tolerance_edges(settings):
    tol = TOLERANCES[settings]["opt"]
    pr = lp_x_geq_1()
    # gap = (x - 1) / (1 + 1): x = 1 + 2 * gap
    inside = classify(pr, message(True, [1.0 + 2 * 0.5 * tol]), 0, False, settings)
    outside = classify(pr, message(True, [1.0 + 2 * 2.0 * tol]), 0, False, settings)
    assert inside[0] == "correct"
    assert outside[0] == "wrong" and "suboptimal" in outside[1]["detail"]


@pytest.mark.parametrize("settings", ["default", "tight"])
def test_feasibility_tolerance_edges(settings):
    tol = TOLERANCES[settings]["feas"]
    pr = lp_x_geq_1()
    # violation = (1 - x) / (1 + |1|): x = 1 - 2 * violation
    inside = classify(pr, message(True, [1.0 - 2 * 0.5 * tol]), 0, False, settings)
    outside = classify(pr, message(True, [1.0 - 2 * 2.0 * tol]), 0, False, settings)
    assert inside[0] == "correct"
    assert outside[0] == "wrong" and "infeasible" in outside[1]["detail"]


def test_success_without_a_solution_or_with_nan_is_wrong_and_a_non_success_is_honest():
    pr = lp_x_geq_1()
    assert classify(pr, message(True, None), 0, False, "default")[0] == "wrong"
    assert classify(pr, message(True, [float("nan")]), 0, False, "default")[0] == "wrong"
    assert classify(pr, message(False, [5.0], "iteration limit"), 0, False, "default")[0] == "honest failure"


def test_infeasible_reference():
    pr = lp_x_geq_1({"status": "infeasible"})
    assert classify(pr, message(True, [1.0]), 0, False, "default")[0] == "wrong"
    assert classify(pr, message(False, None, "kInfeasibleConstraints"), 0, False, "default")[0] == "correct"
    assert classify(pr, message(False, None, "iteration limit"), 0, False, "default")[0] == "honest failure"


def test_a_dead_child_is_a_crash_naming_the_signal_and_no_answer_in_time_is_a_timeout():
    pr = lp_x_geq_1()
    verdict, measures = classify(pr, None, -6, False, "default")
    assert verdict == "crash" and "SIGABRT" in measures["detail"]
    assert classify(pr, None, None, True, "default")[0] == "timeout"
    assert classify(pr, {"crash": "RuntimeError: x"}, 1, False, "default")[0] == "crash"


# -- stub solvers in real child processes --------------------------------------------------------------

@pytest.fixture(scope="module")
def ctx():
    return context(preload=["amcp_drake.studies.solver_matrix.solvers", "tests.solver_stubs"])


@pytest.mark.parametrize(("stub", "verdict", "word"), [
    ("correct", "correct", ""),
    ("wrong", "wrong", "infeasible"),
    ("suboptimal", "wrong", "suboptimal"),
    ("honest", "honest failure", "iteration limit"),
    ("raises", "crash", "RuntimeError"),
    ("panics", "crash", "FakePanic"),
    ("aborts", "crash", "SIGABRT"),
])
def test_stub_solver_in_a_child_process_is_classified(ctx, stub, verdict, word):
    cell = run_one(ctx, f"py:tests.solver_stubs:{stub}", lp_x_geq_1(), "default", time_limit=30.0)
    assert cell.verdict == verdict, cell
    assert word in cell.detail + cell.status


def test_a_hanging_solver_is_killed_at_the_time_limit(ctx):
    """The stub sleeps 600 s and would then report success: only a kill at the 1 s limit makes it a timeout
    with no answer (how long the kill took is the machine's load, not asserted)."""
    cell = run_one(ctx, "py:tests.solver_stubs:hangs", lp_x_geq_1(), "default", time_limit=1.0)
    assert cell.verdict == "timeout" and cell.wall_s is None


@pytest.mark.slow
def test_the_cli_survives_aborting_raising_and_hanging_solvers(tmp_path):
    """The real `amcp solvers` process: every defect stays in its child; exit 0, outputs written. The time
    limit of 20 s per solve is far above a stub's answer on a loaded machine (the forkserver's start
    included), so only the hanging stub reaches it."""
    corpus = tmp_path / "corpus"
    corpus.mkdir()
    (corpus / "x-geq-1.json").write_text(json.dumps(lp_x_geq_1().to_dict()))
    out = tmp_path / "out"
    stubs = ",".join(f"py:tests.solver_stubs:{s}" for s in ("correct", "wrong", "aborts", "raises", "hangs"))
    child = subprocess.run([sys.executable, "-m", "amcp_drake", "solvers", "--corpus", str(corpus), "--solvers", stubs,
                            "--time-limit", "20", "--out", str(out)], capture_output=True, text=True, timeout=GUARD_SECONDS, cwd=ROOT)
    assert child.returncode == 0, child.stderr[-2000:]
    data = json.loads((out / "solvers.json").read_text())
    verdicts = {c["solver"].rsplit(":", 1)[1]: c["verdict"] for c in data["cells"]}
    assert verdicts == {"correct": "correct", "wrong": "wrong", "aborts": "crash", "raises": "crash", "hangs": "timeout"}
    assert data["summary"]["py:tests.solver_stubs:correct"]["counts"]["correct"] == 1
    assert "<table id='matrix'>" in (out / "solvers.html").read_text()
    assert not list(out.glob(".*"))   # no temporary file left
    umask = os.umask(0)
    os.umask(umask)
    written = [out / "solvers.json", out / "solvers.html"]
    assert {oct(p.stat().st_mode & 0o777) for p in written} == {oct(0o666 & ~umask)}


@pytest.mark.parametrize("args", [["--corpus", "/nonexistent/corpus"], ["--solvers", "clarabel"], ["--kind", "nope"],
                                  ["--recheck", "/nonexistent"]])
def test_bad_input_exits_2_with_one_line(tmp_path, args):
    child = subprocess.run([sys.executable, "-m", "amcp_drake", "solvers", "--out", str(tmp_path), *args],
                           capture_output=True, text=True, timeout=GUARD_SECONDS, cwd=ROOT)
    assert child.returncode == 2, child.stderr
    assert child.stderr.startswith("error:") and "Traceback" not in child.stderr


# -- the corpus format ---------------------------------------------------------------------------------

def test_round_trip_and_gzip(tmp_path):
    pr = lp_x_geq_1()
    path = tmp_path / "p.json.gz"
    path.write_bytes(gzip.compress(json.dumps(pr.to_dict()).encode()))
    back = load_problem(path)
    assert back.to_dict() == pr.to_dict()
    assert back.violation(np.array([0.0])) == pytest.approx(0.5)   # (1 - 0) / (1 + 1)
    assert back.objective(np.array([2.0])) == 2.0


@pytest.mark.parametrize(("mutate", "field"), [
    (lambda d: d.pop("kind"), "kind"),
    (lambda d: d["objective"].update(q=[1.0, 2.0]), "objective.q"),
    (lambda d: d["linear"]["A"].update(shape=[1, 3]), "linear.A.shape"),
    (lambda d: d["linear"]["lower"].__setitem__(0, "one"), "linear.lower[0]"),
    (lambda d: d.update(version=99), "version"),
])
def test_a_malformed_file_names_its_field(tmp_path, mutate, field):
    data = lp_x_geq_1().to_dict()
    mutate(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ProblemFileError) as exc:
        load_problem(path)
    assert field in str(exc.value)


def test_shipped_corpus_is_small_verified_and_covers_every_kind():
    folder = shipped_corpus_dir()
    total = sum(f.stat().st_size for f in folder.iterdir())
    assert total < 2_000_000
    problems = load_corpus(folder)
    kinds = {p.kind for p in problems}
    assert kinds == {"tube_qp_plain", "tube_qp_vertex", "set_update_lp", "exact_update_lp", "projection_qp", "gain_sdp",
                     "support_lp"}
    for p in problems:
        ref = p.reference
        assert ref["status"] in ("optimal", "infeasible")
        if ref["status"] == "optimal":
            assert max(ref["kkt"].values()) <= ref["tolerance"]
            # re-checked here from the data, at the tightest verdict tolerance: returning the reference is correct
            assert p.violation(p.reference_x()) <= TOLERANCES["tight"]["feas"]
            assert ref["objective"] == pytest.approx(p.objective(p.reference_x()), rel=1e-9, abs=1e-9)
            if p.problem_class == "lp":
                assert ref["exact"]["verified"] is True
    index = json.loads((folder / "index.json").read_text())
    assert len(index["problems"]) == len(problems)
    assert all(entry["reason"] for entry in index["left_out"])


# -- verified references ---------------------------------------------------------------------------------

def test_reference_of_an_lp_is_its_exact_vertex():
    from amcp_drake.studies.solver_matrix.reference import verify_reference

    # minimise -x - 2y s.t. 3x + 3y <= 1, x, y >= 0: optimum (0, 1/3), objective -2/3 (by hand)
    pr = CorpusProblem(id="lp2", kind="support_lp", P=None, q=np.array([-1.0, -2.0]), r=0.0, A=sp.csr_matrix([[3.0, 3.0]]),
                       lower=np.array([-np.inf]), upper=np.array([1.0]), lb=np.zeros(2), ub=np.full(2, np.inf))
    assert verify_reference(pr) is None
    assert pr.reference["exact"]["verified"] is True
    assert pr.reference["x"] == [0.0, 1 / 3]
    assert pr.reference["objective"] == -2 / 3


def test_an_answer_feasible_only_at_the_kkt_tolerance_is_not_a_reference():
    """The gain LMI (16) of x+ = 1.5 x + 0 u with margin 1e-8 has no solution (x+ = 1.5 x is unstable and
    u has no effect); Clarabel's answer violates it by 1.03e-8, inside the KKT tolerance 1e-7 but above the
    tight verdict tolerance 1e-8: it is left out, not given an "optimal" reference."""
    from amcp_drake.studies.solver_matrix.reference import KKT_TOL, REFERENCE_FEAS_TOL, verify_reference

    assert REFERENCE_FEAS_TOL == min(t["feas"] for t in TOLERANCES.values()) < KKT_TOL
    pr = load_problem(ROOT / "tests" / "data" / "solver_corpus_left_out" / "unstabilisable-gain-lmi-gain_sdp-1.json.gz")
    pr.reference = {}
    reason = verify_reference(pr)
    assert reason is not None and "primal" in reason and "REFERENCE_FEAS_TOL" in reason, reason
    assert pr.reference == {}


def test_infeasible_and_unbounded_problems():
    from amcp_drake.studies.solver_matrix.reference import verify_reference

    infeasible = lp_x_geq_1({})
    infeasible.ub = np.array([0.0])        # x >= 1 and x <= 0
    assert verify_reference(infeasible) is None
    assert infeasible.reference["status"] == "infeasible"
    unbounded = lp_x_geq_1({})
    unbounded.q = np.array([-1.0])         # minimise -x s.t. x >= 1
    assert "unbounded" in verify_reference(unbounded)


def test_kkt_residuals_at_the_optimum_and_off_it():
    from amcp_drake.studies.solver_matrix.reference import KKT_TOL, conic_form, kkt_residuals

    # minimise ½x² - x s.t. x <= 0.5: x* = 0.5, multiplier z = 0.5 (by hand)
    pr = CorpusProblem(id="qp1", kind="projection_qp", P=sp.csr_matrix([[1.0]]), q=np.array([-1.0]), r=0.0,
                       A=sp.csr_matrix([[1.0]]), lower=np.array([-np.inf]), upper=np.array([0.5]),
                       lb=np.array([-np.inf]), ub=np.array([np.inf]))
    cf = conic_form(pr)
    assert max(kkt_residuals(pr, cf, np.array([0.5]), np.array([0.5])).values()) < 1e-15
    # dual residual |x - 1 + z| / (1 + 1 + 0.5): z off by 2 KKT_TOL * 2.5 gives 2 KKT_TOL; by half: KKT_TOL / 2
    assert kkt_residuals(pr, cf, np.array([0.5]), np.array([0.5 + 2 * KKT_TOL * 2.5]))["dual"] > KKT_TOL
    assert kkt_residuals(pr, cf, np.array([0.5]), np.array([0.5 + 0.5 * KKT_TOL * 2.5]))["dual"] < KKT_TOL


# -- the Drake export ------------------------------------------------------------------------------------

def test_a_drake_program_is_read_into_the_neutral_form():
    from pydrake.solvers import MathematicalProgram

    from amcp_drake.studies.solver_matrix.drake_export import program_to_problem

    prog = MathematicalProgram()
    x = prog.NewContinuousVariables(2, "x")
    prog.AddQuadraticCost(np.diag([2.0, 4.0]), np.array([1.0, 0.0]), 3.0, x)      # x0² + 2x1² + x0 + 3
    prog.AddLinearConstraint(np.array([[1.0, 1.0]]), np.array([-1.0]), np.array([2.0]), x)
    prog.AddBoundingBoxConstraint(0.0, 5.0, x[1])
    prog.AddLinearMatrixInequalityConstraint([np.eye(2), np.array([[0.0, 1.0], [1.0, 0.0]])], x[:1])
    pr = program_to_problem(prog, "t", "gain_sdp")
    np.testing.assert_array_equal(pr.P.toarray(), np.diag([2.0, 4.0]))
    np.testing.assert_array_equal(pr.q, [1.0, 0.0])
    assert pr.r == 3.0
    np.testing.assert_array_equal(pr.A.toarray(), [[1.0, 1.0]])
    np.testing.assert_array_equal(pr.lb, [-np.inf, 0.0])
    np.testing.assert_array_equal(pr.ub, [np.inf, 5.0])
    # [[1, x0], [x0, 1]] ⪰ 0 holds for x0 = 1 (eigenvalues 0, 2), not for x0 = 1.5 (-0.5: relative to 1 + 1)
    assert pr.violation(np.array([1.0, 0.0])) == 0.0
    assert pr.violation(np.array([1.5, 0.0])) == pytest.approx(0.25)


# -- reproducers -----------------------------------------------------------------------------------------

def test_reproducer_scripts_say_whether_the_defect_reproduces(tmp_path):
    """cvxpy's Clarabel on x >= 1 with the true optimum recorded does not reproduce; a crash's script
    reproduces only by an exception or an abort, not by the answer it returns; a manifest entry whose
    recorded optimum is 0.5 below the true one is refused (its reference does not verify), never run."""
    pytest.importorskip("cvxpy")
    from amcp_drake.studies.solver_matrix.reproducers import recheck, reproducer_name, write_reproducer_folder

    fine = lp_x_geq_1()
    lying = lp_x_geq_1({"status": "optimal", "x": [0.5], "objective": 0.5})
    lying.id = "x-geq-1-lying"
    write_reproducer_folder(tmp_path, [(fine, "cvxpy:CLARABEL", "default", "wrong", "stub"),
                                       (lying, "cvxpy:CLARABEL", "default", "crash", "stub"),
                                       (lying, "cvxpy:CLARABEL", "default", "wrong", "stub")])
    results = {r.script: r for r in recheck(tmp_path)}
    name = reproducer_name("cvxpy:CLARABEL", "wrong", "x-geq-1")
    assert results[name].outcome == "no longer reproduces"
    crash = results[reproducer_name("cvxpy:CLARABEL", "crash", "x-geq-1-lying")]
    assert crash.outcome == "no longer reproduces" and "without an exception" in crash.last_line
    lied = results[reproducer_name("cvxpy:CLARABEL", "wrong", "x-geq-1-lying")]
    assert lied.outcome == "refused" and lied.returncode is None and "reference.x" in lied.last_line
    imports = [ln for ln in (tmp_path / name).read_text().splitlines() if ln.lstrip().startswith(("import ", "from "))]
    assert imports and not any("amcp" in ln for ln in imports)   # nothing imported from this project


def test_run_matrix_rejects_unknown_settings():
    with pytest.raises(ValueError, match="settings"):
        run_matrix([lp_x_geq_1()], ["py:tests.solver_stubs:correct"], settings="loose")


# -- the HTML page in a real browser ---------------------------------------------------------------------

def test_matrix_page_renders_in_headless_chromium(tmp_path):
    """Every cell of solvers.json is in the DOM that Chromium builds from solvers.html, with its verdict."""
    from amcp_drake.studies.solver_matrix.report import to_json, write_outputs
    from amcp_drake.studies.solver_matrix.runner import Cell, MatrixRun
    from tests.browser import NO_CHROMIUM, find_chromium, headless
    from tests.test_report_browser import parse

    chromium = find_chromium()
    if chromium is None:
        pytest.skip(NO_CHROMIUM)
    a, b = lp_x_geq_1(), lp_x_geq_1()
    b.id = "second <problem> & 'quotes'"
    configs = ["drake:clarabel", "cvxpy:OSQP"]
    cells = [Cell(a.id, configs[0], "correct", wall_s=0.01, cpu_s=0.01), Cell(a.id, configs[1], "wrong", detail="x < y & z"),
             Cell(b.id, configs[0], "crash", detail="SIGABRT"), Cell(b.id, configs[1], "timeout")]
    data = to_json(MatrixRun("default", 5.0, configs, [a, b], cells))
    _, page = write_outputs(tmp_path, data)
    cmd = headless(chromium, tmp_path / "profile", "--dump-dom", page.resolve().as_uri())
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=GUARD_SECONDS)
    assert done.returncode == 0, done.stderr[-2000:]
    doc = parse(done.stdout)
    shown = {(t[1]["data-problem"], t[1]["data-solver"]): t[1]["data-verdict"] for t in doc.tags if "data-verdict" in t[1]}
    assert shown == {(c["problem"], c["solver"]): c["verdict"] for c in data["cells"]}
    assert [t[1]["data-solver"] for t in doc.tags if t[0] == "tr" and "data-solver" in t[1]] == configs


def test_a_cvxpy_problem_is_read_from_its_conic_data():
    """min x0² + x1² + trace(S) s.t. x >= 1, x0 = 2, S ⪰ [[2, 1], [1, 2]]: optimum 4 + 1 + 4 = 9 (by hand),
    read through cvxpy's compiled data (zero, orthant and PSD cones) and verified."""
    cp = pytest.importorskip("cvxpy")
    from amcp_drake.studies.solver_matrix.cvxpy_export import conic_to_problem
    from amcp_drake.studies.solver_matrix.reference import verify_reference

    x = cp.Variable(2)
    S = cp.Variable((2, 2), symmetric=True)
    problem = cp.Problem(cp.Minimize(cp.sum_squares(x) + cp.trace(S)),
                         [x >= 1, x[0] == 2, S >> np.array([[2.0, 1.0], [1.0, 2.0]])])
    data, _, _ = problem.get_problem_data("CLARABEL")
    pr = conic_to_problem(data, "cvx", "gain_sdp")
    assert pr.problem_class == "sdp" and len(pr.lmis) == 1
    assert verify_reference(pr) is None
    assert pr.reference["objective"] == pytest.approx(9.0, abs=1e-7)


def test_the_nonfinite_reproducer_runs_standalone(tmp_path):
    from amcp_drake.studies.solver_matrix.reproducers import recheck, write_reproducer_folder

    write_reproducer_folder(tmp_path, [(None, "drake", "default", "crash", "")])
    (result,) = recheck(tmp_path)
    # either verdict is a statement about the installed Drake; the script must reach one of them
    assert result.outcome in ("reproduces", "no longer reproduces")
    assert result.last_line.startswith(("REPRODUCES", "does not reproduce"))


def test_the_shipped_reproducers_are_what_this_version_writes(tmp_path):
    """docs/reproducers: every script is vouched for by its manifest (written by the current template from
    its entry, references verified), so `amcp solvers --recheck docs/reproducers` runs all of them; written
    again from the manifest, the folder is byte for byte the same."""
    import shutil

    from amcp_drake.studies.solver_matrix.reproducers import read_manifest, rewrite_folder, vet

    folder = ROOT / "docs" / "reproducers"
    runnable, refused = vet(folder, read_manifest(folder))
    assert refused == []
    assert sorted(name for name, _, _ in runnable) == sorted(p.name for p in folder.glob("*.py"))
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    rewrite_folder(copy)
    assert {p.name: p.read_bytes() for p in copy.iterdir()} == {p.name: p.read_bytes() for p in folder.iterdir()}


def test_markdown_tables_count_what_the_cells_say():
    from amcp_drake.studies.solver_matrix.report import markdown, to_json
    from amcp_drake.studies.solver_matrix.runner import Cell, MatrixRun

    a, b = lp_x_geq_1(), lp_x_geq_1()
    b.id = "b"
    cells = [Cell(a.id, "s", "correct", wall_s=0.002, cpu_s=0.001), Cell(b.id, "s", "wrong")]
    text = markdown(to_json(MatrixRun("default", 5.0, ["s"], [a, b], cells)))
    assert "| s | 1 | 0 | 1 | 0 | 0 | 0 | 2.0 | 1.0 |" in text
    assert "| s | 1/2 1W |" in text


def test_generated_projections_are_of_points_outside_theta_and_verified(tmp_path):
    """Each generated projection (12) is of a point outside Θ: its verified optimal distance is positive."""
    from amcp_drake.studies.solver_matrix.export import export_corpus, projection_sources

    index = export_corpus(tmp_path, list(projection_sources(("lorenzen2019",), points=2, seed=0)))
    assert [p["kind"] for p in index["problems"]] == ["projection_qp", "projection_qp"] and index["left_out"] == []
    for pr in load_corpus(tmp_path):
        assert pr.reference["status"] == "optimal"
        # the problem is in the scaled coordinates y = (θ - point) / s of backends/projection_form.py: y = 0 is the point
        assert pr.violation(np.zeros(pr.n)) > 1e-3
        assert pr.objective(pr.reference_x()) > pr.objective(np.zeros(pr.n)) + 1e-3


def test_the_corpus_table_of_the_docs_counts_the_shipped_corpus():
    import re
    from collections import Counter

    counts = Counter(p.kind for p in load_corpus(shipped_corpus_dir()))
    text = (ROOT / "docs" / "choosing-a-solver.md").read_text(encoding="utf-8")
    table = {m.group(1): int(m.group(2)) for m in re.finditer(r"^\| `(\w+)` \|[^|]*\| (\d+) \|$", text, flags=re.M)}
    assert table == dict(counts)


# -- the sources of the shipped corpus ---------------------------------------------------------------

def _shipped_index() -> dict:
    return json.loads((shipped_corpus_dir() / "index.json").read_text())


def _shipped_provenance() -> dict[str, dict]:
    return {p["id"]: load_problem(shipped_corpus_dir() / p["file"]).provenance for p in _shipped_index()["problems"]}


def test_the_shipped_corpus_holds_problems_of_every_file_of_examples():
    """Every problem file of examples/ (listed here, not by the exporter) has at least one problem recorded
    in a closed-loop run or the design of that very example, and one tube QP (20) or a reason it was left out."""
    provenance = _shipped_provenance()
    index = _shipped_index()
    names = sorted(p.name[:-len(".json")] for p in (ROOT / "examples").glob("*.json"))
    assert len(names) >= 15 and {"mass_chain3", "mass_chain4", "ji2022_quadrotor"} <= set(names)
    for name in names:
        mine = {pid: prov for pid, prov in provenance.items()
                if prov.get("source") == f"example {name} (drake)" and prov.get("example") == name}
        assert mine, f"no shipped problem recorded in a run of examples/{name}.json"
        assert all(pid.startswith(f"{name}-") for pid in mine)
        tube = [pid for pid in mine if "tube_qp" in pid]
        tube_left_out = [e for e in index["left_out"] if e["id"].startswith(f"{name}-tube_qp")]
        assert tube or tube_left_out, name


def test_the_shipped_corpus_holds_generated_problems_reproducible_from_their_seed():
    """Problems of the generator under the property suite's strategies, with its labels; the labels of one
    of them are those of a fresh draw of the same (campaign seed, index)."""
    from amcp_drake.studies.campaign import draw_case

    generated = {pid: prov for pid, prov in _shipped_provenance().items()
                 if str(prov.get("source", "")).startswith("generated problem")}
    assert len({(prov["campaign_seed"], prov["idx"]) for prov in generated.values()}) >= 3
    assert {"tube_qp_plain", "tube_qp_vertex", "gain_sdp"} <= {pid.split("-")[-2] for pid in generated}
    # the generator's hard cases are among them: θ* on the boundary of Θ, w_0 pinning Θ_1
    closed_loop = [prov for prov in generated.values() if "labels" in prov]   # the design's come before the labels
    labels = [prov["labels"] for prov in closed_loop]
    assert any(lab["theta_star"] in ("facet", "vertex") for lab in labels)
    assert any(lab["pin"] in ("point", "thin") for lab in labels)
    prov = min(closed_loop, key=lambda p: p["idx"])
    case = draw_case(prov["campaign_seed"], prov["idx"], prov.get("steps", 6))
    assert {k: str(v) for k, v in case.labels.items()} == prov["labels"]


@pytest.mark.parametrize("problem_id", [p["id"] for p in json.loads(
    (shipped_corpus_dir() / "index.json").read_text())["problems"]])
def test_every_shipped_reference_is_verified_again_from_the_data(problem_id):
    """The reference is recomputed from the stored data alone (KKT residuals; an LP's basis in exact
    arithmetic) and agrees with the shipped one."""
    from amcp_drake.studies.solver_matrix.reference import REFERENCE_FEAS_TOL, verify_reference

    pr = load_problem(shipped_corpus_dir() / f"{problem_id}.json.gz")
    shipped = dict(pr.reference)
    pr.reference = {}
    assert verify_reference(pr) is None
    assert pr.reference["status"] == shipped["status"]
    if shipped["status"] == "optimal":
        x = np.asarray(shipped["x"], float)
        assert pr.violation(x) <= REFERENCE_FEAS_TOL
        assert pr.objective(x) == pytest.approx(pr.reference["objective"], rel=1e-7, abs=1e-7)


def test_select_keeps_the_first_and_the_last_program_of_a_kind_that_keeps_its_shape():
    """A kind whose programs all have one shape (the plain tube QP of a closed loop): the first and the
    last of the run; with distinct shapes, those first; a failed solve is kept besides."""
    from amcp_drake.studies.solver_matrix.drake_export import Recorded
    from amcp_drake.studies.solver_matrix.export import example_names, select

    def rec(rows: int, success: bool = True) -> Recorded:
        pr = CorpusProblem(id="p", kind="tube_qp_plain", P=None, q=np.zeros(2), r=0.0, A=sp.csr_matrix(np.ones((rows, 2))),
                           lower=np.zeros(rows), upper=np.ones(rows), lb=np.full(2, -np.inf), ub=np.full(2, np.inf))
        return Recorded("tube_qp_plain", pr, "stub", {}, success=success)

    same = [rec(3) for _ in range(6)]
    picked = select(same, 2)
    assert len(picked) == 2 and picked[0] is same[0] and picked[1] is same[-1]
    assert len(select(same, 1)) == 1 and select(same, 1)[0] is same[0]
    shapes = [rec(3), rec(3), rec(4), rec(3), rec(5)]
    picked = select(shapes, 2)
    assert [r.problem.A.shape[0] for r in picked] == [3, 5]
    failing = [rec(3), rec(3, success=False), rec(3), rec(3)]
    assert [next(i for i, q in enumerate(failing) if q is r) for r in select(failing, 2)] == [0, 3, 1]
    # every problem file of examples/ is exported besides the built-in ones, each once
    names = example_names(ROOT / "examples")
    assert {p.name[:-len(".json")] for p in (ROOT / "examples").glob("*.json")} <= set(names)
    assert len(names) == len(set(names)) and "lorenzen2019_ex2" in names
