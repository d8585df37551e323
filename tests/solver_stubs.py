"""Stub solver configurations for tests/test_solver_matrix*.py (``py:tests.solver_stubs:NAME``): each
behaves like one kind of solver defect. They run in the matrix's child processes."""

from __future__ import annotations

import os
import time

from amcp_drake.studies.solver_matrix.solvers import Outcome


def correct(pr, settings):
    return Outcome(True, "stub solved", list(pr.reference["x"]))


def wrong(pr, settings):
    """Success reported with an infeasible point: every coordinate 10 below the reference."""
    return Outcome(True, "stub solved", [v - 10.0 for v in pr.reference["x"]])


def suboptimal(pr, settings):
    """Success reported with a feasible but worse point: every coordinate 1 above the reference (on the
    tests' problem min x s.t. x >= 1: x = 2, objective 2 against 1)."""
    return Outcome(True, "stub solved", [v + 1.0 for v in pr.reference["x"]])


def honest(pr, settings):
    return Outcome(False, "stub iteration limit")


def raises(pr, settings):
    raise RuntimeError("stub solver exception")


class FakePanic(BaseException):
    """Like pyo3's PanicException: a BaseException, not an Exception."""


def panics(pr, settings):
    raise FakePanic("stub panic")


def aborts(pr, settings):
    os.abort()


def hangs(pr, settings):
    time.sleep(600)
    return Outcome(True, "too late", None)
