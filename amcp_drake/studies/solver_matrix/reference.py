"""The verified reference answer of a corpus problem.

Every problem is solved once at tight tolerances by Clarabel (its Python package, :data:`REFERENCE_SETTINGS`)
in the conic form ``A_c x + s = b_c, s ∈ K`` built here from the neutral data (zero cone for the
equalities, the nonnegative orthant for the inequalities and bounds, the scaled PSD triangle for an LMI
block). The answer is accepted only when its KKT residuals, recomputed here with numpy from the problem's
data and the solver's primal-dual pair, are all below :data:`KKT_TOL`:

* primal: the largest constraint violation (:meth:`.corpus.CorpusProblem.violation`), which must in
  addition be at most :data:`REFERENCE_FEAS_TOL`, the tightest feasibility tolerance of the verdicts
  (so a solver that returns the reference is judged correct under every settings, and a problem that
  is infeasible by less than the verdicts can resolve, e.g. an LMI infeasible only by its 1e-8 margin,
  is left out instead of being given an "optimal" reference);
* dual: ‖P x + q + A_cᵀ z‖∞ / (1 + ‖q‖∞ + ‖P x‖∞), and z in the dual cone (relative to 1 + ‖z‖∞);
* gap: |primal − dual objective| / (1 + |primal objective|).

An LP is in addition verified in exact rational arithmetic (:func:`exact_lp_certificate`): HiGHS's
simplex gives an optimal basis; the vertex of that basis is solved in :class:`fractions.Fraction`s from
the problem's floats (each float is a rational number, so this is exact), it is checked primal feasible
row by row, and the multipliers of the same basis dual feasible (the right sign at every active bound,
zero on free nonbasic columns). Then the vertex is optimal, exactly; its float image is the reference.

An infeasible problem is accepted as such only with a Farkas certificate z ∈ K* with A_cᵀz = 0 and
b_cᵀz < 0 (relative residual below :data:`KKT_TOL`). A problem whose answer cannot be verified is left
out of the corpus and counted (:func:`verify_reference` returns the reason).

A corpus file read back is someone else's data: :func:`check_reference` verifies its stored reference
again from the problem's data before the matrix judges any answer by it (a lowered objective would
turn correct answers into "wrong", a raised one wrong answers into "correct").
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
import scipy.sparse as sp

from amcp_drake.model.errors import ProblemFileError
from amcp_drake.studies.solver_matrix.corpus import CorpusProblem, check_reference_layout, load_corpus

#: Relative KKT residual (primal, dual, gap, cone) below which a tight answer is accepted as the reference.
KKT_TOL = 1e-7
#: Largest constraint violation of an accepted optimal reference: the tightest verdict tolerance
#: (:data:`.runner.TOLERANCES`, "tight").
REFERENCE_FEAS_TOL = 1e-8
#: Largest |stored objective − f(stored x)| / (1 + |f(stored x)|) of a stored optimal reference: the round-off
#: of evaluating f (an LP's objective is computed exactly and rounded once, its x rounded entry by entry).
CONSISTENCY_TOL = 1e-9
#: Largest problem whose reference :func:`check_reference` verifies again on load, in stored nonzeros
#: (:attr:`.corpus.CorpusProblem.size`; the shipped corpus's largest has 35k, an exported file at most
#: 1.2 MB of JSON), and largest LMI block (shipped: 13): a larger problem from someone else's corpus is
#: refused before anything is solved, not verified for hours.
MAX_CHECK_SIZE = 1_000_000
MAX_CHECK_LMI = 200
#: Clarabel settings of the reference solve.
REFERENCE_SETTINGS = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10, "tol_ktratio": 1e-8,
                      "max_iter": 500}
#: Settings of the second try when the tight solve ends in neither Solved nor PrimalInfeasible.
FALLBACK_SETTINGS = {"tol_gap_abs": 1e-8, "tol_gap_rel": 1e-8, "tol_feas": 1e-8, "tol_ktratio": 1e-6, "max_iter": 500}
#: Largest LP (rows + columns) checked in exact arithmetic; a larger one is left out, not trusted.
EXACT_LP_MAX = 4000


@dataclass
class ConicForm:
    """A_c x + s = b_c, s ∈ zero^nz × R+^nn × PSD triangles of ``psd`` sizes (svec, off-diagonals × √2)."""

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    b: np.ndarray
    nz: int
    nn: int
    psd: list[int]


def _svec_rows(s: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the svec of an s×s matrix (upper triangle, column-major): the two column-major positions of
    each entry and its weight (1 on the diagonal, √2/2 per copy off it, i.e. √2 · the symmetrised entry)."""
    first, second, weight = [], [], []
    for j in range(s):
        for i in range(j + 1):
            first.append(i + j * s)
            second.append(j + i * s)
            weight.append(0.5 if i == j else np.sqrt(2.0) / 2.0)
    return np.array(first), np.array(second), np.array(weight)


