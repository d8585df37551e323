"""Drake's log kept off the terminal below WARNING.

pydrake routes Drake's C++ log (spdlog) through Python's ``logging`` (logger ``"drake"``, level INFO,
set again each time pydrake is imported) and configures the root logger on its first message, so a
solver's INFO line such as ``INFO:drake:Clarabel returns NumericalError`` reaches stderr in the
middle of the command's output. What such a line says about the tube QP (20) is in the step record:
its ``MPCSolution.detail`` (``StepRecord.qp_detail``) names Clarabel's own status of a failed answer
(:meth:`~amcp_drake.backends.drake_solver.DrakeSolver.describe`) and of every try a retry had to
rescue (:func:`~amcp_drake.backends.drake_solver.tries_note`), and each step's provenance says how its
answer was obtained. :func:`drop_drake_info` adds a filter to the ``"drake"`` logger that drops
records below WARNING; a filter, not a level, because pydrake resets the level on import. Warnings
and errors of Drake still reach stderr. Called by the ``amcp`` command line and in each campaign
worker; a library user keeps Python's logging as configured.
"""

from __future__ import annotations

import logging

#: The logger pydrake writes Drake's C++ log to.
DRAKE_LOGGER = "drake"


class BelowWarning(logging.Filter):
    """Drops records below WARNING."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno >= logging.WARNING


def drop_drake_info() -> None:
    """Drop Drake's log records below WARNING (module docstring); idempotent. Does not import pydrake."""
    logger = logging.getLogger(DRAKE_LOGGER)
    if not any(isinstance(f, BelowWarning) for f in logger.filters):
        logger.addFilter(BelowWarning())


__all__ = ["DRAKE_LOGGER", "BelowWarning", "drop_drake_info"]
