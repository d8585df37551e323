"""The table of claims: one row per claim of the certificate, read by everything that checks a claim.

A row says what the claim is (its id in certificate.json, the result of Lorenzen, Cannon & Allgöwer (2019)
it checks, its name and statement), how it is judged (the tolerance of :mod:`amcp_drake.model.tolerances`,
absolute or relative to what, strict or not: :func:`amcp_drake.model.check_result.judge`) and what it rests
on (the data it needs, the model consistency of the data, the premises that excuse it). Its readers:

* the certificate (:mod:`amcp_drake.certificate`): every claim's tolerance, its statement and name (a run
  variant, e.g. a time-varying θ* or the min–max cost, words its own), the relative marks
  (``certify.RELATIVE_TOLERANCES``), the claims a measured run cannot check, the claims resting on
  ``data_consistency`` (``consistency.RESTS_ON_CONSISTENCY``), the data claims and the design premises
  (``premises.DATA_CLAIMS``, ``premises.DESIGN_PREMISES``); the design checks of
  :mod:`amcp_drake.offline.checks` read their rows (``design.*``) the same way;
* the report (:mod:`amcp_drake.certificate.report_groups`): which of the paper's results each claim checks;
* ``docs/certificate.md``: its table of claims is :func:`markdown_table` (a test compares them);
* the edge tests (``tests/test_claim_edges.py``, parametrised over the rows) and the property suite's
  registry of second methods (``amcp_properties.nversion``);
* the online answer checks (:mod:`amcp_drake.online.answer_checks`): their gates are the rows' tolerances
  of the claims the answers feed (:data:`GATES`).
"""

from __future__ import annotations

from dataclasses import dataclass

from amcp_drake.model import tolerances as tol

#: What a claim needs beyond the controller's record; a measured run (θ* and w unknown) reports the claims
#: that need either ``not_applicable``.
THETA_STAR, W, THETA_STAR_AND_W = "θ*", "the disturbances w_k", "θ* and the disturbances w_k"
#: The premises of the paper's results (certificate.premises): 𝔻(x_0, Θ_0) ≠ ∅, Assumption 8, (11).
INITIAL_FEASIBILITY, ASSUMPTION_8, MU_CONDITION_11 = "initial_feasibility", "assumption_8", "mu_condition_11"
DESIGN_PREMISE_IDS = (ASSUMPTION_8, MU_CONDITION_11)


@dataclass(frozen=True)
class Claim:
    """One claim of the certificate.

    ``tolerance``: a claim passes when margin >= −tolerance (``strict``: margin > −tolerance, for the strict
    inequalities of the paper); ``relative`` names what a relative tolerance is scaled by ("" absolute).
    ``needs``: θ* and/or w, which a measured run does not have ("" none). ``rests_on_consistency``: the lag
    between the claim's step and the transition whose data must satisfy the model (``data_consistency``),
    None when the claim does not rest on it. ``data``: a claim about the recorded data alone, never excused by
    a premise. ``premise``: the premise this design claim is (its failure excuses the others).
    ``result``: the paper's result it checks, as the report groups them (report_groups.PAPER_RESULTS)."""

    id: str
    paper: str
    family: str
    result: str
    name: str
    statement: str
    tolerance: float
    relative: str = ""
    strict: bool = False
    needs: str = ""
    rests_on_consistency: int | None = None
    data: bool = False
    premise: str = ""

    @property
    def excused_by(self) -> tuple[str, ...]:
        """The premises whose failure moves a failure of this claim to ``not_claimed`` (certificate.premises.apply):
        none for a data claim (no premise excuses data that contradict each other; a data claim with nothing to
        check is moved like any claim that could not run), the design premises for a design claim (X0, X_f and
        (16) are built on the same K), every premise otherwise."""
        if self.data:
            return ()
        if self.family == "design":
            return DESIGN_PREMISE_IDS
        return (INITIAL_FEASIBILITY, *DESIGN_PREMISE_IDS)


_D, _A, _T, _S, _E, _TB, _C, _X = ("design", "assumptions", "theorem14", "set_membership", "point_estimate", "tube",
                                   "cost", "excitation")

