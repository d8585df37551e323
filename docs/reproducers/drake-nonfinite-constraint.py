#!/usr/bin/env python3
"""Drake: a NaN in a linear constraint's matrix ends the Python process (SystemExit from a C++
DRAKE_THROW_UNLESS) instead of raising an ordinary exception; a NaN in a linear cost is answered with
kSolverSpecificError. Exit 3: reproduces (SystemExit seen); 0: an ordinary exception or a status; 4:
pydrake missing (any other exit code is an error of the script, not a finding). Needs numpy and pydrake
only.
"""
import sys

import numpy as np

try:
    from pydrake.solvers import ClarabelSolver, MathematicalProgram
except ImportError as exc:
    print(f"cannot run: {exc}")
    sys.exit(4)
from importlib.metadata import version

print(f"drake {version('drake')}, numpy {np.__version__}, python {sys.version.split()[0]}")
prog = MathematicalProgram()
x = prog.NewContinuousVariables(1, "x")
prog.AddLinearCost(np.array([1.0]), 0.0, x)
try:
    prog.AddLinearConstraint(np.array([[np.nan]]), np.array([1.0]), np.array([np.inf]), x)
    result = ClarabelSolver().Solve(prog)
except SystemExit as exc:
    print(f"REPRODUCES: a NaN coefficient raised SystemExit({exc.code}): an uncaught one ends the interpreter")
    sys.exit(3)
except Exception as exc:  # noqa: BLE001
    print(f"does not reproduce: an ordinary exception {type(exc).__name__}: {exc}")
    sys.exit(0)
print(f"does not reproduce: the solve returned {result.get_solution_result()}")
sys.exit(0)
