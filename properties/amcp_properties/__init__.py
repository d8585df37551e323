"""amcp_properties: the Hypothesis property suite of amcp-drake.

One property test per claim of Lorenzen, Cannon & Allgöwer (2019), each run on both online
backends (``drake``, ``cvxpy``):

==========================================  ================================================
test                                        claim (spec numbering)
==========================================  ================================================
test_theorem14_i_recursive_feasibility      Theorem 14 (i)
test_theorem14_ii_theta_star_in_theta_k...  Theorem 14 (ii): θ* ∈ Θ_k, θ̂_k ∈ Θ
test_theorem14_iii_state_and_input_...      Theorem 14 (iii): (x_k, u_k) ∈ Z
test_lemma3_update_is_consistent_...        Lemma 3, (10)
test_lemma5_lms_error_energy_is_bounded...  Lemma 5 (exact inequality for every m) and (11)
test_proposition9_tube_contains_every_...   Proposition 9, by vertex enumeration
test_assumption11_terminal_set_is_...       Assumption 11 for X_f, every vertex of Θ
test_corollary16_state_converges_...        Corollary 16
test_finite_gain_l2_ratio_stays_bounded     (22), with what a finite run can and cannot show
test_backends_agree_in_lockstep             Drake and cvxpy agree step by step
test_vertex_forms_agree_in_lockstep         the same for the vertex form of (20)
==========================================  ================================================

Modules: :mod:`.strategies` (problems built valid, not filtered), :mod:`.feasible` (the feasible
set of (20) as an independent LP, for boundary initial states), :mod:`.cases` (a run and its
memoisation), :mod:`.claims` and :mod:`.geometry` (the checks, numpy/scipy only),
:mod:`.lockstep`, :mod:`.coverage`, :mod:`.profiles`, :mod:`.failures`, :mod:`.mutants`.

Running::

    python -m pytest --pyargs amcp_properties          # or: amcp verify [--profile ...] [--mutants]

Environment: ``AMCP_PROFILE`` (``ci`` default, ``thorough``), ``AMCP_BACKENDS`` (default
``drake,cvxpy``), ``AMCP_SEED`` (ci seed), ``AMCP_FAILURE_DIR`` (default ``./amcp-failures``),
``AMCP_COVERAGE_FILE`` (coverage summary as JSON). A failing example is saved as a problem file
plus trajectory and replayed with ``python -m amcp_properties.failures DIR``.
"""
