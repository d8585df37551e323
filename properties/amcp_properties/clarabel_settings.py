"""Clarabel settings profiles that emulate another machine, for the shipped-answers property under them
(``test_shipped_answers_settings.py``) and for ``benchmarks/plain_form_profiles.py``.

A QP that Clarabel solves to "Solved" only by luck ends "AlmostSolved" when round-off changes (another
CPU, BLAS or load-dependent thread schedule); changing settings that do not loosen any tolerance moves
the iterates as another machine would. Each profile is passed as the backends' ``solver_options``
(every Clarabel solve of the run, under the first tries and retry rungs of
``amcp_drake.backends.clarabel_retry``). Only numeric and boolean settings: Drake's Clarabel takes no
string options (``direct_solve_method``). Tolerances are equal to or tighter than Clarabel's defaults.
"""

from __future__ import annotations

#: name -> Clarabel settings (Clarabel's own names, the same in Drake and cvxpy).
CLARABEL_PROFILES: dict[str, dict] = {
    # a larger static regularisation of the KKT systems (default 1e-8), presolve off
    "regularised": {"static_regularization_constant": 1e-7, "presolve_enable": False},
    # tighter tolerances (default 1e-8) with more iterations, fewer equilibration passes (default 10)
    "tight": {"tol_gap_abs": 1e-9, "tol_gap_rel": 1e-9, "tol_feas": 1e-9, "max_iter": 400,
              "equilibrate_max_iter": 5},
    # shorter steps (default 0.99), iterative refinement from the first try
    "short_steps": {"max_step_fraction": 0.95, "iterative_refinement_enable": True},
}

#: Settings measured but not required (docs/results.md, "The Drake plain form under other Clarabel
#: settings").
MEASURED_ONLY_PROFILES: dict[str, dict] = {
    "small_regularisation": {"static_regularization_constant": 1e-9},
    "short_small_reg": {"max_step_fraction": 0.95, "iterative_refinement_enable": True,
                        "static_regularization_constant": 1e-9},
    "unequilibrated": {"equilibrate_enable": False},
}

#: The shipped examples of four to eight states whose plain form (15) is large (n = 6, 8 and the 102-facet
#: quadrotor X0), and the closed-loop steps each runs under every profile (the first steps, from x0 on
#: the boundary of the feasible region, are the hard ones).
LARGE_EXAMPLE_STEPS: dict[str, int] = {"mass_chain3": 4, "mass_chain4": 2, "ji2022_quadrotor": 2}
