"""The vertex-form LP of the feasible set of (20) now lives in the library
(:mod:`amcp_drake.studies.tube_feasibility`), where the numpy problem generator
(:mod:`amcp_drake.studies.random_problems`) uses it to place initial states on the boundary; this module
re-exports it for the property tests and mutants that import it from here."""

from amcp_drake.studies.tube_feasibility import TubeGeometry, feasibility_margin, max_ray_length

__all__ = ["TubeGeometry", "feasibility_margin", "max_ray_length"]
