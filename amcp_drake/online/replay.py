"""Run the scenario of a problem file: offline design, then the closed loop.

One function, :func:`run_scenario`, used both by ``amcp certify PROBLEM`` and by the campaign
(:mod:`amcp_drake.studies.campaign`), so that a campaign run and the replay of its saved problem file take
exactly the same path: the same design call (on ``design_backend``), the same controller, the same
arguments to :func:`~amcp_drake.online.simulate.simulate`. Given the same problem file, backend, design
backend and formulation, the two runs are the same computation and their certificates agree bit
for bit (see docs/decisions.md, "Campaign replays").
"""

from __future__ import annotations

from amcp_drake.model.problem import ProblemSpec


def run_scenario(spec: ProblemSpec, backend: str = "drake", *, design_backend: str | None = None,
                 formulation: str = "plain", steps: int | None = None, seed: int | None = None, options=None,
                 offline=None, progress: bool = False, design_budget=None, simulate=None,
                 backend_options: dict | None = None):
    """The closed loop of ``spec.scenario`` on ``backend``; returns the Trajectory (a partial one when
    Θ_{k-1} ∩ Δ_k = ∅ stops the run, with ``stop_reason`` saying so).

    ``design_backend``: the backend of the offline design (default: ``backend``); ``offline``: an
    OfflineDesign to use instead of designing; ``steps``/``seed``: override the scenario's;
    ``options``: the OnlineOptions (default: the file's ``online`` section, else the defaults);
    ``design_budget``: the :class:`~amcp_drake.offline.budget.DesignBudget` of the design (memory limit,
    time budget per candidate, progress lines; None: the default limit, silent); with a budget, the run's
    size is estimated again for the design found and refused above its memory limit
    (:func:`~amcp_drake.online.run_size.check_run_size` with the design, in the form it will use).
    ``simulate``: the closed-loop function (default :func:`~amcp_drake.online.simulate.simulate`;
    ``amcp_drake.systems.closed_loop.simulate_in_drake`` runs the plant in Drake), called with the same
    arguments. ``backend_options``: keyword options of the backend's constructor (e.g.
    ``{"solver_options": {...}}``, the solver's settings for every problem of the run), passed to the
    controller; ``formulation`` is given on its own.
    """
    from amcp_drake.model.errors import InconsistentDataError, ProblemError
    from amcp_drake.offline.design import design
    from amcp_drake.online.controller import AdaptiveMPC
    from amcp_drake.online.run_size import check_run_size

    if simulate is None:
        from amcp_drake.online.simulate import simulate

    sc = spec.scenario
    if sc is None:
        raise ProblemError("scenario", "a scenario (x0, theta_star, ...) in the problem file to run", "none",
                           "Add a \"scenario\" object, or pass --trajectory.")
    steps = sc.steps if steps is None else steps
    seed = sc.seed if seed is None else seed
    if options is None:
        options = spec.online
    if offline is None:
        offline = design(spec.problem, spec.design, backend=design_backend or backend, budget=design_budget)
        if design_budget is not None:  # the run's size with the design found, before the controller is built
            check_run_size(spec.problem, spec.design, steps, options, design_budget.max_memory_mb, design=offline,
                           formulation=formulation)
    backend_options = dict(backend_options or {})
    if "formulation" in backend_options:
        raise ProblemError("backend_options", "backend options without 'formulation' (it is its own argument)",
                           repr(backend_options["formulation"]))
    ctrl = AdaptiveMPC(spec.problem, offline, backend=backend, options=options, formulation=formulation,
                       max_memory_mb=None if design_budget is None else design_budget.max_memory_mb, **backend_options)
    try:
        return simulate(ctrl, sc.x0, sc.theta_star_for(steps), steps, sc.disturbance_for(steps), seed=seed,
                        progress=progress, mu_state_bound=spec.design.mu_state_bound)
    except InconsistentDataError as exc:
        return exc.trajectory


__all__ = ["run_scenario"]
