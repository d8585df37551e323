"""Helpers shared by the CLI subcommands: loading a problem, mapping errors to exit code 2."""

from __future__ import annotations

import functools
import sys
from typing import Callable

import click

from .errors import AmcpError, BackendNotFound, ProblemError, TrajectoryError

EXIT_OK, EXIT_FAIL, EXIT_BAD_INPUT = 0, 1, 2


def load_problem_spec(problem_file: str | None, example: str | None):
    """The ProblemSpec named by a PROBLEM argument or ``--example`` (default: lorenzen2019)."""
    from .examples import get_example
    from .problem_io import load_spec

    if problem_file and example:
        raise ProblemError("PROBLEM, --example", "one of them", "both")
    if problem_file:
        return load_spec(problem_file)
    return get_example(example or "lorenzen2019")


def bad_input_exits_2(func: Callable) -> Callable:
    """Turn ProblemError / BackendNotFound / TrajectoryError into a one-line message and exit 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (ProblemError, BackendNotFound, TrajectoryError) as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(EXIT_BAD_INPUT)
        except AmcpError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(EXIT_FAIL)

    return wrapper


backend_option = click.option("--backend", type=click.Choice(["drake", "cvxpy"]), default="drake", show_default=True,
                              help="Optimisation backend.")
problem_argument = click.argument("problem_file", metavar="[PROBLEM]", required=False, type=click.Path())
example_option = click.option("--example", default=None, help="Built-in example (default: lorenzen2019).")

formulation_option = click.option("--formulation", type=click.Choice(["plain", "vertex"]), default="plain",
                                  show_default=True,
                                  help="Tube QP: plain (15) with multipliers, or the exact vertex form (faster, issue 8).")
