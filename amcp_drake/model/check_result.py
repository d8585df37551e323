"""A check result: the unit of every design check and certificate claim.

``status`` is ``"pass"``, ``"fail"``, ``"not_run"`` or ``"not_applicable"``; a check that could not run is
never a pass. ``not_applicable`` is a claim of the paper that needs data the run does not have (θ* and
the disturbances w_k of a measured run): it is neither a pass nor a failure, and the certificate says so.
``margin`` is how far the quantity is from failing (positive = holds, in the check's own units),
``tolerance`` the slack allowed for round-off; a check passes when margin >= -tolerance. A check of one
of the paper's strict inequalities (Assumption 8: spectral radius < 1; (11): 1/μ > sup ‖D‖²) is judged
with ``strict=True`` and tolerance 0: it passes only when margin > 0, so the boundary case fails
(docs/decisions.md, "Strict inequalities of the paper").
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

PASS, FAIL, NOT_RUN, NOT_APPLICABLE = "pass", "fail", "not_run", "not_applicable"


@dataclass(frozen=True)
class CheckResult:
    """Outcome of one check; see module docstring."""

    name: str
    claim: str
    status: str
    margin: float | None
    tolerance: float
    detail: str = ""
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.status == PASS

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        if out["margin"] is not None and out["margin"] != out["margin"]:  # NaN -> None for JSON
            out["margin"] = None
        return out


def judge(name: str, claim: str, margin: float | None, tolerance: float, detail: str = "",
          data: dict[str, Any] | None = None, strict: bool = False) -> CheckResult:
    """Build a CheckResult: pass iff margin is a number and margin >= -tolerance (``strict``:
    margin > -tolerance, for a strict inequality of the paper)."""
    if margin is None or margin != margin:
        return CheckResult(name, claim, NOT_RUN, None, tolerance, detail or "margin could not be computed", data or {})
    status = PASS if (margin > -tolerance if strict else margin >= -tolerance) else FAIL
    return CheckResult(name, claim, status, float(margin), tolerance, detail, data or {})


def not_run(name: str, claim: str, reason: str, tolerance: float = 0.0) -> CheckResult:
    """A check that could not run, with the reason."""
    return CheckResult(name, claim, NOT_RUN, None, tolerance, reason)
