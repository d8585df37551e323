"""The N-version design of the paper's claims, made explicit: claim id -> [certificate method, property re-check].

Every claim the property suite checks is a row of the table of claims (:mod:`amcp_drake.model.claim_table`).
Its *first method* is the certificate's check (:mod:`amcp_drake.certificate`, :mod:`amcp_drake.offline.checks`):
numpy/scipy on the recorded run. Its *second methods* are this suite's independent re-checks
(:mod:`amcp_properties.claims`, :mod:`amcp_properties.section4`), written again from the paper and sharing
no code with the certificate but the model and the tolerances; each is registered under the ids it re-checks
with :func:`second_method` where it is defined. The property tests call :func:`check`, which runs every method
of the ids once: a claim holds on a generated run only when both versions say so.

A first method takes what its second methods take: a trajectory for the claims of a run, ``(problem,
design)`` for the claims of a design.
"""

from __future__ import annotations

from collections.abc import Callable

from amcp_drake.certificate import claims as cert
from amcp_drake.certificate.section4 import cost_value, pe_bounds, pe_level
from amcp_drake.certificate.tube import tube_checks
from amcp_drake.model.check_result import CheckResult
from amcp_drake.model.claim_table import claim as row_of

Method = Callable[..., CheckResult]


def _on_run(check: Callable[[cert.RunView], CheckResult]) -> Method:
    """The certificate's check ``check`` of a RunView, as a method of a trajectory."""
    def first(traj) -> CheckResult:
        return check(cert.RunView(traj))
    first.__qualname__ = first.__name__ = f"certificate:{check.__module__}.{check.__name__}"
    return first


def _tube(claim_id: str) -> Method:
    def first(traj) -> CheckResult:
        return next(c for c in tube_checks(cert.RunView(traj)) if c.data["id"] == claim_id)
    first.__qualname__ = first.__name__ = f"certificate:tube_checks[{claim_id}]"
    return first


def _lemma5(traj) -> CheckResult:
    view = cert.RunView(traj)
    return cert.lemma5(view, cert.lemma5_series(view))


def _mu_precondition(traj) -> CheckResult:
    bound = traj.mu_state_bound if traj.mu_state_bound is not None else traj.design.mu_state_bound
    return cert.mu_precondition(cert.RunView(traj), bound)


def _design(claim_id: str) -> Method:
    """The design check ``claim_id`` of :func:`amcp_drake.offline.checks.verify_design`, a method of (problem, design)."""
    name = row_of(claim_id).name

    def first(problem, design) -> CheckResult:
        from amcp_drake.offline.checks import verify_design

        return next(c for c in verify_design(problem, design) if c.name == name)
    first.__qualname__ = first.__name__ = f"certificate:verify_design[{claim_id}]"
    return first


#: claim id -> the certificate's check (the first method).
FIRST_METHODS: dict[str, Method] = {
    "recursive_feasibility": _on_run(cert.recursive_feasibility),
    "theta_star_in_Theta_k": _on_run(cert.theta_star_in_theta_k),
    "theta_hat_in_Theta": _on_run(cert.theta_hat_in_theta),
    "state_input_constraints": _on_run(cert.state_input_constraints),
    "Theta0_contains_Theta": _on_run(cert.prior_contains_theta),
    "Theta_k_nested": _on_run(cert.nested_sets),
    "Theta_k_lower_inclusion": _on_run(cert.lower_inclusion),
    "mu_precondition": _mu_precondition,
    "lemma5": _lemma5,
    **{cid: _tube(cid) for cid in ("tube_contains_state", "tube_contains_next_state", "tube_propagation",
                                   "tube_constraints")},
    **{cid: _design(cid) for cid in ("design.x_f_non_empty", "design.x_f_invariant", "design.x_f_in_z")},
    "cost_value": _on_run(cost_value),
    "pe_level": _on_run(pe_level),
    "pe_bounds": _on_run(pe_bounds),
}
#: claim id -> this suite's independent re-checks (the second methods), filled by :func:`second_method`.
SECOND_METHODS: dict[str, list[Method]] = {}


def second_method(*claim_ids: str) -> Callable[[Method], Method]:
    """Register the decorated re-check as a second method of each of ``claim_ids`` (ids of the table of claims)."""
    for claim_id in claim_ids:
        row_of(claim_id)  # KeyError naming an id that is not in the table of claims

    def register(fn: Method) -> Method:
        for claim_id in claim_ids:
            SECOND_METHODS.setdefault(claim_id, []).append(fn)
        return fn
    return register


def _load() -> None:
    """Import the modules whose re-checks register themselves."""
    from . import claims, section4  # noqa: F401


def methods(claim_id: str) -> list[Method]:
    """[the certificate's method, *the property re-checks] of ``claim_id`` (KeyError when it has no first method)."""
    _load()
    return [FIRST_METHODS[claim_id], *SECOND_METHODS.get(claim_id, [])]


def check(claim_ids: str | tuple[str, ...], *subject) -> list[CheckResult]:
    """Every method of ``claim_ids`` applied once to ``subject`` (a trajectory, or problem and design), the
    certificate's first; a re-check registered under several of the ids runs once."""
    ids = (claim_ids,) if isinstance(claim_ids, str) else claim_ids
    seen: list[Method] = []
    for claim_id in ids:
        seen += [m for m in methods(claim_id) if m not in seen]
    return [m(*subject) for m in seen]