#: Every claim, in the certificate's reading order.
CLAIMS: tuple[Claim, ...] = (
    # -- the offline design (offline.checks.verify_design, certificate.tube.x0_vertex_list) --------------------
    Claim("design.terminal_cost_16", "(16)", _D, "design", "terminal cost (16)",
          "A_cl(θ)ᵀ P A_cl(θ) + Q + KᵀRK ⪯ P at every vertex of Θ", tol.EIG_TOL_REL,
          relative="eigenvalue tolerance relative to the size of the terms of (16)"),
    Claim("design.assumption_8", "Assumption 8", _D, "design", "Assumption 8",
          "A_cl(θ) Schur stable at every vertex of Θ (spectral radius < 1)", 0.0, strict=True, premise=ASSUMPTION_8),
    Claim("design.x0_contractive", "Appendix A.1", _D, "design", "X0 contractive",
          "Appendix A.1: lambda_bar = max_k,i [h_bar^k]_i < 1", tol.VERTEX_TOL),
    Claim("design.x0_robustly_invariant", "(14), Appendix A.1", _D, "design", "X0 robustly invariant",
          "A_cl(θ)X0 ⊕ W ⊆ X0 for all θ ∈ Θ (h_bar^k + w_bar <= 1)", tol.VERTEX_TOL),
    Claim("design.w_bar_f_bar_recomputed", "Proposition 9", _D, "design", "w_bar, f_bar recomputed",
          "offline constants of Prop. 9 match vertex recomputation", tol.OFFLINE_CONSTANTS_TOL),
    Claim("design.x_f_non_empty", "Assumption 11", _D, "design", "X_f non-empty",
          "Assumption 11: X_f ≠ ∅, i.e. it holds the tube's steady state (0, α_∞), α_∞ = max w̄_i / (1 − h̄^k_i)",
          tol.VERTEX_TOL),
    Claim("design.x_f_invariant", "Assumption 11", _D, "design", "X_f invariant",
          "Assumption 11: A_cl(θ)({z} ⊕ αX0) ⊕ W ⊆ {z⁺} ⊕ α⁺X0 with (z⁺, α⁺) ∈ X_f, for all θ ∈ Θ", tol.VERTEX_TOL),
    Claim("design.x_f_in_z", "Assumption 11", _D, "design", "X_f in Z",
          "Assumption 11: (x, Kx) ∈ Z for all x ∈ {z} ⊕ αX0, (z, α) ∈ X_f", tol.VERTEX_TOL),
    Claim("design.mu_condition_11", "(11)", _D, "design", "mu condition (11)",
          "(11): 1/μ > sup ‖D(x,u)‖₂² over the (x,u) region", 0.0, strict=True, premise=MU_CONDITION_11),
    Claim("design.x0_vertices", "(14)", _D, "design", "X0 vertex list",
          "(14): the vertices x^j used by the QP are exactly the vertices of X0", tol.VERTEX_TOL,
          relative="relative to the largest vertex coordinate (floor 1)"),
    # -- Assumption 1, (1), (21), the precondition of Lemma 5 (certificate.claims, certificate.consistency) ----
    Claim("theta_star_in_Theta", "Assumption 1, (3)", _A, "assumptions", "θ* ∈ Θ",
          "Assumption 1, (3) (Assumption 17 for a sequence θ*_k): the true parameter lies in the prior set Θ",
          tol.DATA_MEMBERSHIP_TOL, needs=THETA_STAR, data=True),
    Claim("w_in_W", "Assumption 1", _A, "assumptions", "w_k ∈ W", "Assumption 1: every recorded disturbance lies in W",
          tol.DATA_MEMBERSHIP_TOL, needs=W, data=True),
    Claim("model_consistent", "(1)", _A, "assumptions", "states follow (1)",
          "(1): x_{k+1} = A(θ*)x_k + B(θ*)u_k + w_k for the recorded θ*, u_k and w_k", tol.IDENTITY_TOL,
          needs=THETA_STAR_AND_W, data=True),
    Claim("data_consistency", "Assumption 1, Lemma 3, (6)", _A, "assumptions", "Θ_(k−1) ∩ Δ_k ≠ ∅",
          "model consistency (Assumption 1, Lemma 3): the data never contradicted the declared Θ and W, "
          "Θ_(k−1) ∩ Δ_k ≠ ∅ at every step", tol.SET_TOL, data=True),
    Claim("control_law", "(21)", _A, "assumptions", "u_k = K x_k + v*_0|k", "(21): the applied input is the MPC law",
          tol.IDENTITY_TOL, data=True),
    Claim("mu_precondition", "Lemma 5, (11)", _A, "assumptions", "μ‖D(x_k,u_k)‖² <= 1",
          "Lemma 5 precondition ((11) at the visited points): μ‖D(x_k, u_k)‖₂² <= 1", tol.MU_TOL),
    # -- Theorem 14 ---------------------------------------------------------------------------------------------
    Claim("recursive_feasibility", "Theorem 14 (i)", _T, "theorem14-i", "recursive feasibility",
          "Theorem 14 (i): 𝔻(x_k, Θ_k) ≠ ∅ and the QP (20) solved at every step", 0.0, rests_on_consistency=0),
    Claim("theta_star_in_Theta_k", "Theorem 14 (ii), Lemma 3", _T, "theorem14-ii", "θ* ∈ Θ_k",
          "Theorem 14 (ii), Lemma 3: the true parameter lies in every set estimate Θ_k", tol.SET_TOL, needs=THETA_STAR),
    Claim("theta_hat_in_Theta", "Theorem 14 (ii), Lemma 5", _T, "theorem14-ii", "θ̂_k ∈ Θ",
          "Theorem 14 (ii), Lemma 5: every point estimate lies in Θ", tol.PROJECTION_TOL),
    Claim("state_input_constraints", "Theorem 14 (iii), (4)", _T, "theorem14-iii", "(x_k, u_k) ∈ Z",
          "Theorem 14 (iii), (4): every visited state and its input satisfy F x + G u <= 1", tol.SET_TOL,
          rests_on_consistency=0),
    # -- Lemma 3, (10) ------------------------------------------------------------------------------------------
    Claim("Theta0_contains_Theta", "Lemma 3", _S, "lemma3", "Θ ⊆ Θ_0",
          "Lemma 3 premise: the initial set estimate Θ_0 contains the prior set Θ", tol.SET_TOL),
    Claim("Theta_k_nested", "Lemma 3, (10); (25)", _S, "lemma3", "Θ_{k+1} ⊆ Θ_k",
          "Lemma 3, (10) right: the set estimates are nested", tol.SET_TOL),
    Claim("Theta_k_lower_inclusion", "Lemma 3, (10)", _S, "lemma3", "Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1}",
          "Lemma 3, (10) left: the update keeps every parameter consistent with the new data", tol.SET_TOL),
    # -- (12), Lemma 5 ------------------------------------------------------------------------------------------
    Claim("lms_update", "(12), Remark 7", _E, "lemma5", "θ̂ follows (12)",
          "(12): θ̂_(k+1) is the projection onto Θ of the LMS step from the recorded data", tol.PROJECTION_TOL),
    Claim("lemma5", "Lemma 5", _E, "lemma5", "Lemma 5 inequality",
          "Lemma 5: (1/μ)‖θ̂_(m+1) − θ*‖² + Σ_(k<=m) ‖x̃_(1|k)‖² <= (1/μ)‖θ̂_0 − θ*‖² + Σ_(k<=m) ‖w_k‖², every m",
          tol.LEMMA5_TOL, needs=THETA_STAR_AND_W),
    # -- Proposition 9: the tube and its multipliers (certificate.tube) ------------------------------------------
    Claim("tube_contains_state", "(5a), (15b)", _TB, "proposition9", "x_k ∈ X_0|k",
          "(5a), (15b): the tube starts at the measured state", tol.TUBE_TOL),
    Claim("tube_contains_next_state", "(5b)", _TB, "proposition9", "x_(k+1) ∈ X_1|k",
          "(5b) on the run: the realised successor lies in the first predicted cross-section", tol.TUBE_TOL,
          rests_on_consistency=1),
    Claim("tube_propagation", "(5b)", _TB, "proposition9", "tube propagation (5b)",
          "(5b): A(θ)X_(l|k) ⊕ B(θ)v_l ⊕ W ⊆ X_(l+1|k) for all θ ∈ Θ_k (vertex enumeration)", tol.TUBE_TOL),
    Claim("tube_constraints", "(5c), (15a)", _TB, "proposition9", "tube in Z (5c)",
          "(5c), (15a): F x + G(Kx + v_l) <= 1 at every vertex of every X_(l|k), l < N", tol.TUBE_TOL),
    Claim("tube_alpha_nonneg", "(14)", _TB, "proposition9", "α_(l|k) >= 0", "(14): tube scalings are non-negative",
          tol.TUBE_TOL),
    Claim("terminal_set", "Assumption 11", _TB, "proposition9", "(z_N, α_N) ∈ X_f",
          "Assumption 11: the tube ends in the terminal set", tol.TUBE_TOL),
    Claim("multipliers_nonneg", "Proposition 9", _TB, "proposition9", "Λ >= 0",
          "Proposition 9: the multipliers Λ^j_(l|k) are non-negative", tol.TUBE_TOL),
    Claim("multipliers_15c", "(15c)", _TB, "proposition9", "(15c) residual",
          "(15c): Λ^j h_θk + H_x d^j − α_(l+1) 1 <= −w̄ with the recorded Λ", tol.TUBE_TOL),
    Claim("multipliers_15d", "(15d)", _TB, "proposition9", "(15d) residual",
          "(15d): H_x D^j = Λ^j H_θk with the recorded Λ", tol.TUBE_TOL),
    # -- the QP (20) and its cost (certificate.section4, certificate.optimality) ---------------------------------
    Claim("cost_value", "(17)-(18); (19)", _C, "qp20", "cost (17)",
          "(17)-(18): the recorded cost is J_N of the recorded inputs along the nominal prediction with the "
          "recorded θ̂_k", tol.COST_REL_TOL, relative="relative to max(|J|, 1)"),
    Claim("qp_optimality", "(20)", _C, "qp20", "QP (20) optimality",
          "(20): the recorded (z, α, v) of every solved step minimises the QP rebuilt from the record "
          "(x_k, Θ_k, θ̂_k, K, P, X0, X_f, w̄, f̄, the cost (17) or (19), PE bounds): KKT residuals",
          tol.OPTIMALITY_TOL, relative="KKT residuals relative to the stationarity scale s"),
    # -- Section 4.2: persistent excitation (certificate.section4) ----------------------------------------------
    Claim("pe_level", "Section 4.2", _X, "section42", "PE window level",
          "Section 4.2 (PE constraint): at every step where the PE constraint was enforced, the window Gram of the "
          "applied inputs (stacked to pe_dim) has λ_min >= pe_level", tol.PE_LEVEL_TOL,
          relative="relative to max(1, pe_level)"),
    Claim("pe_bounds", "Section 4.2", _X, "section42", "PE input bounds",
          "Section 4.2 (PE, two QPs): the applied input lies within the first-input bounds of the chosen QP",
          tol.PE_BOUND_TOL, relative="relative to max(1, |bound|)"),
)

