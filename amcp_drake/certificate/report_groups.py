"""What report.html says around the plots: the claims grouped by the paper's numbered results, the
notation of the text (subscripts as HTML) and the numbers of its note on θ̂_k convergence.

A claim's ``group`` in certificate.json names the code's check family (``theorem14``, ``tube``, ...);
the report groups the claims by the result of Lorenzen, Cannon & Allgöwer (2019) they check instead:
Theorem 14 (i), (ii), (iii), Lemma 3, Lemma 5, Proposition 9, the QP (20) and its cost, Section 4.2,
the Assumptions and the offline design. :func:`paper_result` maps a claim id to its result (by id,
else by its family, else "Other checks", so no claim is ever left out of the report).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
from markupsafe import Markup, escape

from amcp_drake.model.claim_table import CLAIMS
from amcp_drake.model.tolerances import PROJECTION_TOL


@dataclass(frozen=True)
class PaperResult:
    """One numbered result of the paper and the claim ids that check it."""

    key: str
    title: str
    statement: str
    ids: tuple[str, ...] = ()
    families: tuple[str, ...] = ()


def _ids(key: str) -> tuple[str, ...]:
    """The claim ids whose row in the table of claims checks the paper result ``key`` (its ``result``)."""
    return tuple(c.id for c in CLAIMS if c.result == key)


#: The paper's results in the order the report shows them (the main theorem first, premises last); the
#: claims of each are read from the table of claims (:mod:`amcp_drake.model.claim_table`, ``result``).
PAPER_RESULTS = (
    PaperResult("theorem14-i", "Theorem 14 (i): recursive feasibility",
                "𝔻(x_k, Θ_k) ≠ ∅ for all k: the QP (20) has a solution at every step.", _ids("theorem14-i")),
    PaperResult("theorem14-ii", "Theorem 14 (ii): the parameter is never lost",
                "θ* ∈ Θ_k and θ̂_k ∈ Θ for all k.", _ids("theorem14-ii")),
    PaperResult("theorem14-iii", "Theorem 14 (iii): constraint satisfaction",
                "(x_k, u_k) ∈ Z for all k.", _ids("theorem14-iii")),
    PaperResult("lemma3", "Lemma 3: the set estimates",
                "Under the update (9): Θ ⊆ Θ_0 and Θ_k ∩ Δ_{k+1} ⊆ Θ_{k+1} ⊆ Θ_k (10).",
                _ids("lemma3"), ("set_membership",)),
    PaperResult("lemma5", "Lemma 5: the point estimate",
                "θ̂_k by the projected LMS update (12) satisfies (1/μ)‖θ̂_{m+1} − θ*‖² + Σ_{k≤m} ‖x̃_{1|k}‖² ≤ "
                "(1/μ)‖θ̂_0 − θ*‖² + Σ_{k≤m} ‖w_k‖² for every m.", _ids("lemma5"), ("point_estimate",)),
    PaperResult("proposition9", "Proposition 9: the prediction tube",
                "The recorded tube X_{l|k} = z_{l|k} ⊕ α_{l|k} X0 satisfies (5a)–(5c) and ends in the terminal set "
                "X_f; in the plain form (15) of (20) with multipliers Λ ≥ 0 of (15c), (15d) (the vertex form has "
                "none: its Λ claims are not applicable).", _ids("proposition9"), ("tube",)),
    PaperResult("qp20", "The controller: QP (20) and its cost",
                "Every applied input u_k = K x_k + v*_{0|k} (21) comes from a minimiser of (20) with the cost (17) "
                "or (19).", _ids("qp20"), ("cost",)),
    PaperResult("section42", "Section 4.2: persistent excitation",
                "When the run enforces PE, the applied inputs keep the window level and the input bounds.",
                _ids("section42"), ("excitation",)),
    PaperResult("assumptions", "Assumptions: the premises of the run",
                "Assumption 1 (θ* ∈ Θ, w_k ∈ W), the model (1), its consequence on the data Θ_{k−1} ∩ Δ_k ≠ ∅ "
                "(model consistency), the control law (21) and the precondition μ‖D(x_k, u_k)‖² ≤ 1 of Lemma 5 "
                "on the visited points.", _ids("assumptions"), ("assumptions",)),
    PaperResult("design", "Design: the offline ingredients",
                "The terminal cost (16), Assumptions 8 and 11 (X0, X_f), the constants w̄, f̄ of Proposition 9, "
                "μ of (11) and the vertices of X0 in (14).", _ids("design"), ("design",)),
)
OTHER = PaperResult("other", "Other checks", "Checks not tied to one numbered result.")


def paper_result(claim_id: str, family: str | None = None) -> PaperResult:
    """The result a claim checks: by its id, else by its family (``group`` in certificate.json), else OTHER."""
    for result in PAPER_RESULTS:
        if claim_id in result.ids:
            return result
    if claim_id.startswith("design."):
        family = family or "design"
    for result in PAPER_RESULTS:
        if family in result.families:
            return result
    return OTHER


def grouped(claims: list[dict], not_claimed: list[dict]) -> list[dict]:
    """The report's claim sections: one per paper result that has a claim (or a claim not made for this
    run), in PAPER_RESULTS order; each with its claims in certificate order and counts per status."""
    sections: dict[str, dict] = {}
    for result in (*PAPER_RESULTS, OTHER):
        sections[result.key] = {"key": result.key, "title": result.title, "statement": result.statement,
                                "claims": [], "not_claimed": [], "counts": {}}
    for c in claims:
        section = sections[paper_result(c["id"], c.get("group")).key]
        section["claims"].append(c)
        section["counts"][c["status"]] = section["counts"].get(c["status"], 0) + 1
    for c in not_claimed:
        sections[paper_result(c["id"]).key]["not_claimed"].append(c)
    return [s for s in sections.values() if s["claims"] or s["not_claimed"]]


# -- notation ----------------------------------------------------------------------------------------
_BAR = re.compile(r"\b(lambda|[A-Za-z])_bar\b")
_SUB_BRACED = re.compile(r"_\{([^{}]*)\}")
_SUB_PAREN = re.compile(r"_\(([^()]*)\)")
_SUP_BRACED = re.compile(r"\^\{([^{}]*)\}")
_SUP_TOKEN = re.compile(r"\^([A-Za-z0-9*]+)")
#: x_k, X_0|k, max_k,i, A_cl, h_θk, ‖·‖_∞: a subscript of one short token. Snake-case words (``certainty_equivalence``,
#: ``h_theta``) are left alone: a letter token of four or more letters is not a subscript.
_SUB_TOKEN = re.compile(r"(?<=[^\s_(\[,])_([A-Za-z0-9θΘ∞]+(?:\|[A-Za-z0-9]+|,[a-z](?![_A-Za-z]))?)")


def math_html(text: str | None) -> Markup:
    """``text`` HTML-escaped, with the ASCII notation of the claim texts set as HTML: ``w_bar`` → w̄,
    ``X_{l|k}``/``x_(k+1)``/``x_k`` → subscripts, ``d^j``/``h^{k}`` → superscripts."""
    if text is None:
        return Markup("")
    html = str(escape(text))
    html = _BAR.sub(lambda m: ("λ" if m.group(1) == "lambda" else m.group(1)) + "\u0304", html)
    html = _SUB_BRACED.sub(r"<sub>\1</sub>", html)
    html = _SUB_PAREN.sub(r"<sub>\1</sub>", html)
    html = _SUP_BRACED.sub(r"<sup>\1</sup>", html)
    html = _SUP_TOKEN.sub(r"<sup>\1</sup>", html)

    def sub(m: re.Match) -> str:
        token = m.group(1)
        if len(token) >= 4 and token.isalpha() and token.isascii():
            return m.group(0)
        return f"<sub>{token}</sub>"

    return Markup(_SUB_TOKEN.sub(sub, html))


# -- the note on θ̂_k convergence ------------------------------------------------------------------------
def regressor_gram_lambda_min(traj, window: int) -> tuple[float | None, float | None]:
    """λ_min(Σ_k D_kᵀ D_k) over the first and over the last ``window`` applied steps (Definition 21 with
    Φ_k = D_kᵀ, D_k = D(x_k, u_k)); None when the run has fewer steps than ``window``."""
    T = len(traj.u)
    if T < window or window < 1:
        return None, None
    D = [traj.problem.regressor(traj.x[k], traj.u[k]) for k in range(T)]

    def lam(ks) -> float:
        gram = sum(D[k].T @ D[k] for k in ks)
        return float(np.linalg.eigvalsh(gram)[0])

    return lam(range(window)), lam(range(T - window, T))



@dataclass(frozen=True)
class ThetaHatOutside:
    """How often the estimate θ̂_k lay outside the set estimate Θ_k over a run's records."""

    steps: int  #: records checked (those with Θ_k and θ̂_k recorded)
    outside: int  #: records with θ̂_k ∉ Θ_k
    worst: float | None  #: the largest violation max_i([H_θ,k]_i θ̂_k − [h_θ,k]_i), None when nothing was checked


def theta_hat_outside_theta_k(traj, tol: float = PROJECTION_TOL) -> ThetaHatOutside:
    """Count the records whose θ̂_k lies outside Θ_k = {θ | H_θ,k θ ≤ h_θ,k}: allowed by (12) (the projection
    is onto Θ) and removed by Remark 7 (``--projection Theta_k``); the report says how often it happened.
    θ̂_k counts as outside when max_i ([H_θ,k]_i θ̂_k − [h_θ,k]_i) exceeds ``tol`` (the rows of Θ_k as
    recorded; a projection onto Θ_k lands on its boundary up to the projection's tolerance, PROJECTION_TOL)."""
    steps, outside, worst = 0, 0, None
    for r in traj.records:
        if r.H_theta is None or r.h_theta is None or r.theta_hat is None:
            continue
        H, h, th = (np.asarray(v, float) for v in (r.H_theta, r.h_theta, r.theta_hat))
        if H.size == 0 or not np.all(np.isfinite(th)):
            continue
        violation = float(np.max(H @ th - h))
        steps += 1
        outside += violation > tol
        worst = violation if worst is None else max(worst, violation)
    return ThetaHatOutside(steps, outside, worst)
