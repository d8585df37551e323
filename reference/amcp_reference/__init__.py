"""cvxpy reference backend of amcp-drake (design.md: "Compare two solver backends").

The same optimisation problems as ``amcp_drake.backends.drake_``, formulated independently with
cvxpy so that the two backends cross-check each other:

* :mod:`amcp_reference.backend`: :class:`CvxpyBackend`, the status map and the solve wrapper;
* :mod:`amcp_reference.offline`: the gain LMI (16) and the batched support-function LPs;
* :mod:`amcp_reference.online`: the set-membership LP (9) in per-row primal form and the
  projection QP of (12);
* :mod:`amcp_reference.tube_mpc`: the tube MPC QP (20) as one DPP problem built once.
"""

from .backend import STATUS_MAP, CvxpyBackend

__all__ = ["CvxpyBackend", "STATUS_MAP"]
