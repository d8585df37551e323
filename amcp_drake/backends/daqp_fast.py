"""Fast path of the vertex form (off by default): the QP (20) solved densely by DAQP, a
dual active-set solver warm-started from the previous step's active set, every answer checked.

``DrakeBackend(formulation="vertex", qp_solver="daqp")``. The QP is the one of
:mod:`.drake_vertex` (same rows, same cost), in the variables w = [α (N+1) | z (N+1)·n | v N·m]
(α first: DAQP takes simple bounds on the leading variables, here α >= 0):

    minimise ½ wᵀ P w + qᵀ w   s.t.   α >= 0,   A w <= b,

with P = 2H on v (the condensed cost (17)-(18), :mod:`.condensed_cost`) and zero on (z, α). DAQP
needs a positive definite P, so P gets :data:`REGULARISATION` on the diagonal of (z, α) (with
1e-10 DAQP reported false infeasibility at N = 5, 4 facets, p = 4). The answer is then
**verified against the original problem** (no regularisation, the original rows, plain numpy):

* DAQP's exit flag says optimal;
* primal feasibility: A w <= b + :data:`PRIMAL_TOL`·max(1, |b|), α >= −PRIMAL_TOL;
* dual feasibility: multipliers of upper bounds >= −:data:`DUAL_TOL`, of the lower bounds α >= 0
  <= DUAL_TOL (DAQP signs them negative);
* one proximal step removes the regularisation's bias (w of the regularised problem is shifted
  back; the fixed point is the unregularised optimum);
* stationarity of the unregularised Lagrangian: ‖P₀ w + q + Aᵀλ‖∞ <= :data:`STATIONARITY_TOL`·scale;
* complementarity: |λ_i|·slack_i <= :data:`COMPLEMENTARITY_TOL`·scale for every row.

Any failed check, exception or non-optimal flag returns None with the reason, and the caller
solves the same step with Clarabel (the fallback is counted and named in ``MPCSolution.detail``).
Together the checks say that w is a KKT point of the original convex QP to the stated tolerances,
hence optimal to that accuracy, whatever DAQP did internally.
"""

from __future__ import annotations

import time

import numpy as np

#: Diagonal regularisation of (z, α) in DAQP's Hessian (they have no cost of their own). Measured on
#: Example 1: 1e-8 solves every step; 1e-10 gave false "infeasible" at N = 5, 4 facets,
#: p = 4. Its effect on the optimum is removed from the checks (they use the unregularised cost).
REGULARISATION = 1e-8
#: Row violation accepted (relative to max(1, |b|)): Clarabel's own feasibility tolerance is 1e-8.
PRIMAL_TOL = 1e-8
#: A multiplier of the wrong sign up to this is round-off.
DUAL_TOL = 1e-8
#: Stationarity ‖P₀ w + q + Aᵀλ‖∞ relative to max(1, ‖q‖∞, ‖P₀ w‖∞). Tight because v is sensitive:
#: on Example 1 at x = [2, 3] a residual of 3.6e-8 (the regularisation's, before the proximal step)
#: moved v by 4e-7; the issue asks for v within 1e-6 of Clarabel's.
STATIONARITY_TOL = 1e-9
#: |λ_i|·slack_i relative to max(1, ‖q‖∞).
COMPLEMENTARITY_TOL = 1e-7
#: DAQP's own primal tolerance below the check's PRIMAL_TOL (its default, 1e-6, let a step end
#: 7.5e-7 outside a row on Example 1, step 253, which the check then sent to Clarabel).
DAQP_SETTINGS = {"primal_tol": 1e-9}
#: DAQP's exit flag for an optimal solution.
DAQP_OPTIMAL = 1


