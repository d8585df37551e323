"""The SHA-256 hash of a problem in canonical form: what ties a saved design to the problem it belongs to.

The canonical form is the JSON text of the data the offline design depends on, in a fixed layout:

* the system (2): ``A0``, ``B0``, ``A``, ``B``; W (``H_w``), Θ (``H_theta``, ``h_theta``), Z (``F``,
  ``G``) of Assumption 1, (3), (4); the cost (17): ``Q``, ``R``, ``N``; ``theta_hat0`` of (12);
* ``mu_state_bound`` (the box over which μ of (11) is computed when Z does not bound x; null otherwise),

as the rows the problem holds after loading (redundant rows removed, as every command sees it), every
number as the shortest decimal text that reads back to the same float64 (``repr``; −0.0 written as
0.0), keys sorted, no spaces. The problem's name, the scenario, the online options and the design
options other than ``mu_state_bound`` are not part of it: a design made for one scenario serves every
scenario of the same problem, and is re-verified when it is loaded (``offline/design_file.py``).
Changing any number of the data above by one unit in the last place changes the hash.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

#: The layout of the canonical form (a change of it is a change of every hash).
CANONICAL_FORMAT = "amcp-problem-canonical"
CANONICAL_VERSION = 1
#: The fields of :class:`~amcp_drake.model.problem.Problem` in the canonical form.
HASHED_FIELDS = ("A0", "B0", "A", "B", "H_w", "H_theta", "h_theta", "F", "G", "Q", "R", "N", "theta_hat0")


def _numbers(value) -> object:
    """Nested lists of float64 (−0.0 as 0.0) for an array, an int for ``N``."""
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return int(value)
    return (np.asarray(value, dtype=float) + 0.0).tolist()


def canonical_problem(problem, mu_state_bound: float | None = None) -> str:
    """The canonical JSON text of ``problem`` (module docstring)."""
    data = {name: _numbers(getattr(problem, name)) for name in HASHED_FIELDS}
    data["mu_state_bound"] = None if mu_state_bound is None else float(mu_state_bound) + 0.0
    data["format"], data["version"] = CANONICAL_FORMAT, CANONICAL_VERSION
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)


def problem_hash(problem, mu_state_bound: float | None = None) -> str:
    """The SHA-256 (64 hexadecimal digits) of :func:`canonical_problem`."""
    return hashlib.sha256(canonical_problem(problem, mu_state_bound).encode("utf-8")).hexdigest()


def spec_hash(spec) -> str:
    """:func:`problem_hash` of a :class:`~amcp_drake.model.problem.ProblemSpec` (its ``design.mu_state_bound``)."""
    return problem_hash(spec.problem, spec.design.mu_state_bound)


__all__ = ["CANONICAL_FORMAT", "CANONICAL_VERSION", "HASHED_FIELDS", "canonical_problem", "problem_hash", "spec_hash"]
