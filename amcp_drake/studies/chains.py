"""Chain systems of any dimension n, as problem files (dicts of the ``amcp-problem`` format): the
scaling benchmark (``amcp bench --only size``) and the tests of the design at n = 4 … 8 use them.

* :func:`actuated_chain`: x_i⁺ = x_i + 0.2 x_(i+1) + 0.5 u_i (an input on every state), Θ a box on
  two entries (A[0, 1] and B[n-1, n-1]), W a box of half-width ``w``;
* :func:`integrator_chain`: the same chain with one input on the last state (uncertain gain), the
  chain of integrators of the size study of docs/decisions.md;
* :func:`mass_chain`: the chain of unit masses and springs of the built-in ``mass_chain3`` and
  ``mass_chain4`` (docs/decisions.md, "Literature examples") with any number of masses: n = 2·masses,
  m = masses, p = masses − 1 (the springs between masses).

Neither file has a ``design`` section unless one is given: the defaults apply at every n.
"""

from __future__ import annotations

import numpy as np

#: The chain families by name (``amcp bench --only size --chains``).
CHAIN_KINDS = ("actuated", "integrator")
#: Step of the forward-Euler discretisation of the mass chain (seconds).
MASS_CHAIN_STEP = 0.1


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


def mass_chain(masses: int, steps: int = 50, horizon: int | None = None, x0_amplitude: float | None = None) -> dict:
    """The mass-spring chain of ``mass_chain3``/``mass_chain4`` with ``masses`` unit masses (>= 2), no design
    section: state [p1, v1, p2, v2, ...], x⁺ = x + h ẋ (h = :data:`MASS_CHAIN_STEP`), the first mass tied
    to the wall by a known spring of 1 N/m, θ = the constants of the masses − 1 springs between masses in
    [0.5, 1.5] N/m, a force on every mass; |p_i| <= 1, |v_i| <= 1, |u_i| <= 3, W = {|w_p| <= 1e-4,
    |w_v| <= 1e-3}; Q = I, R = I, N = 10 for 3 masses and 6 otherwise (``horizon`` overrides);
    θ̂0 = 1, θ* = [0.7, 1.3, 1.0, 0.7, 1.3, 1.0, ...], x0 = [a, 0, ..., -a, 0] with a = ``x0_amplitude``
    (default 0.2 up to 4 masses; 0.1 above, where [0.2, 0, …, −0.2, 0] lies outside the feasible region of the
    5-mass chain's first QP by a slack of 9.7e-5); ``steps`` closed-loop steps
    with uniform disturbances, seed 0. ``mass_chain(3)`` and ``mass_chain(4)`` are the built-in files'
    data (tested)."""
    if isinstance(masses, bool) or not isinstance(masses, (int, np.integer)) or masses < 2:
        raise ValueError(f"masses: expected an integer >= 2; received {masses!r}")
    masses = int(masses)
    n, p, h = 2 * masses, masses - 1, MASS_CHAIN_STEP
    A0 = np.eye(n)
    for i in range(masses):
        A0[2 * i, 2 * i + 1] = h
    A0[1, 0] -= h  # the wall spring, known
    A_list = []
    for j in range(1, masses):  # spring j between masses j-1 and j (0-based), constant θ_j
        a, b = 2 * (j - 1), 2 * j
        Aj = np.zeros((n, n))
        Aj[a + 1, b], Aj[a + 1, a], Aj[b + 1, a], Aj[b + 1, b] = h, -h, h, -h
        A_list.append(Aj)
    B0 = np.zeros((n, masses))
    for i in range(masses):
        B0[2 * i + 1, i] = h
    eye_n, eye_m, eye_p = np.eye(n), np.eye(masses), np.eye(p)
    w_half = np.array([1e-4, 1e-3] * masses)
    theta_star = [(0.7, 1.3, 1.0)[j % 3] for j in range(p)]
    x0 = [0.0] * n
    amplitude = float(x0_amplitude) if x0_amplitude is not None else (0.2 if masses <= 4 else 0.1)
    x0[0], x0[n - 2] = amplitude, -amplitude
    return {"format": "amcp-problem", "version": 1, "name": f"mass_chain{masses}",
            "system": {"A0": A0.tolist(), "B0": B0.tolist(), "A": [Aj.tolist() for Aj in A_list],
                       "B": [np.zeros((n, masses)).tolist() for _ in range(p)]},
            "W": {"H": np.vstack([np.diag(1 / w_half), -np.diag(1 / w_half)]).tolist()},
            "Theta": {"H": np.vstack([eye_p, -eye_p]).tolist(), "h": [1.5] * p + [-0.5] * p},
            "Z": {"F": np.vstack([eye_n, -eye_n, np.zeros((2 * masses, n))]).tolist(),
                  "G": np.vstack([np.zeros((2 * n, masses)), eye_m / 3, -eye_m / 3]).tolist()},
            "cost": {"Q": eye_n.tolist(), "R": eye_m.tolist(),
                     "N": int(horizon if horizon is not None else (10 if masses == 3 else 6))},
            "theta_hat0": [1.0] * p,
            "scenario": {"x0": x0, "theta_star": theta_star, "steps": int(steps), "disturbance": "uniform", "seed": 0}}


def chain(kind: str, n: int) -> dict:
    """The chain of ``kind`` (:data:`CHAIN_KINDS`) with n states."""
    if kind not in CHAIN_KINDS:
        raise ValueError(f"kind: expected one of {', '.join(CHAIN_KINDS)}; received {kind!r}")
    return actuated_chain(n) if kind == "actuated" else integrator_chain(n)


__all__ = ["CHAIN_KINDS", "MASS_CHAIN_STEP", "actuated_chain", "chain", "integrator_chain", "mass_chain"]