class DaqpVertexQP:
    """The dense vertex-form QP for one vertex count S of Θ_k, with its DAQP workspace.

    ``order``: indices of y = [z | α | v] (the Drake program's order) in w's order [α | z | v].
    ``fixed_A`` (r, size), ``fixed_b`` (r,): rows that never change ((15a), terminal set);
    ``A15b`` (u, size): the rows of (15b), whose right-hand side −H_x x_k changes every step.
    """

    def __init__(self, order: np.ndarray, n_alpha: int, v_slice: slice, fixed_A: np.ndarray,
                 fixed_b: np.ndarray, A15b: np.ndarray, tube_rows: int) -> None:
        import daqp

        self.order = order
        self.n_alpha = n_alpha
        size = len(order)
        self.v = np.arange(size)[v_slice]                  # positions of v in w (v is last in both)
        u = A15b.shape[0]
        self.A = np.zeros((u + len(fixed_b) + tube_rows, size))
        self.A[:u] = A15b[:, order]
        self.A[u:u + len(fixed_b)] = fixed_A[:, order]
        self.b = np.zeros(len(self.A))
        self.b[u:u + len(fixed_b)] = fixed_b
        self._u, self._tube0 = u, u + len(fixed_b)
        self.P = np.zeros((size, size))
        self._v0 = size - len(self.v)                      # v is the trailing block of w
        self.P[np.arange(self._v0), np.arange(self._v0)] = REGULARISATION
        self._Pvv = self.P[self._v0:, self._v0:]
        self.q = np.zeros(size)
        self._q_prox = np.zeros(size)
        self._zalpha = np.arange(size - len(self.v))        # positions of (α, z) in w
        self.lower = np.concatenate([np.zeros(n_alpha), np.full(len(self.A), -np.inf)])
        self.upper = np.concatenate([np.full(n_alpha, np.inf), self.b])
        self._model = daqp.Model()
        self._model.settings = DAQP_SETTINGS
        self._ready = False
        self.version = -1  # the caller's version of the tube rows written here (-1: none yet)

    def write_tube(self, A_tube: np.ndarray, b_tube: np.ndarray) -> None:
        """The N·S·u tube rows (in y's column order) and their bound; the DAQP workspace is set up
        again with them (warm start kept where DAQP allows)."""
        self.A[self._tube0:] = A_tube[:, self.order]
        self.b[self._tube0:] = b_tube
        self.upper[self.n_alpha + self._tube0:] = b_tube
        self._ready = False

    def solve(self, b15b: np.ndarray, H: np.ndarray, g: np.ndarray) -> tuple[np.ndarray | None, str, float]:
        """(y in the Drake program's order, or None; detail; DAQP time in s) for the right-hand side
        of (15b) and the condensed cost vᵀ H v + 2 gᵀ v."""
        start = time.perf_counter()
        self.b[: self._u] = b15b
        self.upper[self.n_alpha: self.n_alpha + self._u] = b15b
        self._Pvv[:] = 2.0 * H            # the v block of P (a view); (z, α) keep the regularisation
        self.q[self._v0:] = 2.0 * g
        try:
            if not self._ready:
                flag, _ = self._model.setup(self.P, self.q, self.A, self.upper, self.lower)
                if flag < 0:
                    return None, f"DAQP setup failed (exit flag {flag})", time.perf_counter() - start
                self._ready = True
            else:
                flag = self._model.update(H=self.P, f=self.q, bupper=self.upper)
                if flag < 0:
                    return None, f"DAQP update failed (exit flag {flag})", time.perf_counter() - start
            w, _, exitflag, info = self._model.solve()
            iterations = int(info["iterations"])
            if exitflag == DAQP_OPTIMAL:
                # one proximal step: min ½wᵀ(P + εI_{z,α})w + (q − ε w⁰_{z,α})ᵀw has the fixed point of the
                # unregularised problem; one step from the regularised optimum w⁰ removes the bias
                # (Example 1, x = [2, 3]: |v − v_Clarabel| 4e-7 -> 6e-12); warm-started, few iterations
                self._q_prox[:] = self.q
                self._q_prox[self._zalpha] -= REGULARISATION * np.asarray(w, float)[self._zalpha]
                self._model.update(f=self._q_prox)
                w, _, exitflag, info = self._model.solve()
                iterations += int(info["iterations"])
                self._model.update(f=self.q)
        except Exception as exc:  # noqa: BLE001 - any DAQP failure is a fallback, never a crash
            self._ready = False
            return None, f"DAQP raised {type(exc).__name__}: {exc}", time.perf_counter() - start
        elapsed = time.perf_counter() - start
        if exitflag != DAQP_OPTIMAL:
            self._ready = False  # start the next step cold
            return None, f"DAQP exit flag {exitflag}", elapsed
        w = np.asarray(w, float)
        self.last_w, self.last_lam = w, np.asarray(info["lam"], float)  # kept for diagnostics and tests
        reason = self.check(w, self.last_lam)
        if reason:
            self._ready = False
            return None, reason, elapsed
        y = np.empty_like(w)
        y[self.order] = w
        return y, f"DAQP, {iterations} iterations", elapsed

    def check(self, w: np.ndarray, lam: np.ndarray) -> str:
        """'' when w is a KKT point of the unregularised QP to the tolerances, else the reason."""
        if not (np.all(np.isfinite(w)) and np.all(np.isfinite(lam))):
            # DAQP 0.11 can report "optimal" with NaN: measured on Example 1, 4-facet X0, step 0, in the
            # proximal step after update(f=...) (the same QP solved afresh is finite); every comparison
            # below is False for NaN, so without this line such an answer would pass every check
            return "non-finite answer (NaN or inf in w or the multipliers)"
        na = self.n_alpha
        slack = self.b - self.A @ w
        if np.any(slack < -PRIMAL_TOL * np.maximum(1.0, np.abs(self.b))) or np.any(w[:na] < -PRIMAL_TOL):
            return f"primal infeasible by {max(-slack.min(), -w[:na].min()):.1e}"
        lam_bounds, lam_rows = lam[:na], lam[na:]
        if np.any(lam_rows < -DUAL_TOL) or np.any(lam_bounds > DUAL_TOL):
            return "multiplier of the wrong sign"
        P0w = np.zeros_like(w)
        P0w[self._v0:] = self._Pvv @ w[self._v0:]   # the cost without regularisation
        grad = P0w + self.q
        residual = grad + self.A.T @ lam_rows
        residual[:na] += lam_bounds
        scale = max(1.0, float(np.max(np.abs(self.q))), float(np.max(np.abs(P0w))))
        if np.max(np.abs(residual)) > STATIONARITY_TOL * scale:
            return f"stationarity residual {np.max(np.abs(residual)):.1e}"
        gap = max(float(np.max(np.abs(lam_rows * slack), initial=0.0)), float(np.max(np.abs(lam_bounds * w[:na]))))
        if gap > COMPLEMENTARITY_TOL * scale:
            return f"complementarity {gap:.1e}"
        return ""


