"""A plane of two states and the values of the others: the ``--plane`` and ``--fix`` options.

A state is named by its 1-based index (``1`` is x1, as in ``bounds`` and the tables) or by its name
(``phi``; ``x1 … xn`` when the problem names none). ``--plane i,j`` picks two distinct states: plots draw
them as the horizontal and vertical axis, in that order. ``--fix NAME=VALUE,...`` gives values to states
outside the plane (every state not given is 0).
"""

from __future__ import annotations

import math

import numpy as np

from amcp_drake.model.errors import ProblemError
from amcp_drake.model.problem import Problem


def state_index(field: str, token: str, problem: Problem) -> int:
    """The 0-based index of the state named by ``token`` (a 1-based index or a name)."""
    text = token.strip()
    names = problem.state_names
    if text.isdigit():
        i = int(text)
        if 1 <= i <= problem.n:
            return i - 1
        raise ProblemError(field, f"a state index from 1 to {problem.n} or one of the names {list(names)}", repr(text))
    if text in names:
        return names.index(text)
    raise ProblemError(field, f"a state index from 1 to {problem.n} or one of the names {list(names)}", repr(text))


def parse_plane(field: str, text: str, problem: Problem) -> tuple[int, int]:
    """``"i,j"`` -> the 0-based indices (i, j) of two distinct states; ProblemError naming ``field``."""
    if problem.n < 2:
        raise ProblemError(field, "a problem with at least two states (a plane needs two)", f"n = {problem.n}")
    parts = text.split(",") if isinstance(text, str) else []
    if len(parts) != 2:
        raise ProblemError(field, "two states separated by a comma (indices from 1, or names), e.g. 1,2",
                           repr(text))
    i, j = (state_index(field, part, problem) for part in parts)
    if i == j:
        raise ProblemError(field, "two different states", repr(text))
    return i, j


def parse_fixed(field: str, text: str | None, problem: Problem, plane: tuple[int, int]) -> np.ndarray:
    """The n values of a slice: ``"NAME=VALUE,..."`` for states outside ``plane`` (the others 0); the
    entries of the plane are 0 (they vary over the grid)."""
    values = np.zeros(problem.n)
    if not text:
        return values
    seen: set[int] = set()
    for part in text.split(","):
        name, sep, value = part.partition("=")
        if not sep:
            raise ProblemError(field, "NAME=VALUE pairs separated by commas (NAME an index from 1 or a state name)",
                               repr(part))
        i = state_index(field, name, problem)
        if i in plane:
            raise ProblemError(field, "states outside the plane (the plane's states vary over the grid)",
                               f"{name.strip()} (in --plane)")
        if i in seen:
            raise ProblemError(field, "each state at most once", f"{name.strip()} twice")
        try:
            number = float(value)
        except ValueError:
            raise ProblemError(field, f"a number after {name.strip()}=", repr(value)) from None
        if not math.isfinite(number):
            raise ProblemError(field, f"a finite number after {name.strip()}=", repr(value))
        values[i] = number
        seen.add(i)
    return values


__all__ = ["parse_fixed", "parse_plane", "state_index"]
