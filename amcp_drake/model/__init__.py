"""The model layer: what a problem *is*, before any algorithm runs.

System (1)-(2), W, Θ, Z (Assumption 1, eqs (3)-(4)), cost and horizon (``problem``); the JSON problem
file (``problem_io``); the online options of Section 4 (``options``); H-polytope helpers with
numpy/scipy only (``polytope``); the error hierarchy (``errors``); the canonical solve status
(``status``); the result of one check (``check_result``); the built-in problems (``examples``).
Imports nothing else of amcp_drake (docs/architecture.md).
"""
