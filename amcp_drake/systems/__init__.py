"""The controller and the true system (1) as Drake Systems: a layer above ``online`` (imports pydrake).

:class:`~amcp_drake.systems.controller_system.AdaptiveMPCSystem` (the controller as a ``LeafSystem``),
:func:`~amcp_drake.systems.plant.drake_plant` and :class:`~amcp_drake.systems.plant.RecordedDisturbance`
(the plant and its disturbances), :func:`~amcp_drake.systems.closed_loop.closed_loop` and
:func:`~amcp_drake.systems.closed_loop.simulate_in_drake` (the Diagram run by Drake's Simulator).
"""
