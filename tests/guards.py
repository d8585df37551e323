"""The one time guard of the suite's child processes (nested pytest runs, CLI commands run as
subprocesses, solver children): :data:`GUARD_SECONDS`.

Why one generous constant and no short per-test timeouts: a child's wall time measures the machine's
load, not the code (on a busy 2-core machine the whole suite ran six times slower than on an idle one,
and a nested pytest run exceeded a 600 s timeout). A test never asserts how long a child took; the
guard only keeps a child that hangs from holding the suite forever, so it is set far above any
child's time on a loaded machine. Budgets that the software itself enforces (CPU limits, candidate
budgets, solver time limits) are tested with fake clocks or CPU counters, not with this guard."""

from __future__ import annotations

#: Wall-time guard of any child process started by a test: one hour.
GUARD_SECONDS = 3600.0
