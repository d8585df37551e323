"""Clarabel settings tried, in order, when a tube MPC QP (20) ends "inaccurate" (AlmostSolved) or
with a numerical solver error (InsufficientProgress).

Both backends use this ladder for the plain form (15) of the QP (both costs), so a retry cannot
make them disagree, and for the vertex form too (after its first try without and its
second with iterative refinement; :func:`retry_ladder`): the property suite's lockstep comparison of
the vertex forms found a Drake step at 1e-10 that ended AlmostSolved after both, answered only by the
controller's fallback, where cvxpy's solved it. Each retry is a full solve
with Clarabel's default tolerances (1e-8); only a status "Solved" is accepted, so a retry never
turns an inaccurate answer into "optimal" by loosening anything. Which rung solved a step is
written into ``MPCSolution.detail``.

Measured (min-max cost (19) in its second-order-cone form, Hypothesis min-max cases of
the property suite, 12 steps each): on 21 steps whose first solve ended AlmostSolved, one retry
without equilibration left 1 of 21 inaccurate, the smaller static regularisation 0 of 21. Over 200
fresh cases (2600 steps) per backend, with the ladder every step solved to "optimal"; retries were
needed on 340 Drake steps (rung 1: 314, rung 2: 21, rung 3: 5) and 32 cvxpy steps (rung 1: 20,
rung 2: 11, rung 4: 1). The stalls are Clarabel's step length collapsing to 0 while the primal
residual grows (ill-conditioned KKT system near several active cones), not an iteration limit:
raising ``max_iter`` changes nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from amcp_drake.model.status import SolveStatus

#: Statuses of the first solve that start the retries: "inaccurate" (AlmostSolved) and a solver
#: error (Clarabel's InsufficientProgress / NumericalError). Infeasible and unbounded are answers.
RETRIED = frozenset({SolveStatus.INACCURATE, SolveStatus.ERROR})

#: Clarabel settings tried first for the certainty-equivalence cost (17) in both formulations and
#: both backends (the user's options override them): iterative refinement off. Measured on Example 1
#: (8-facet X0, N = 10): plain form (15) 26 -> 17.5 ms CPU per Drake solve, vertex form
#: 1.91 -> 1.37 ms, v unchanged to 1e-11. A first try whose status is in RETRIED is solved
#: again with the backend's own options (refinement on), then the ladder below.
NO_REFINEMENT = {"iterative_refinement_enable": False}
#: Clarabel tolerances tried first for the min–max cost (19) in both backends (the user's options
#: override them). Its epigraph cones meet at a nonsmooth point (several tube vertices attain the max),
#: where an interior-point answer at the default 1e-8 fixes the plan only to about √tol: on 30 generated
#: min–max runs (numpy seeds 5000–5029 of random_case, N <= 6, 12 steps, Drake) the certificate's KKT
#: claim ``qp_optimality`` failed 2 honest runs (stationarity 1.3e-5, 2.2e-5 > 1e-5; the two backends'
#: costs 2e-6 apart) and passed all 30 at 1e-10. At 1e-10 alone 9 of the 30 runs stopped on
#: "InsufficientProgress", so a first try that ends in RETRIED is solved again at the backend's own
#: options (then the ladder), exactly as after a first try without refinement.
MINMAX_TIGHT = {"tol_gap_abs": 1e-10, "tol_gap_rel": 1e-10, "tol_feas": 1e-10}
#: The note of a step whose MINMAX_TIGHT first try gave no answer (studies.resolves counts it).
MINMAX_TIGHT_NOTE = "re-solved at the default tolerances"

#: Option sets of the retries (Clarabel setting names, the same in Drake and cvxpy).
CLARABEL_RETRY_LADDER: tuple[dict, ...] = (
    {"equilibrate_enable": False},
    {"static_regularization_constant": 1e-10},
    {"equilibrate_enable": False, "static_regularization_constant": 1e-10},
    {"equilibrate_enable": False, "max_step_fraction": 0.95},
    {"max_step_fraction": 0.9},
    # added after the thorough property profile (min-max cost, n = 3, N = 3, x_0 on the boundary):
    # a Drake step AlmostSolved under every rung above was Solved by each of these two (tried on it:
    # 16 settings; the cvxpy form of the same step was Solved at rung 2)
    {"static_regularization_constant": 1e-12},
    {"max_step_fraction": 0.5},
)


#: The note and the :class:`~amcp_drake.backends.base.Attempt` rung of the solve after a failed first try.
REFINE_NOTE = "re-solved with iterative refinement"
FIRST_RUNG = {REFINE_NOTE: "refine", MINMAX_TIGHT_NOTE: "default_tolerances"}
#: The rung of the retry ladder (its option sets: ``Attempt.options`` ``(("retry", "<i>"),)``, 1-based).
LADDER_RUNG = "clarabel_retry"


def first_try(minmax: bool, refine: bool, user_options) -> tuple[dict | None, str]:
    """(``first``, ``first_note``) of :func:`solve_with_retries` for the tube QP (20), the same in both
    backends: ``refine`` (the controller's re-solve of an answer that failed its checks): no first try;
    min–max cost (19): :data:`MINMAX_TIGHT`; certainty-equivalence cost: :data:`NO_REFINEMENT`. The
    user's options (names in ``user_options``) override the first try's."""
    if refine:
        return None, ""
    if minmax:
        return {k: v for k, v in MINMAX_TIGHT.items() if k not in user_options}, MINMAX_TIGHT_NOTE
    return {k: v for k, v in NO_REFINEMENT.items() if k not in user_options}, REFINE_NOTE


def solve_with_retries(solve: Callable[[dict | None], tuple[Any, SolveStatus, float]],
                       first: dict | None = None,
                       first_note: str = REFINE_NOTE) -> tuple[Any, SolveStatus, float, str, tuple]:
    """``solve(extra_options)`` once with ``first`` (when given, e.g. :data:`NO_REFINEMENT` or
    :data:`MINMAX_TIGHT`; ``first_note`` says what the solve after a failed first try is), then
    with None (the backend's own options), then, while its status is in RETRIED, once per rung of
    the ladder. Returns the last (result, status), the summed solver time, a note for
    ``MPCSolution.detail`` (the rung that ended the retries, "after N Clarabel retries" when none
    did, or "" when no retry was needed) and the re-solves that ran after the first solve as
    (rung, options) pairs (:data:`FIRST_RUNG`, :data:`LADDER_RUNG`). The caller decides whether the
    solver is Clarabel (the ladder's settings are Clarabel's)."""
    spent_first, note, rungs = 0.0, "", ()
    if first:
        result, status, spent_first = solve(first)
        if status not in RETRIED:
            return result, status, spent_first, "", ()
        note, rungs = f"{first_note}; ", ((FIRST_RUNG.get(first_note, "default_options"), ()),)
    result, status, elapsed = solve(None)
    result, status, elapsed, ladder_note, ladder = retry_ladder(solve, result, status, elapsed + spent_first)
    return result, status, elapsed, note + ladder_note if ladder_note else note.rstrip("; "), rungs + ladder


def retry_ladder(solve: Callable[[dict | None], tuple[Any, SolveStatus, float]], result: Any, status: SolveStatus,
                 elapsed: float) -> tuple[Any, SolveStatus, float, str, tuple]:
    """The ladder alone, after a solve that ended with (``result``, ``status``, ``elapsed``): while the
    status is in RETRIED, ``solve(extra_options)`` once per rung. Returns as :func:`solve_with_retries`,
    the note "" and no rungs when no retry was needed. Used by :func:`solve_with_retries` and by the
    vertex forms, whose first two solves (without, then with iterative refinement) are their own."""
    if status not in RETRIED:
        return result, status, elapsed, "", ()
    rungs = []
    for rung, extra in enumerate(CLARABEL_RETRY_LADDER):
        result, status, spent = solve(extra)
        elapsed += spent
        rungs.append((LADDER_RUNG, (("retry", str(rung + 1)),)))
        if status not in RETRIED:
            return result, status, elapsed, describe(rung), tuple(rungs)
    return result, status, elapsed, f"after {len(CLARABEL_RETRY_LADDER)} Clarabel retries", tuple(rungs)


def describe(rung: int) -> str:
    """Text for ``MPCSolution.detail`` when retry ``rung`` (0-based) solved the problem."""
    opts = ", ".join(f"{k}={v}" for k, v in CLARABEL_RETRY_LADDER[rung].items())
    return f"Clarabel retry {rung + 1} ({opts})"
