"""Exception hierarchy of amcp-drake.

Every error the package raises on purpose derives from :class:`AmcpError` and
from the closest built-in exception, so callers can catch either. Messages name
the field, what was expected, what was received and, where possible, the fix.

Solver failures are *not* exceptions: they are recorded as a
:class:`~amcp_drake.model.status.SolveStatus` on the step (design.md, Conventions).
"""

from __future__ import annotations


class AmcpError(Exception):
    """Base class of every error raised on purpose by amcp-drake."""


class ProblemError(AmcpError, ValueError):
    """A problem definition violates the paper's assumptions or has malformed data.

    Attributes
    ----------
    field: the dotted name of the offending field (e.g. ``"system.A0"``).
    expected: what was expected, in words.
    received: what was received, in words.
    """

    def __init__(self, field: str, expected: str, received: str, fix: str = "") -> None:
        self.field = field
        self.expected = expected
        self.received = received
        self.fix = fix
        message = f"{field}: expected {expected}; received {received}"
        if fix:
            message += f". {fix}"
        super().__init__(message)


class ProblemFileError(ProblemError):
    """A problem, design or trajectory file cannot be read or has the wrong format."""


class DesignError(AmcpError, RuntimeError):
    """The offline design (K, P, X0, Xf, mu) cannot be completed for this problem."""


class TerminalSetError(DesignError):
    """The terminal set recursion (Appendix A.1) gave an empty set or did not converge."""


class BackendNotFound(AmcpError, ImportError):
    """A backend was requested that is unknown or whose packages are not installed."""


class InconsistentDataError(AmcpError, RuntimeError):
    """Measured data contradict the model: Theta_{k-1} ∩ Delta_k is empty (eqs (6), (7), (9)).

    This means the disturbance left W, theta* is not in Theta, or the model (A_i, B_i)
    is wrong. It is never repaired by inflating W (design.md, Pitfalls).
    """

    def __init__(self, step: int, detail: str) -> None:
        self.step = step
        super().__init__(
            f"step {step}: the measured data contradict the model: Theta_(k-1) ∩ Delta_k is empty "
            f"({detail}). Either the disturbance left W, theta* is not in Theta, or the model "
            "matrices are wrong; amcp never inflates W to hide this."
        )


class TrajectoryError(AmcpError, ValueError):
    """A recorded trajectory is malformed or inconsistent with its problem."""


class CampaignStoreError(ProblemFileError):
    """A campaign store (SQLite) cannot be used: not an SQLite file, corrupted, of another schema, or
    made with other settings than those requested. The store is never written to then."""
