"""The scaled-copy terminal set: a terminal set of Assumption 11 with as many rows as X0 has facets.

The recursion of Appendix A.1 (docs/explanation/paper.md §5, :func:`~amcp_drake.offline.design.terminal_set`) computes
the maximal positively invariant set of the (z, α) dynamics; its rows multiply by v_p·u per iteration
and its redundancy tests enumerate vertices in n + 1 dimensions, which grows out of reach from n = 4
on (measured: a 4-chain of integrators needed 154,666 candidate rows against 3,033 vertices in one
iteration). This module gives a smaller terminal set whose complexity is that of X0, with a proof
that it satisfies Assumption 11:

    X_f = {(z, α) | H_x z + α·1 <= ᾱ·1, α >= 0},    ᾱ = (1 − SCALED_MARGIN) / max_j f̄_j,

i.e. H_T = H_x / ᾱ and h_T = 1 / ᾱ, with the centre dynamics z⁺ = A_z z = 0 (A_z = 0 is the choice
"zero" of step 2 of the recursion, Appendix A.1). It exists iff α_∞ <= ᾱ, where α_∞ = max_{k,i} w̄_i / (1 − [h̄^k]_i) is the
tube's steady state (the condition "α_∞ f̄ < 1" under which the recursion's X_f holds (0, α_∞)).

**Proof of Assumption 11.** Let (z, α) ∈ X_f. Since X0 is bounded with 0 inside, max_i [H_x]_i z >= 0,
so ᾱ − α >= max_i [H_x]_i z >= 0 and z ∈ (ᾱ − α) X0.

* Constraints: for x = z + α y, y ∈ X0: H_x x = H_x z + α H_x y <= (ᾱ − α)·1 + α·1 = ᾱ·1, so
  x ∈ ᾱ X0 and (F + GK) x <= ᾱ f̄ <= (1 − SCALED_MARGIN)·1 <= 1: (x, Kx) ∈ Z.
* Invariance, with the witness z⁺ = 0 and α⁺ = φ(z, α) = max_{k,i} [H_x]_i A_cl(θ^k) z + [h̄^k]_i α
  + w̄_i (step 2 of Appendix A.1 with A_z = 0; Step 1 shows A_cl(θ)({z} ⊕ αX0) ⊕ W ⊆ α⁺X0 for all θ ∈ Θ).
  α⁺ >= 0 (each term's maximum over i is >= 0 for the same reason as above). From z ∈ (ᾱ − α) X0,
  [H_x]_i A_cl(θ^k) z <= (ᾱ − α)[h̄^k]_i, hence α⁺ <= max_{k,i} ᾱ [h̄^k]_i + w̄_i, which is <= ᾱ
  exactly when ᾱ >= w̄_i / (1 − [h̄^k]_i) for every k, i, i.e. ᾱ >= α_∞ (λ̄ < 1 is required).
  Then H_x z⁺ + α⁺·1 = α⁺·1 <= ᾱ·1 and α⁺ >= 0: (z⁺, α⁺) ∈ X_f.  ∎

The independent check (offline/checks.py) re-verifies both properties at the vertices of X_f with
the recorded A_z = 0, and the non-emptiness condition h_T α_∞ <= 1, with numpy/scipy only.
"""

from __future__ import annotations

import numpy as np

from amcp_drake.model.errors import TerminalSetError

#: ᾱ is taken this fraction below 1 / max f̄, so that the constraint (F + GK)x <= 1 on X_f holds with
#: a margin well above vertex round-off (1e-12) instead of with equality.
SCALED_MARGIN = 1e-6
#: Values of ``design.terminal_set``.
TERMINAL_SET_KINDS = ("auto", "recursion", "scaled")
#: With ``design.terminal_set = "auto"`` the recursion of Appendix A.1 is used up to this dimension n,
#: the scaled copy above it (every example of examples/ with n <= 3 keeps its design).
RECURSION_MAX_N = 3


def terminal_set_kind(options, n: int) -> str:
    """"recursion" or "scaled": ``options.terminal_set``, with "auto" resolved by the dimension
    (:data:`RECURSION_MAX_N`)."""
    kind = getattr(options, "terminal_set", "auto")
    if kind == "auto":
        return "recursion" if n <= RECURSION_MAX_N else "scaled"
    return kind


def steady_alpha(w_bar: np.ndarray, h_bar: np.ndarray) -> float:
    """α_∞ = max_{k,i} w̄_i / (1 − [h̄^k]_i), the least fixed point of α ↦ φ(0, α); inf when λ̄ >= 1."""
    h_bar = np.atleast_2d(np.asarray(h_bar, float))
    if float(np.max(h_bar)) >= 1.0:
        return float("inf")
    return float(np.max(np.asarray(w_bar, float)[None, :] / (1.0 - h_bar)))


def scaled_terminal_set(H_x: np.ndarray, f_bar: np.ndarray, w_bar: np.ndarray,
                        h_bar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(H_T, h_T) of the scaled copy X_f = {H_x z + α 1 <= ᾱ 1, α >= 0} (module docstring); raises
    TerminalSetError naming the condition when α_∞ > ᾱ (no such set holds the tube's steady state)."""
    f_max = float(np.max(f_bar))
    if not f_max > 0.0:
        raise TerminalSetError("scaled terminal set: max f_bar <= 0, the constraints do not bound X0's multiples")
    alpha_bar = (1.0 - SCALED_MARGIN) / f_max
    alpha_inf = steady_alpha(w_bar, h_bar)
    if not alpha_inf <= alpha_bar:
        raise TerminalSetError(
            f"scaled terminal set: the tube's steady state alpha_inf = {alpha_inf:.4g} exceeds alpha_bar = "
            f"1/max f_bar = {alpha_bar:.4g} (Appendix A.1: alpha_inf f_bar < 1 fails); choose a smaller or more "
            "contractive X0, or relax Z")
    H_T = np.asarray(H_x, float) / alpha_bar
    h_T = np.full(len(H_x), 1.0 / alpha_bar)
    return H_T, h_T


__all__ = ["RECURSION_MAX_N", "SCALED_MARGIN", "TERMINAL_SET_KINDS", "scaled_terminal_set", "steady_alpha",
           "terminal_set_kind"]