BY_ID: dict[str, Claim] = {c.id: c for c in CLAIMS}

#: The online answer checks' gates (online.answer_checks) and the claim each guards, with its tolerance:
#: a gate is never looser than its claim (tests/test_claim_table.py).
GATES: dict[str, tuple[str, float]] = {
    "projection_membership": ("theta_hat_in_Theta", tol.PROJECTION_MEMBERSHIP_TOL),
    "projection_kkt": ("lms_update", tol.PROJECTION_KKT_RTOL),
    "set_nested": ("Theta_k_nested", tol.SET_NESTED_TOL),
    "set_outer": ("Theta_k_lower_inclusion", tol.SET_TOL),
    "tube_rows": ("tube_propagation", tol.TUBE_TOL),
}


def claim(claim_id: str) -> Claim:
    """The row of ``claim_id`` (KeyError naming the id and the known ids if absent)."""
    try:
        return BY_ID[claim_id]
    except KeyError:
        raise KeyError(f"no claim {claim_id!r} in the table of claims; known: {sorted(BY_ID)}") from None


def tolerance(claim_id: str) -> float:
    """The tolerance of ``claim_id`` (see :class:`Claim`)."""
    return claim(claim_id).tolerance


def markdown_table() -> str:
    """The table of claims as docs/certificate.md shows it (one line per row, in reading order)."""
    lines = ["| id | paper | statement | tolerance | kind | needs | rests on | excused by |",
             "|---|---|---|---|---|---|---|---|"]
    for c in CLAIMS:
        kind = "strict" if c.strict else (f"relative: {c.relative}" if c.relative else "absolute")
        rests = "" if c.rests_on_consistency is None else f"data_consistency (lag {c.rests_on_consistency})"
        excused = ", ".join(c.excused_by) or "never (data claim)"
        if c.premise:
            excused += f"; is premise {c.premise}"
        statement = c.statement.replace("|", "\\|")
        lines.append(f"| `{c.id}` | {c.paper} | {statement} | {c.tolerance:g} | {kind} | {c.needs or '—'} | "
                     f"{rests or '—'} | {excused} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # python -m amcp_drake.model.claim_table: the table for docs/certificate.md
    print(markdown_table(), end="")
