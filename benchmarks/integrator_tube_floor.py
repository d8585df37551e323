"""How much of Z the smallest tube of a linear gain needs on the integrator chains (amcp_drake/studies/chains.py).

For the nominal system (θ = θ̂0, no parameter uncertainty, which only enlarges the tube) and a gain K,
the minimal robust invariant set of x⁺ = (A0 + B0 K) x + w, w ∈ W, has support
f_i = Σ_k h_W((F + G K)_i A_cl^k) in the direction of row i of Z (h_W(c) = 0.01 ‖c‖₁ for the chains'
W); every tube of the scheme (X0 scaled by α under the fixed K) contains it at its steady state, so
max_i f_i > 1 means that no tube with this K fits in Z. The script reports the smallest max_i f_i found
over a grid of real closed-loop poles (scipy's place_poles) refined by a Nelder–Mead search over K: an
upper bound of the least value over all gains (a search, not a proof), and a lower bound of what any
design of the chain with a linear tube needs.

    python benchmarks/integrator_tube_floor.py --n 3 4 5 6 7 8
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.optimize import minimize
from scipy.signal import place_poles

from amcp_drake.model.problem_io import spec_from_dict
from amcp_drake.studies.chains import integrator_chain

#: Terms of the series Σ_k h_W((F+GK)_i A_cl^k) (stopped earlier once A_cl^k is below 1e-12).
HORIZON = 3000
#: Half-width of the chains' W (integrator_chain: ‖w‖∞ <= 0.01).
W_HALF_WIDTH = 0.01


def tube_floor(A0: np.ndarray, B0: np.ndarray, F: np.ndarray, G: np.ndarray, K: np.ndarray) -> float:
    """max_i Σ_k h_W((F + G K)_i A_cl^k) (module docstring); inf when A_cl is not Schur stable."""
    A_cl = A0 + B0 @ K
    if np.max(np.abs(np.linalg.eigvals(A_cl))) >= 0.9999:
        return float("inf")
    rows = F + G @ K
    total = np.zeros(len(rows))
    for _ in range(HORIZON):
        total += W_HALF_WIDTH * np.abs(rows).sum(axis=1)
        rows = rows @ A_cl
        if np.abs(rows).max() < 1e-12:
            break
    return float(total.max())


def smallest_found(n: int) -> tuple[float, float]:
    """(grid minimum, after the local search) of :func:`tube_floor` for the integrator chain of n states."""
    pr = spec_from_dict(integrator_chain(n)).problem
    A0, B0 = pr.A_of(pr.theta_hat0), pr.B_of(pr.theta_hat0)
    best, best_K = float("inf"), None
    for last in np.linspace(0.3, 0.99, 70):
        for spread in (0.0, 0.05, 0.1, 0.2):
            poles = np.clip(np.linspace(last - spread, last, n), 0.01, 0.999) + 1e-3 * np.arange(n) * (spread == 0.0)
            try:
                K = -np.asarray(place_poles(A0, B0, poles).gain_matrix, float)
            except (ValueError, np.linalg.LinAlgError):
                continue
            value = tube_floor(A0, B0, pr.F, pr.G, K)
            if value < best:
                best, best_K = value, K
    local = minimize(lambda k: tube_floor(A0, B0, pr.F, pr.G, k.reshape(1, -1)), best_K.ravel(), method="Nelder-Mead",
                     options={"maxiter": 4000, "xatol": 1e-8, "fatol": 1e-10})
    return best, min(best, float(local.fun))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, nargs="+", default=[3, 4, 5, 6, 7, 8], help="state dimensions")
    args = parser.parse_args(argv)
    print("| n | smallest max_i f_i found: pole grid | after the local search |")
    print("|---|---|---|")
    for n in args.n:
        grid, local = smallest_found(n)
        print(f"| {n} | {grid:.3f} | {local:.3f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