def conic_form(pr: CorpusProblem) -> ConicForm:
    n = pr.n
    blocks_A, blocks_b = [], []
    eye = sp.identity(n, format="csr")
    rows = [(pr.A, pr.lower, pr.upper), (eye, pr.lb, pr.ub)]
    # zero cone: equalities
    nz = 0
    for M, lo, up in rows:
        eq = np.isfinite(lo) & np.isfinite(up) & (lo == up)
        if np.any(eq):
            blocks_A.append(M[np.flatnonzero(eq)])
            blocks_b.append(up[eq])
            nz += int(eq.sum())
    nn = 0
    for M, lo, up in rows:
        eq = np.isfinite(lo) & np.isfinite(up) & (lo == up)
        upper = np.isfinite(up) & ~eq
        lower = np.isfinite(lo) & ~eq
        if np.any(upper):
            blocks_A.append(M[np.flatnonzero(upper)])
            blocks_b.append(up[upper])
            nn += int(upper.sum())
        if np.any(lower):
            blocks_A.append(-M[np.flatnonzero(lower)])
            blocks_b.append(-lo[lower])
            nn += int(lower.sum())
    psd = []
    for s, G, g0 in pr.lmis:
        first, second, weight = _svec_rows(s)
        Gs = sp.csr_matrix(G)
        sv = sp.diags(weight) @ (Gs[first] + Gs[second])
        blocks_A.append(-sv)
        blocks_b.append(weight * (g0[first] + g0[second]))
        psd.append(s)
    A = sp.vstack(blocks_A, format="csc") if blocks_A else sp.csc_matrix((0, n))
    b = np.concatenate(blocks_b) if blocks_b else np.zeros(0)
    P = sp.csc_matrix(pr.P) if pr.P is not None else sp.csc_matrix((n, n))
    return ConicForm(P, pr.q, A, b, nz, nn, psd)


def _smat(v: np.ndarray, s: int) -> np.ndarray:
    M = np.zeros((s, s))
    k = 0
    for j in range(s):
        for i in range(j + 1):
            M[i, j] = M[j, i] = v[k] if i == j else v[k] / np.sqrt(2.0)
            k += 1
    return M


def dual_cone_violation(cf: ConicForm, z: np.ndarray) -> float:
    """How far z is outside the dual cone (the zero cone's dual is free)."""
    worst = float(max(0.0, -np.min(z[cf.nz:cf.nz + cf.nn], initial=0.0)))
    k = cf.nz + cf.nn
    for s in cf.psd:
        t = s * (s + 1) // 2
        worst = max(worst, float(max(0.0, -np.linalg.eigvalsh(_smat(z[k:k + t], s))[0])))
        k += t
    return worst


def kkt_residuals(pr: CorpusProblem, cf: ConicForm, x: np.ndarray, z: np.ndarray) -> dict[str, float]:
    """The relative KKT residuals of the pair (x, z), recomputed from the data (see the module docstring)."""
    Px = cf.P @ x
    pobj = pr.objective(x)
    dobj = -0.5 * float(x @ Px) - float(cf.b @ z) + pr.r
    dual = np.abs(Px + cf.q + cf.A.T @ z)
    scale = 1.0 + float(np.max(np.abs(cf.q), initial=0.0)) + float(np.max(np.abs(Px), initial=0.0))
    s = cf.b - cf.A @ x
    return {
        "primal": pr.violation(x),
        "dual": float(np.max(dual, initial=0.0)) / scale,
        "cone": dual_cone_violation(cf, z) / (1.0 + float(np.max(np.abs(z), initial=0.0))),
        "gap": abs(pobj - dobj) / (1.0 + abs(pobj)),
        "complementarity": abs(float(s @ z)) / (1.0 + abs(pobj)),
    }


def clarabel_solve(cf: ConicForm, settings: dict | None = None):
    import clarabel

    opts = clarabel.DefaultSettings()
    opts.verbose = False
    for key, value in {**REFERENCE_SETTINGS, **(settings or {})}.items():
        setattr(opts, key, value)
    cones = []
    if cf.nz:
        cones.append(clarabel.ZeroConeT(cf.nz))
    if cf.nn:
        cones.append(clarabel.NonnegativeConeT(cf.nn))
    cones.extend(clarabel.PSDTriangleConeT(s) for s in cf.psd)
    solver = clarabel.DefaultSolver(sp.triu(cf.P, format="csc"), np.asarray(cf.q, float), cf.A, cf.b, cones, opts)
    return solver.solve()


