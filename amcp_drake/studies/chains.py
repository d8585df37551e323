"""Chain systems of any dimension n, as problem files (dicts of the ``amcp-problem`` format): the
scaling benchmark (``amcp bench --only size``) and the tests of the design at n = 4 … 8 use them.

* :func:`actuated_chain`: x_i⁺ = x_i + 0.2 x_(i+1) + 0.5 u_i (an input on every state), Θ a box on
  two entries (A[0, 1] and B[n-1, n-1]), W a box of half-width ``w``;
* :func:`integrator_chain`: the same chain with one input on the last state (uncertain gain), the
  chain of integrators of the size study of docs/decisions.md.

Neither file has a ``design`` section unless one is given: the defaults apply at every n.
"""

from __future__ import annotations

import numpy as np

#: The chain families by name (``amcp bench --only size --chains``).
CHAIN_KINDS = ("actuated", "integrator")


def actuated_chain(n: int, w: float = 0.005, eps: float = 0.1, design_section: dict | None = None) -> dict:
    """A problem file (dict) without a design section unless given: a chain x_i⁺ = x_i + 0.2 x_(i+1)
    with an input on every state, box W of half-width w, a box Θ = [-eps, eps]² on two entries
    (A[0,1], B[n-1,n-1]); Z: |x_i| <= 5, |u_i| <= 1; Q = I, R = I, N = 5."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n: expected an integer >= 2; received {n!r}")
    A0 = np.eye(n) + 0.2 * np.eye(n, k=1)
    A1 = np.zeros((n, n))
    A1[0, 1] = 0.2
    B2 = np.zeros((n, n))
    B2[-1, -1] = 0.5
    eye = np.eye(n)
    data = {"format": "amcp-problem", "version": 1, "name": f"actuated_chain{n}",
            "system": {"A0": A0.tolist(), "B0": (0.5 * eye).tolist(), "A": [A1.tolist(), np.zeros((n, n)).tolist()],
                       "B": [np.zeros((n, n)).tolist(), B2.tolist()]},
            "W": {"H": np.vstack([eye / w, -eye / w]).tolist()},
            "Theta": {"H": [[1, 0], [-1, 0], [0, 1], [0, -1]], "h": [eps] * 4},
            "Z": {"F": np.vstack([eye / 5, -eye / 5, np.zeros((2 * n, n))]).tolist(),
                  "G": np.vstack([np.zeros((2 * n, n)), eye, -eye]).tolist()},
            "cost": {"Q": eye.tolist(), "R": eye.tolist(), "N": 5},
            "theta_hat0": [0.0, 0.0],
            "scenario": {"x0": [0.5] + [0.0] * (n - 1), "theta_star": [0.05, -0.05], "steps": 4,
                         "disturbance": "uniform", "seed": 0}}
    if design_section is not None:
        data["design"] = design_section
    return data


def integrator_chain(n: int, w: float = 0.01) -> dict:
    """A chain of n integrators with one input (B uncertain), box Θ on two entries, ‖w‖∞ <= w (0.01)."""
    data = actuated_chain(n, w=w)
    data["name"] = f"integrator_chain{n}"
    B0 = np.zeros((n, 1))
    B0[-1, 0] = 0.2
    data["system"]["B0"] = B0.tolist()
    data["system"]["B"] = [np.zeros((n, 1)).tolist(), B0.tolist()]
    eye = np.eye(n)
    data["Z"] = {"F": np.vstack([eye / 5, -eye / 5, np.zeros((2, n))]).tolist(),
                 "G": np.vstack([np.zeros((2 * n, 1)), [[1.0]], [[-1.0]]]).tolist()}
    data["cost"]["R"] = [[1.0]]
    return data


def chain(kind: str, n: int) -> dict:
    """The chain of ``kind`` (:data:`CHAIN_KINDS`) with n states."""
    if kind not in CHAIN_KINDS:
        raise ValueError(f"kind: expected one of {', '.join(CHAIN_KINDS)}; received {kind!r}")
    return actuated_chain(n) if kind == "actuated" else integrator_chain(n)


__all__ = ["CHAIN_KINDS", "actuated_chain", "chain", "integrator_chain"]
