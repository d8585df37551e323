"""amcp-drake: verification suite for the adaptive robust MPC of Lorenzen, Cannon & Allgöwer (2019).

Public API (imports are lazy so that ``import amcp_drake`` and ``amcp --help`` stay fast; Drake and
cvxpy are loaded only when a backend is used). A run and its certificate, the same verdict and claims
as ``amcp certify --steps 20`` (tests/test_api_verdict.py; docs/api-snippet.md):

>>> import amcp_drake as amcp
>>> spec = amcp.examples.lorenzen2019_spec()      # or amcp.load_spec("examples/lorenzen2019.json")
>>> offline = amcp.design(spec.problem, spec.design, backend="drake")
>>> ctrl = amcp.AdaptiveMPC(spec.problem, offline, backend="drake")   # or "cvxpy"
>>> traj = amcp.simulate(ctrl, x0=[2, 3], theta_star=[0.8, 0.2, -0.5], steps=20, disturbance="uniform", seed=0)
>>> cert = amcp.certify(traj)
>>> cert.verdict, cert.conformance
('pass', 'pass')
>>> cert.solver_answers["summary"][-1]
'drake answered 21 of 21 tube QPs (20) itself'
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "Problem": "amcp_drake.model.problem",
    "DesignOptions": "amcp_drake.model.problem",
    "Scenario": "amcp_drake.model.problem",
    "ProblemSpec": "amcp_drake.model.problem",
    "load_problem": "amcp_drake.model.problem_io",
    "load_spec": "amcp_drake.model.problem_io",
    "save_spec": "amcp_drake.model.problem_io",
    "design": "amcp_drake.offline.design",
    "OfflineDesign": "amcp_drake.offline.design",
    "verify_design": "amcp_drake.offline.checks",
    "AdaptiveMPC": "amcp_drake.online.controller",
    "OnlineOptions": "amcp_drake.model.options",
    "simulate": "amcp_drake.online.simulate",
    "Trajectory": "amcp_drake.online.simulate",
    "measured_trajectory": "amcp_drake.online.measured",
    "ControllerState": "amcp_drake.online.state",
    "AdaptiveMPCSystem": "amcp_drake.systems.controller_system",
    "drake_plant": "amcp_drake.systems.plant",
    "RecordedDisturbance": "amcp_drake.systems.plant",
    "closed_loop": "amcp_drake.systems.closed_loop",
    "simulate_in_drake": "amcp_drake.systems.closed_loop",
    "certify": "amcp_drake.certificate.certify",
    "available_backends": "amcp_drake.backends",
    "get_backend": "amcp_drake.backends",
    "SolveStatus": "amcp_drake.model.status",
}
#: public submodule names (kept from the flat layout) -> their module in the layered package
_SUBMODULES = {
    "examples": "amcp_drake.model.examples",
    "errors": "amcp_drake.model.errors",
    "polytope": "amcp_drake.model.polytope",
    "checks": "amcp_drake.model.check_result",
    "backends": "amcp_drake.backends",
    "plots": "amcp_drake.certificate.plots",
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name in _SUBMODULES:
        return importlib.import_module(_SUBMODULES[name])
    raise AttributeError(f"module 'amcp_drake' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(_LAZY) + list(_SUBMODULES) + ["__version__"])