# -- exact LP check -----------------------------------------------------------------------------

def _quiet_highs():
    """A ``highspy.Highs`` with its output off; the banner its constructor writes to the process's stdout
    (file descriptor 1, from C++) is dropped, so ``amcp solvers`` prints only its own lines."""
    import highspy

    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 1)
            h = highspy.Highs()
    finally:
        os.dup2(saved, 1)
        os.close(saved)
    h.setOptionValue("output_flag", False)
    return h


def _highs_basis(pr: CorpusProblem):
    import highspy

    h = _quiet_highs()
    h.setOptionValue("solver", "simplex")
    inf = highspy.kHighsInf
    A = sp.csc_matrix(pr.A)
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = pr.n, A.shape[0]
    lp.col_cost_ = np.asarray(pr.q, float)
    lp.offset_ = float(pr.r)
    lp.col_lower_ = np.where(np.isfinite(pr.lb), pr.lb, -inf)
    lp.col_upper_ = np.where(np.isfinite(pr.ub), pr.ub, inf)
    lp.row_lower_ = np.where(np.isfinite(pr.lower), pr.lower, -inf)
    lp.row_upper_ = np.where(np.isfinite(pr.upper), pr.upper, inf)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = A.indptr
    lp.a_matrix_.index_ = A.indices
    lp.a_matrix_.value_ = A.data
    h.passModel(lp)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        return None, str(h.modelStatusToString(h.getModelStatus()))
    basis = h.getBasis()
    return (list(basis.col_status), list(basis.row_status)), "optimal"


def _solve_exact(rows: list[dict[int, Fraction]], rhs: list[Fraction], n: int) -> list[Fraction] | None:
    """Solve the square system (sparse rows: column -> value) exactly; None if singular."""
    rows = [dict(r) for r in rows]
    rhs = list(rhs)
    pivots: list[tuple[int, int]] = []
    used = [False] * len(rows)
    for col in range(n):
        best = None
        for i, r in enumerate(rows):
            if not used[i] and r.get(col, 0) != 0 and (best is None or len(r) < len(rows[best])):
                best = i
        if best is None:
            return None
        used[best] = True
        pr_row, pr_rhs = rows[best], rhs[best]
        pv = pr_row[col]
        for i, r in enumerate(rows):
            if i != best and r.get(col, 0) != 0:
                f = r[col] / pv
                for c, v in pr_row.items():
                    new = r.get(c, 0) - f * v
                    if new == 0:
                        r.pop(c, None)
                    else:
                        r[c] = new
                rhs[i] -= f * pr_rhs
        pivots.append((best, col))
    x = [Fraction(0)] * n
    for i, col in pivots:
        x[col] = rhs[i] / rows[i][col]
    return x


