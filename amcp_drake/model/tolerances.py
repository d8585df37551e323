"""The tolerances of the paper's claims, one name per tolerance.

Every claim of the certificate (:mod:`amcp_drake.certificate`), the design checks
(:mod:`amcp_drake.offline.checks`), the online answer checks (:mod:`amcp_drake.online.answer_checks`) and the
property suite's independent re-checks (``amcp_properties``) judge their margins with the constants of this
module; the table of claims (:mod:`amcp_drake.model.claim_table`) says which claim uses which. A claim passes
when its margin >= −tolerance (:func:`amcp_drake.model.check_result.judge`); a *relative* tolerance is scaled
by the size of the quantity named in the claim's row.

Two kinds of constants live here:

* **claim tolerances** judge a recorded run or design (certificate, design checks, property suite);
* **gate tolerances** (the last section) decide whether the online loop accepts a solver's answer before using it.
  A gate is never looser than the claim the answer feeds (equal, or an order below, as each says), so an
  answer that passes its gate is one the certificate accepts, and loosening a gate never loosens a claim.

Tolerances of the solvers themselves (feasibility options, vertex merging, retry settings) are not claims
and stay with the code that uses them.
"""

from __future__ import annotations

# -- identities and memberships of recorded data ---------------------------------------------------------
#: Identities recomputed from recorded float64 data (model (1), control law (21), θ̂_0 of (12)): the
#: trajectory file stores floats with repr (exact round trip), so only float64 rounding of a few
#: products (~1e-15 relative, states of order 1-10) separates both sides. Absolute, state/input units.
IDENTITY_TOL = 1e-9
#: w_k ∈ W and θ* ∈ Θ (Assumption 1): recorded data evaluated exactly; rounding of H_w w only. Absolute,
#: on rows of unit norm (θ) or of W's own scaling (w).
DATA_MEMBERSHIP_TOL = 1e-9
#: The precondition μ‖D(x_k, u_k)‖₂² <= 1 of Lemma 5 at the visited points: exact arithmetic on recorded
#: data (SVD rounding). Absolute, dimensionless.
MU_TOL = 1e-12

# -- set membership ---------------------------------------------------------------------------------------
#: Set-membership margins in θ units on rows of unit norm: θ* ∈ Θ_k, Θ ⊆ Θ_0, both sides of (10), the
#: model consistency Θ_(k−1) ∩ Δ_k ≠ ∅, (x_k, u_k) ∈ Z, and the dual outer bound of an answer of (9). The
#: LP (9) is solved to ~1e-10 (Clarabel) and the checks' own HiGHS LPs are feasible to ~1e-9; 1e-7 is
#: HiGHS' default primal feasibility tolerance, so anything below it is solver noise. Absolute.
SET_TOL = 1e-7
#: θ̂_k ∈ Θ and the projected LMS update (12) (its variational inequality in ‖θ̃ − θ̂‖·diam(Θ) units):
#: the projection QP is solved to ~1e-8, which bounds both by ~1e-8 on Θ = [−1, 1]^p. Also where the report
#: counts θ̂_k as outside Θ_k. Absolute, θ units.
PROJECTION_TOL = 1e-7
#: Lemma 5: both sides are sums of squares of recorded data; the projection QP's accuracy moves
#: (1/μ)‖θ̂ − θ*‖² by ~1e-9, rounding of the sums by ~1e-14 relative. Absolute.
LEMMA5_TOL = 1e-8
#: The property suite's Lemma 5 re-check, on the relative margin (rhs − lhs)/(1 + rhs): sums of squares of
#: size up to ~1e3 with round-off ~1e-9 each. Relative.
LEMMA5_REL_TOL = 1e-7

# -- the tube of Proposition 9 and the QP (20) -----------------------------------------------------------
#: The tube and its multipliers: x_k ∈ X_(0|k), (5b), (5c), α >= 0, the terminal set, Λ >= 0, (15c), (15d)
#: at the recorded (z, α, v, Λ), in the certificate, in the answer checks of the online loop (a gate equal
#: to the claim) and in the property suite. Clarabel's default feasibility tolerance is 1e-8 relative to data
#: of order 1-10, vertex expansion multiplies residuals by |x^j| <= ~5 and |θ| <= 1.5; 1e-6 allows that and
#: is far below any violation that matters (bounds of order 0.1-1). Absolute, in the units of each row.
TUBE_TOL = 1e-6
#: KKT residuals of the QP (20) rebuilt from the record (stationarity, primal feasibility on rows of unit
#: norm, complementarity), relative to the stationarity scale s (certificate.optimality).
OPTIMALITY_TOL = 1e-5
#: The recorded cost against (17) or (19) evaluated with numpy: |cost − J| <= tolerance·max(1, |J|)
#: (Clarabel stops at a relative gap of 1e-8; the condensed and the stage-wise evaluation differ by
#: round-off). Relative.
COST_REL_TOL = 1e-6