#: Steps of the measured switch: on the first CALIBRATION_STEPS steps that DAQP answers, the same
#: step is also solved (and timed) by Clarabel; the fast path stays on only if DAQP's median thread
#: CPU time is at most Clarabel's. Measured on Example 1 (scaling table, benchmarks/README.md): DAQP
#: 2.6× faster at N = 10, 1.2× at N = 20, 2.1× slower at N = 40; a size rule alone would depend on the
#: number of active constraints, which only the solve itself shows.
CALIBRATION_STEPS = 3
#: The dense workspace of one DAQP model holds (rows × variables) float64 entries: above this many
#: (32 MB) the model is not built and the fast path is switched off (every step by Clarabel).
MAX_DENSE_ENTRIES = 4_000_000


class DaqpFastPath:
    """The DAQP models of one tube QP, one per vertex count S (made on first use), the count of steps
    answered by DAQP and of fallbacks to Clarabel, and the measured switch: ``active`` turns False
    (for the rest of the run, with ``off_reason``) when DAQP was slower than Clarabel on the first
    :data:`CALIBRATION_STEPS` steps, or when a dense model would exceed :data:`MAX_DENSE_ENTRIES`."""

    def __init__(self, order: np.ndarray, n_alpha: int, v_slice: slice, fixed_A: np.ndarray,
                 fixed_b: np.ndarray, A15b: np.ndarray, rows_per_vertex: int) -> None:
        self._args = (order, n_alpha, v_slice, fixed_A, fixed_b, A15b)
        self._rows_per_vertex = rows_per_vertex
        self._fixed_rows = A15b.shape[0] + len(fixed_b)
        self._size = len(order)
        self.models: dict[int, DaqpVertexQP] = {}
        self.counts = {"daqp": 0, "fallback": 0}
        self.last_fallback = ""  # the reason of the last fallback (also in MPCSolution.detail)
        self.active = True
        self.off_reason = ""
        #: (DAQP CPU s, Clarabel CPU s) of the calibration steps
        self.calibration: list[tuple[float, float]] = []

    @property
    def calibrating(self) -> bool:
        """True while the measured switch still times Clarabel beside DAQP."""
        return self.active and len(self.calibration) < CALIBRATION_STEPS

    def calibrate(self, daqp_cpu: float, clarabel_cpu: float) -> None:
        """Record one calibration step; after the last one, switch off when DAQP's median is larger."""
        self.calibration.append((float(daqp_cpu), float(clarabel_cpu)))
        if len(self.calibration) == CALIBRATION_STEPS:
            fast, slow = (float(np.median([c[i] for c in self.calibration])) for i in (0, 1))
            if fast > slow:
                self.switch_off(f"DAQP {1e3 * fast:.2f} ms > Clarabel {1e3 * slow:.2f} ms CPU per step "
                                f"(median of {CALIBRATION_STEPS} steps)")

    def switch_off(self, reason: str) -> None:
        self.active, self.off_reason = False, reason

    def dense_entries(self, S: int) -> int:
        """Entries of the dense constraint matrix of the model for S vertices."""
        return (self._fixed_rows + S * self._rows_per_vertex) * self._size

    def model(self, S: int) -> DaqpVertexQP | None:
        """The model for S vertices (made on first use); None (and the fast path off) when it would
        exceed :data:`MAX_DENSE_ENTRIES`."""
        if S not in self.models:
            entries = self.dense_entries(S)
            if entries > MAX_DENSE_ENTRIES:
                self.switch_off(f"dense QP of {entries} entries > {MAX_DENSE_ENTRIES} (S = {S} vertices)")
                return None
            self.models[S] = DaqpVertexQP(*self._args, tube_rows=S * self._rows_per_vertex)
        return self.models[S]

    def solve(self, model: DaqpVertexQP, b15b: np.ndarray, H: np.ndarray, g: np.ndarray):
        """``model.solve`` (see :meth:`DaqpVertexQP.solve`), counted."""
        y, detail, elapsed = model.solve(b15b, H, g)
        self.counts["daqp" if y is not None else "fallback"] += 1
        if y is None:
            self.last_fallback = detail
        return y, detail, elapsed


__all__ = ["CALIBRATION_STEPS", "MAX_DENSE_ENTRIES", "REGULARISATION", "DaqpFastPath", "DaqpVertexQP"]