def exact_lp_certificate(pr: CorpusProblem) -> tuple[np.ndarray | None, dict]:
    """(x, info): the optimal vertex of HiGHS's basis, verified optimal in exact arithmetic, or (None,
    info with the reason)."""
    import highspy

    m, n = pr.A.shape
    if m + n > EXACT_LP_MAX:
        return None, {"verified": False, "reason": f"LP of {m} rows and {n} columns is above EXACT_LP_MAX={EXACT_LP_MAX}"}
    basis, status = _highs_basis(pr)
    if basis is None:
        return None, {"verified": False, "reason": f"HiGHS simplex: {status}"}
    col_status, row_status = basis
    S = highspy.HighsBasisStatus
    A = sp.csr_matrix(pr.A)
    F = Fraction
    eqs: list[dict[int, Fraction]] = []
    rhs: list[Fraction] = []
    active: list[tuple[str, int, str]] = []   # (row|col, index, lower|upper|free)
    for i, st in enumerate(row_status):
        if st in (S.kLower, S.kUpper):
            bound = pr.lower[i] if st == S.kLower else pr.upper[i]
            if not np.isfinite(bound):
                return None, {"verified": False, "reason": f"basis puts row {i} at an infinite bound"}
            start, end = A.indptr[i], A.indptr[i + 1]
            eqs.append({int(c): F(float(v)) for c, v in zip(A.indices[start:end], A.data[start:end])})
            rhs.append(F(float(bound)))
            active.append(("row", i, "eq" if pr.lower[i] == pr.upper[i] else ("lower" if st == S.kLower else "upper")))
    for j, st in enumerate(col_status):
        if st in (S.kLower, S.kUpper, S.kZero, S.kNonbasic):
            if st == S.kZero:
                value, side = 0.0, "free"
            else:
                value = pr.lb[j] if st == S.kLower else pr.ub[j]
                side = "eq" if pr.lb[j] == pr.ub[j] else ("lower" if st == S.kLower else "upper")
            if not np.isfinite(value):
                return None, {"verified": False, "reason": f"basis puts column {j} at an infinite bound"}
            eqs.append({j: F(1)})
            rhs.append(F(float(value)))
            active.append(("col", j, side))
    if len(eqs) != n:
        return None, {"verified": False, "reason": f"basis has {len(eqs)} active constraints for {n} variables"}
    x = _solve_exact(eqs, rhs, n)
    if x is None:
        return None, {"verified": False, "reason": "basis matrix singular"}
    # primal feasibility, exactly
    for i in range(m):
        start, end = A.indptr[i], A.indptr[i + 1]
        ax = sum((F(float(v)) * x[c] for c, v in zip(A.indices[start:end], A.data[start:end])), F(0))
        if (np.isfinite(pr.upper[i]) and ax > F(float(pr.upper[i]))) or (np.isfinite(pr.lower[i]) and ax < F(float(pr.lower[i]))):
            return None, {"verified": False, "reason": f"basis vertex violates row {i} (exactly)"}
    for j in range(n):
        if (np.isfinite(pr.ub[j]) and x[j] > F(float(pr.ub[j]))) or (np.isfinite(pr.lb[j]) and x[j] < F(float(pr.lb[j]))):
            return None, {"verified": False, "reason": f"basis vertex violates the bound of column {j} (exactly)"}
    # dual feasibility: c = Σ_k y_k a_k over the active constraints (the transposed system), signs checked
    cols_t: list[dict[int, Fraction]] = [dict() for _ in range(n)]   # row j of Bᵀ: coefficient of y_k
    for k, eq in enumerate(eqs):
        for c, v in eq.items():
            cols_t[c][k] = v
    y = _solve_exact(cols_t, [F(float(c)) for c in pr.q], n)
    if y is None:
        return None, {"verified": False, "reason": "basis matrix singular (dual)"}
    for (what, idx, side), yk in zip(active, y):
        if (side == "lower" and yk < 0) or (side == "upper" and yk > 0) or (side == "free" and yk != 0):
            return None, {"verified": False, "reason": f"multiplier of {what} {idx} ({side}) has the wrong sign, exactly"}
    objective = sum((F(float(c)) * xj for c, xj in zip(pr.q, x)), F(float(pr.r)))
    return np.array([float(v) for v in x]), {"verified": True, "method": "HiGHS simplex basis, checked in fractions.Fraction",
                                             "active": len(active), "objective": float(objective)}


# -- the reference --------------------------------------------------------------------------------

def verify_reference(pr: CorpusProblem) -> str | None:
    """Compute and verify the reference of ``pr`` in place (``pr.reference``); None when accepted, else
    the reason it is left out."""
    import clarabel

    cf = conic_form(pr)
    sol, used = clarabel_solve(cf), REFERENCE_SETTINGS
    if sol.status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.PrimalInfeasible):
        sol, used = clarabel_solve(cf, FALLBACK_SETTINGS), FALLBACK_SETTINGS   # at Clarabel's defaults; verified all the same
    status = str(sol.status)
    x, z = np.asarray(sol.x, float), np.asarray(sol.z, float)
    if sol.status == clarabel.SolverStatus.PrimalInfeasible:
        scale = abs(float(cf.b @ z))
        if scale <= 0 or float(cf.b @ z) >= 0:
            return f"Clarabel: {status} without a certificate"
        res = {"farkas": float(np.max(np.abs(cf.A.T @ z), initial=0.0)) / scale,
               "cone": dual_cone_violation(cf, z) / scale}
        if max(res.values()) > KKT_TOL:
            return f"Clarabel: {status}, certificate residuals {res} above {KKT_TOL:g}"
        pr.reference = {"status": "infeasible", "certificate": res, "tolerance": KKT_TOL,
                        "solver": f"clarabel {clarabel.__version__}", "settings": used}
        return None
    if sol.status == clarabel.SolverStatus.DualInfeasible:
        return "unbounded (Clarabel: DualInfeasible)"
    if sol.status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved):
        return f"Clarabel: {status}"
    res = kkt_residuals(pr, cf, x, z)
    if max(res.values()) > KKT_TOL:
        worst = max(res, key=res.get)
        return f"KKT residual {worst} = {res[worst]:.2e} above {KKT_TOL:g} (Clarabel {status})"
    if res["primal"] > REFERENCE_FEAS_TOL and pr.problem_class != "lp":   # an LP's reference is its exact vertex
        return (f"KKT residual primal = {res['primal']:.2e} above REFERENCE_FEAS_TOL={REFERENCE_FEAS_TOL:g}, the tightest "
                f"verdict tolerance (Clarabel {status}; infeasible by less than the verdicts resolve, or inaccurate)")
    ref = {"status": "optimal", "x": x.tolist(), "objective": pr.objective(x), "kkt": res, "tolerance": KKT_TOL,
           "solver": f"clarabel {clarabel.__version__} ({status})", "settings": used}
    if pr.problem_class == "lp":
        x_exact, info = exact_lp_certificate(pr)
        if x_exact is None:
            return f"LP basis not verified: {info['reason']}"
        ref.update(x=x_exact.tolist(), objective=info["objective"], exact=info, kkt_interior_point=res)
    pr.reference = ref
    return None