# -- the offline design -----------------------------------------------------------------------------------
#: The eigenvalue check of (16), relative to the size of its terms (max of ‖A_clᵀPA_cl‖, ‖P‖, ‖Q + KᵀRK‖
#: over the vertices): forming the matrix and eigvalsh err by about n·1e-16 of that, so 1e-12 leaves a
#: factor 1e3 for round-off and no room for a violation. Relative because (16) is homogeneous in the
#: units of x (docs/decisions.md, "Gain LMI (16) on badly scaled systems").
EIG_TOL_REL = 1e-12
#: Round-off of set inclusions evaluated at enumerated vertices (Qhull accuracy ~1e-12): the design checks
#: of X0 and X_f (absolute, X0 units) and the QP's vertex list of X0 (relative to max(1, largest vertex
#: coordinate)).
VERTEX_TOL = 1e-8
#: The offline constants w̄, f̄ of Proposition 9 against their recomputation from the vertices of W and X0.
#: Absolute, X0 units.
OFFLINE_CONSTANTS_TOL = 1e-6

# -- Section 4.2: persistent excitation -------------------------------------------------------------------
#: λ_min of the realised PE window Gram against the enforced level, relative to max(1, level): the first
#: input of the window sits on the level's boundary up to the QP's accuracy.
PE_LEVEL_TOL = 1e-6
#: The applied input against the enforced PE bounds [lo, hi], relative to max(1, |bound|).
PE_BOUND_TOL = 1e-7

# -- premises ---------------------------------------------------------------------------------------------
#: The independent LP slack t (rows of unit norm) below which x_0 is outside the feasible region of (20),
#: premise 𝔻(x_0, Θ_0) ≠ ∅: ten times the LP's own feasibility tolerance (1e-10), so that a start 1e-7
#: outside is not met. Absolute.
PREMISE_LP_TOL = 1e-9

# -- gates of the online answer checks ----------------------------------------------------------------------
# (online.answer_checks; the tube's gate is TUBE_TOL and the dual outer bound's SET_TOL, equal to their claims)
#: Projection (12): a point may leave the target set by this much on unit rows (θ units). The backends solve
#: the scaled QP at 1e-10 (violations <= 1e-10 × the scale, ~1e-9 at most on the property suite), and a
#: slab emptied by round-off (width in [−1e-8, 0)) is answered by its mid-plane, <= 5e-9 outside each row;
#: 1e-8 covers both and is an order below the claim's :data:`PROJECTION_TOL`.
PROJECTION_MEMBERSHIP_TOL = PROJECTION_TOL / 10
#: Projection: ‖θ̂ − θ̃‖ may exceed the distance of a known point of S by this much relative to
#: max(that distance, 1) (round-off of two norms of order 1, plus the solver's 1e-10 gap on the scaled
#: objective). The floor 1 makes it absolute (θ units, as PROJECTION_MEMBERSHIP_TOL) for short distances.
PROJECTION_CANDIDATE_RTOL = 1e-8
#: Projection KKT: rows within this of θ̂ (θ units, unit rows) count as active: the membership gate times 10,
#: so thin slabs keep both rows active.
PROJECTION_ACTIVE_TOL = 10 * PROJECTION_MEMBERSHIP_TOL
#: Projection KKT: ‖θ̃ − θ̂ − Σ_active λ_i [H]_i‖ (λ >= 0, by NNLS) may be this, relative to
#: max(‖θ̃ − θ̂‖, 1). The residual bounds the variational inequality of the claim ``lms_update`` by
#: residual × diam(S); on sets of diameter ~1 that is the claim's :data:`PROJECTION_TOL`.
PROJECTION_KKT_RTOL = PROJECTION_TOL
#: Set update (9): h may exceed h_(k−1) by this (unit rows, θ units). The LP at 1e-10 drifts by ~1e-9; 1e-8
#: is an order above that and an order below the nesting claim's :data:`SET_TOL`.
SET_NESTED_TOL = SET_TOL / 10
#: Set update (9): a returned maximiser may violate a row of Θ_(k−1) ∩ Δ_k, or miss its offset, by this
#: (θ units, unit rows): the primal feasibility of the LP at 1e-10 on data of order 1-1e3.
SET_POINT_TOL = 1e-7