def check_reference(pr: CorpusProblem, source: str = "corpus problem") -> None:
    """Verify the stored reference of ``pr`` again from its data; ProblemFileError naming the field of
    ``reference`` that does not check. Its layout (:func:`.corpus.check_reference_layout`); the reference
    recomputed here (:func:`verify_reference`) must be accepted and have the same status; an optimal one's
    stored ``x`` must be feasible (violation at most :data:`REFERENCE_FEAS_TOL`), its stored ``objective``
    equal to f(x) (:data:`CONSISTENCY_TOL`) and to the recomputed optimum f* (|f − f*| at most
    :data:`KKT_TOL` · (1 + |f*|), the accuracy every reference is accepted at)."""
    import copy

    check_reference_layout(pr.reference, pr.n, source)
    largest_lmi = max((s for s, _, _ in pr.lmis), default=0)
    if pr.size > MAX_CHECK_SIZE or largest_lmi > MAX_CHECK_LMI:
        raise ProblemFileError(f"{source}: reference", f"a problem of at most {MAX_CHECK_SIZE:,} stored nonzeros and LMI "
                               f"blocks of at most {MAX_CHECK_LMI} (the size whose reference is verified again on load)",
                               f"{pr.size:,} nonzeros, largest LMI block {largest_lmi}")
    stored = pr.reference
    fresh = copy.copy(pr)
    fresh.reference = {}
    why = verify_reference(fresh)
    if why is not None:
        raise ProblemFileError(f"{source}: reference", "a reference that can be verified again from the problem's data",
                               f"the problem's answer cannot be verified here ({why})")
    if stored["status"] != fresh.reference["status"]:
        raise ProblemFileError(f"{source}: reference.status", f"{fresh.reference['status']!r} (verified again here)",
                               repr(stored["status"]))
    if stored["status"] != "optimal":
        return
    x = np.asarray(stored["x"], float)
    violation = pr.violation(x)
    if violation > REFERENCE_FEAS_TOL:
        raise ProblemFileError(f"{source}: reference.x", f"a feasible point (largest violation at most {REFERENCE_FEAS_TOL:g})",
                               f"a point violating the constraints by {violation:.3e}")
    f, f_x, f_star = float(stored["objective"]), pr.objective(x), float(fresh.reference["objective"])
    if abs(f - f_x) > CONSISTENCY_TOL * (1.0 + abs(f_x)):
        raise ProblemFileError(f"{source}: reference.objective", f"f(reference.x) = {f_x:.17g}", f"{f:.17g}")
    if abs(f - f_star) > KKT_TOL * (1.0 + abs(f_star)):
        raise ProblemFileError(f"{source}: reference.objective",
                               f"the optimum {f_star:.17g} verified again here (relative tolerance {KKT_TOL:g})", f"{f:.17g}")


def load_checked_corpus(paths) -> list[CorpusProblem]:
    """The corpus problems under ``paths`` (:func:`.corpus.load_corpus`), each reference verified again
    (:func:`check_reference`): a corpus whose answers do not check is refused (ProblemFileError)."""
    problems = load_corpus(paths)
    for pr in problems:
        check_reference(pr, f"corpus problem {pr.id}")
    return problems


__all__ = ["CONSISTENCY_TOL", "EXACT_LP_MAX", "KKT_TOL", "MAX_CHECK_LMI", "MAX_CHECK_SIZE", "check_reference", "load_checked_corpus", "REFERENCE_FEAS_TOL", "REFERENCE_SETTINGS", "ConicForm", "clarabel_solve", "conic_form",
           "exact_lp_certificate", "kkt_residuals", "verify_reference"]
