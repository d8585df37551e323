"""Helpers shared by the CLI subcommands: loading a problem, mapping errors to exit code 2."""

from __future__ import annotations

import errno
import functools
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple, NoReturn

import click

from amcp_drake.model.errors import AmcpError, BackendNotFound, ProblemError, TrajectoryError
from amcp_drake.model.limits import DEFAULT_MAX_MEMORY_MB, MAX_MEMORY_MB, MAX_STEPS
from amcp_drake.model.problem_io import check_output_dir, check_output_file, check_store_path
from amcp_drake.offline.budget import DEFAULT_CANDIDATE_SECONDS, PROGRESS_SECONDS

EXIT_OK, EXIT_FAIL, EXIT_BAD_INPUT = 0, 1, 2
#: ``amcp certify``: a premise of the paper's results does not hold on the run (nothing is claimed).
EXIT_PREMISE_NOT_MET = 3
#: Largest seed: seeds are stored as signed 64-bit integers (campaign store, trajectory meta).
MAX_SEED = 2**63 - 1
#: Most disturbance seeds of one ``amcp baseline`` / ``pe-figure`` (each seed is two full runs).
MAX_SEEDS = 10_000


#: Characters a terminal interprets rather than shows: the C0 controls but newline and tab (ESC starts escape
#: sequences, CR overwrites the line, BEL rings), DEL and the C1 controls (CSI U+009B is ESC [ on some terminals).
_CONTROL_CHARACTERS = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def terminal_safe(text: str) -> str:
    """``text`` with every control character but newline and tab written as a visible escape (``\\x1b``,
    ``\\r``): a problem name or file content printed to the terminal cannot move the cursor, clear the screen or
    rewrite the line."""
    named = {"\r": "\\r", "\x1b": "\\x1b"}
    return _CONTROL_CHARACTERS.sub(lambda m: named.get(m.group(), f"\\x{ord(m.group()):02x}"), text)


def echo(message: object = "", err: bool = False, nl: bool = True) -> None:
    """``click.echo`` of :func:`terminal_safe` text: the lines of design, run, certify, baseline, coverage, compare,
    pe-figure and campaign go through here."""
    click.echo(terminal_safe(str(message)), err=err, nl=nl)


def exit_verdict(passed: bool) -> NoReturn:
    """End a command: exit code 0 when what it checks holds, 1 otherwise (2, bad input, is
    :func:`bad_input_exits_2`'s)."""
    sys.exit(EXIT_OK if passed else EXIT_FAIL)


def load_problem_spec(problem_file: str | None, example: str | None):
    """The ProblemSpec named by a PROBLEM argument or ``--example`` (default: lorenzen2019); what
    loading changed (``spec.notes``, e.g. redundant rows removed) is printed to stderr."""
    from amcp_drake.model.examples import get_example
    from amcp_drake.model.problem_io import load_spec

    if problem_file and example:
        raise ProblemError("PROBLEM, --example", "one of them", "both")
    if problem_file is not None and not str(problem_file).strip():
        raise ProblemError("PROBLEM", "the path of a problem file", "an empty string")
    spec = load_spec(problem_file) if problem_file else get_example(example or "lorenzen2019")
    for note in spec.notes:
        echo(f"note: {note}", err=True)
    return spec


def check_run_size(spec, steps: int, online=None, max_memory_mb: float = DEFAULT_MAX_MEMORY_MB, design=None,
                   formulation: str = "plain"):
    """The run-size check of every command that runs the tube QP (20): refuse a run whose estimated size
    exceeds ``--max-memory``, before the design (``design`` None) and again with the design found before
    the controller is built, for the form of (20) the run will use (``formulation``, "auto" resolved
    first: :func:`amcp_drake.online.run_size.check_run_size`); returns the estimate. ``amcp design``
    builds no run and does not call it."""
    from amcp_drake.online.run_size import check_run_size as check

    online = online if online is not None else spec.online
    return check(spec.problem, spec.design, steps, online, max_memory_mb, design=design, formulation=formulation)


# -- output paths (checked as soon as the option is parsed) ----------------------------------------
def _callback(check: Callable[[str, str], Path]) -> Callable:
    def callback(ctx: click.Context, param: click.Parameter, value):
        if value is None:
            return None
        try:
            check(param.opts[0], value)
        except ProblemError as exc:
            raise click.BadParameter(f"expected {exc.expected}; received {exc.received}") from None
        return value

    return callback


def check_nonempty_path(option: str, path) -> Path:
    """``path`` as a Path unless it is empty or blank (``Path("")`` is ".", the current folder, which no
    path option means): ProblemError naming ``option``."""
    if path is None or not str(path).strip():
        raise ProblemError(option, "a path", "an empty string")
    return Path(path)


#: click callbacks: the option is checked as soon as it is parsed (exit 2, click's "Invalid value for '--out'").
output_dir_callback = _callback(check_output_dir)
output_file_callback = _callback(check_output_file)
store_path_callback = _callback(check_store_path)
_nonempty_callback = _callback(check_nonempty_path)


def nonempty_path_callback(ctx: click.Context, param: click.Parameter, value):
    """click callback of an input path option (repeatable or not): every value given must be non-empty."""
    for item in value if isinstance(value, (tuple, list)) else (value,):
        _nonempty_callback(ctx, param, item)
    return value


def steps_option(help_text: str, default=None, minimum: int = 1, show_default: bool = False):
    """``--steps`` between ``minimum`` and :data:`~amcp_drake.model.limits.MAX_STEPS` (``--steps 0`` is refused,
    never read as "the default")."""
    return click.option("--steps", type=click.IntRange(minimum, MAX_STEPS), default=default, show_default=show_default,
                        help=help_text)


def seed_option(help_text: str, default=None, show_default: bool = False):
    """``--seed`` between 0 and :data:`MAX_SEED`."""
    return click.option("--seed", type=click.IntRange(0, MAX_SEED), default=default, show_default=show_default,
                        help=help_text)


def seeds_option(help_text: str, default: int):
    """``--seeds`` between 1 and :data:`MAX_SEEDS` (the disturbance seeds 0..seeds-1 of a study)."""
    return click.option("--seeds", type=click.IntRange(1, MAX_SEEDS), default=default, show_default=True,
                        help=help_text)


class FiniteFloatRange(click.FloatRange):
    """A click FloatRange that refuses NaN and ±inf (``nan >= 1`` is false, so FloatRange lets NaN
    through, and an infinite limit is no limit)."""

    def convert(self, value, param, ctx):
        import math

        number = click.FLOAT.convert(value, param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return super().convert(number, param, ctx)


def parse_range(option: str, text: str, low: int, high: int) -> tuple[int, ...]:
    """"A-B" or "A" (integers, low <= A <= B <= high) as the tuple A..B; ProblemError naming ``option``."""
    from amcp_drake.model.errors import ProblemError

    expected = f"an integer or a range A-B of integers within {low}..{high}"
    parts = text.strip().split("-")
    try:
        first, last = (int(parts[0]), int(parts[-1])) if len(parts) in (1, 2) else (None, None)
    except ValueError:
        first = last = None
    if first is None or not low <= first <= last <= high:
        raise ProblemError(option, expected, repr(text))
    return tuple(range(first, last + 1))


max_memory_option = click.option(
    "--max-memory", "max_memory", type=FiniteFloatRange(min=1.0, max=MAX_MEMORY_MB), default=DEFAULT_MAX_MEMORY_MB,
    show_default=True,
    help="Refuse a run whose estimated size (tube QP nonzeros in the form of (20) the run uses, recorded steps; "
         "docs/problem-format.md, 'Size limits') exceeds this many MiB, before anything is built; every stage of "
         "the offline design is sized against the same limit (a design candidate above it is skipped, with the "
         "stage named).")

#: ``amcp design``'s --max-memory: the design builds no run, so only its own stages are sized.
design_max_memory_option = click.option(
    "--max-memory", "max_memory", type=FiniteFloatRange(min=1.0, max=MAX_MEMORY_MB), default=DEFAULT_MAX_MEMORY_MB,
    show_default=True,
    help="Memory limit of the offline design in MiB: every stage of it is sized against this limit before it "
         "allocates (a candidate above it is skipped, with the stage named). The size of a later run is checked "
         "by the command that runs it, in the form of (20) it uses.")


candidate_budget_option = click.option(
    "--candidate-budget", "candidate_budget", type=click.FloatRange(min=0.1), default=DEFAULT_CANDIDATE_SECONDS,
    show_default=True,
    help="Time budget of one candidate of the offline design, in CPU seconds (so that the choice does not depend "
         "on the machine's load; automatic mode: a candidate over it is recorded as 'time budget' and the next one "
         "is tried; a fixed template stops with that reason).")



progress_every_option = click.option(
    "--progress-every", "progress_every", type=FiniteFloatRange(min=0.1, max=3600.0), default=PROGRESS_SECONDS,
    show_default=True,
    help="Least wall time in seconds between two progress lines of a long design stage on stderr.")


def design_budget(max_memory: float = DEFAULT_MAX_MEMORY_MB, candidate_budget: float | None = DEFAULT_CANDIDATE_SECONDS,
                  quiet: bool = False, progress_every: float = PROGRESS_SECONDS):
    """The :class:`~amcp_drake.offline.budget.DesignBudget` of a command: ``--max-memory``,
    ``--candidate-budget`` and progress lines on stderr (each design candidate when it starts and ends,
    long stages every ``--progress-every`` seconds) unless ``quiet``."""
    from amcp_drake.offline.budget import DesignBudget

    progress = None if quiet else (lambda line: echo(line, err=True))
    return DesignBudget(max_memory, candidate_budget, progress, progress_seconds=progress_every)


def bad_input_exits_2(func: Callable) -> Callable:
    """Turn ProblemError / BackendNotFound / TrajectoryError into a one-line message and exit 2."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            return func(*args, **kwargs)
        except (ProblemError, BackendNotFound, TrajectoryError) as exc:
            echo(f"error: {exc}", err=True)
            sys.exit(EXIT_BAD_INPUT)
        except AmcpError as exc:
            echo(f"error: {exc}", err=True)
            sys.exit(EXIT_FAIL)

    return wrapper


class Terminated(KeyboardInterrupt):
    """Raised in the main thread on SIGTERM while a command of :func:`interruptible` runs, so that a
    SIGTERM unwinds exactly like Ctrl-C (staging folders removed, workers stopped, stores closed)."""


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


def interruptible(describe: Callable[[dict, BaseException], str]) -> Callable:
    """Handle SIGTERM like SIGINT in a command and end an interrupt with one line on stderr,
    ``interrupted (SIGTERM): <describe(kwargs, exc)>``, and exit code 128 + the signal number (130 on
    Ctrl-C, 143 on SIGTERM) instead of click's "Aborted!" or a traceback. ``describe`` says what was
    (not) written and how to continue, from the command's keyword arguments."""
    import signal

    def decorate(func: Callable) -> Callable:
        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            import threading

            main = threading.current_thread() is threading.main_thread()
            previous = signal.signal(signal.SIGTERM, _raise_terminated) if main else None
            try:
                return func(*args, **kwargs)
            except KeyboardInterrupt as exc:
                signum = signal.SIGTERM if isinstance(exc, Terminated) else signal.SIGINT
                try:
                    text = describe(kwargs, exc)
                except Exception:  # noqa: BLE001 - the line is said even if the description fails
                    text = "stopped"
                echo(f"interrupted ({signum.name}): {text}", err=True)
                sys.exit(128 + signum)
            finally:
                if main:
                    signal.signal(signal.SIGTERM, previous)

        return wrapper

    return decorate


#: errno values of a failed write that the user can fix (full disk, quota, read-only or failing medium).
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EIO, errno.EFBIG})


def write_error(option: str, path, exc: OSError) -> ProblemError:
    """A ProblemError naming ``option`` for a write that failed with ``exc`` (a full disk: ENOSPC)."""
    name = errno.errorcode.get(exc.errno or 0, "")
    cause = f"{exc.strerror or exc}" + (f" ({name})" if name else "")
    return ProblemError(option, "a place where the output can be written", f"{path}: {cause}; nothing was written")


x0_template_option = click.option(
    "--x0-template", "x0_template", type=click.Choice(["auto", "mrpi", "contractive", "given", "parallelotope", "preimage"]), default=None,
    help="Cross-section template of the tube (docs/decisions.md, 'X0 templates'): auto tries them in a documented "
         "order and keeps the first design passing every check. Default: the problem file's design.x0_template, "
         "else auto. 'given' needs design.x0_H in the file.")


def with_x0_template(spec, x0_template: str | None):
    """``spec`` with design.x0_template replaced by ``x0_template`` (None: unchanged), validated again."""
    import dataclasses

    if x0_template is None:
        return spec
    options = dataclasses.replace(spec.design, x0_template=x0_template).validate_for(spec.problem)
    return dataclasses.replace(spec, design=options)


backend_option = click.option("--backend", type=click.Choice(["drake", "cvxpy"]), default="drake", show_default=True,
                              help="Optimisation backend.")
problem_argument = click.argument("problem_file", metavar="[PROBLEM]", required=False, type=click.Path())
example_option = click.option("--example", default=None, help="Built-in example (default: lorenzen2019).")

formulation_option = click.option(
    "--formulation", type=click.Choice(["auto", "plain", "vertex"]), default="auto", show_default=True,
    help="Form of the tube QP (20): auto (the default) chooses the exact vertex form when its size per stage is at "
         "most a measured multiple of the plain form's, else the plain form, and the plain form whenever an option "
         "needs it (min-max cost, d_theta > 0, PE; docs/decisions.md, 'The formulation of the tube QP'); plain: (15) "
         "with the multipliers Λ, the paper's form, whose Λ the certificate checks; vertex: (5b) at the vertices "
         "of Θ_k, the same optimum, no Λ (the certificate lists the Λ claims as not applicable).")

design_file_option = click.option(
    "--design", "design_file", default=None, type=click.Path(dir_okay=False),
    help="Use the design saved by 'amcp design PROBLEM --out FILE' instead of designing: refused (exit 2) when it "
         "was made for another problem (SHA-256 of the canonical problem) or fails any independent check of the "
         "offline design, which are run again on loading. Nothing is redesigned.")


def load_design_file(spec, design_file: str | None, quiet: bool = False):
    """The OfflineDesign of ``--design`` for ``spec`` (checked: :func:`amcp_drake.offline.design_file.load_design`),
    or None when no file is given; one line on stderr says it is used."""
    if design_file is None:
        return None
    from amcp_drake.offline.design_file import load_design

    if not str(design_file).strip():
        raise ProblemError("--design", "the path of a design file", "an empty string")
    d = load_design(design_file, spec)
    if not quiet:
        echo(f"design: {design_file} (problem SHA-256 matches; every design check passes; not redesigned)", err=True)
    return d


def parse_vector(option: str, text: str | None, size: int):
    """``text`` ("1.5,-2,0") as a float vector of length ``size``, every entry finite; ProblemError naming
    ``option`` otherwise. None stays None."""
    import math

    import numpy as np

    if text is None:
        return None
    expected = f"{size} finite numbers separated by commas"
    try:
        values = [float(part) for part in str(text).split(",")]
    except ValueError:
        raise ProblemError(option, expected, repr(text)) from None
    if len(values) != size:
        raise ProblemError(option, expected, f"{len(values)} number(s): {text!r}")
    bad = [v for v in values if not math.isfinite(v)]
    if bad:
        raise ProblemError(option, expected, f"{text!r} (not finite: {bad[0]!r})")
    return np.array(values, dtype=float)


def scenario_options(func: Callable) -> Callable:
    """``--x0`` and ``--theta-star``: the initial state and the true parameter of the run, replacing the
    problem file's scenario values (:func:`with_scenario`)."""
    func = click.option("--theta-star", "theta_star", default=None, metavar="T1,T2,...",
                        help="True parameter θ* of the run (p comma-separated numbers, a point of Θ); default: "
                             "the problem file's scenario.")(func)
    return click.option("--x0", "x0", default=None, metavar="X1,X2,...",
                        help="Initial state of the run (n comma-separated numbers); default: the problem file's "
                             "scenario.")(func)


def with_scenario(spec, x0: str | None, theta_star: str | None):
    """``spec`` with ``--x0`` / ``--theta-star`` replacing its scenario's x0 / θ* (a constant θ*), each
    checked (length, finite, θ* ∈ Θ) with errors naming the option. Without a scenario in the file both
    options make one (50 steps, uniform disturbance, seed 0)."""
    import dataclasses

    from amcp_drake.model import polytope
    from amcp_drake.model.problem import THETA_HAT0_TOL, Scenario

    if x0 is None and theta_star is None:
        return spec
    pr = spec.problem
    x0_vec = parse_vector("--x0", x0, pr.n)
    theta_vec = parse_vector("--theta-star", theta_star, pr.p)
    if theta_vec is not None:
        violation = polytope.max_violation(pr.H_theta, pr.h_theta, theta_vec)
        if violation > THETA_HAT0_TOL:
            raise ProblemError("--theta-star", "a point of Theta (Assumption 1)", f"{theta_star!r}, outside by {violation:.3g}")
    sc = spec.scenario
    if sc is None:
        if x0_vec is None or theta_vec is None:
            raise ProblemError("scenario", SCENARIO_EXPECTED, "none", "Add a \"scenario\" object, or pass both --x0 "
                               "and --theta-star.")
        scenario = Scenario(x0_vec, theta_vec)
    else:
        scenario = dataclasses.replace(sc, x0=sc.x0 if x0_vec is None else x0_vec,
                                       theta_star=sc.theta_star if theta_vec is None else theta_vec)
    return dataclasses.replace(spec, scenario=scenario)


simulator_option = click.option(
    "--simulator", type=click.Choice(["builtin", "drake"]), default="builtin", show_default=True,
    help="Who runs the plant (1): amcp's simulator, or Drake's Simulator with the plant as a Drake AffineSystem "
         "and the controller as AdaptiveMPCSystem (the same closed loop; the trajectory records which ran it; "
         "docs/how-to/drake-plant.md).")


def simulate_function(simulator: str) -> Callable:
    """The closed-loop function of ``--simulator``: :func:`amcp_drake.online.simulate.simulate` (builtin) or
    :func:`amcp_drake.systems.closed_loop.simulate_in_drake` (drake: pydrake imported only here)."""
    if simulator == "drake":
        from amcp_drake.systems.closed_loop import simulate_in_drake

        return simulate_in_drake
    from amcp_drake.online.simulate import simulate

    return simulate


def update_options(func):
    """--update, --window, --projection (the online set update and LMS projection; defaults: the
    file's online section). ``--update none`` is the robust baseline (Θ_k ≡ Θ, θ̂_k ≡ θ̂0)."""
    func = click.option("--projection", type=click.Choice(["Theta", "Theta_k"]), default=None,
                        help="Project the LMS estimate onto Θ (12) or Θ_k (Remark 7). Default: file, else "
                             "Theta.")(func)
    func = click.option("--window", type=click.IntRange(min=1), default=None,
                        help="Window length for --update window (default: file, else 10).")(func)
    return click.option("--update", type=click.Choice(["fixed", "exact", "window", "none"]), default=None,
                        help="Parameter-set update: (9), (7), (9) over a moving window (Remark 4), or none (robust "
                             "baseline). Default: the problem file's online section, else fixed.")(func)


def section4_options(func):
    """--d-theta, --pe, --pe-level, --cost (Section 4 extensions; defaults: the file's online section)."""
    func = click.option("--cost", type=click.Choice(["certainty_equivalence", "minmax"]), default=None,
                        help="Cost of (20): (17) with θ̂_k, or the min-max cost (19) (default: the file's online "
                             "section, else certainty_equivalence). minmax is solved in the plain form (auto chooses it).")(func)
    func = click.option("--pe-level", "pe_level", type=click.FloatRange(min=0.0, min_open=True), default=None,
                        help="PE level ρ (default: file, else 0.1).")(func)
    func = click.option("--pe", "pe_window", type=click.IntRange(min=1), default=None,
                        help="Enforce a persistently exciting input over windows of this length (Section 4.2 of the paper, m = 1; "
                             "default: the file's online section, else off). Solved in the plain form (auto chooses it).")(func)
    return d_theta_option(func)


d_theta_option = click.option("--d-theta", "d_theta", type=click.FloatRange(min=0.0), default=None,
                              help="Rate bound d_θ of a time-varying θ* (Section 4.1; default: the problem file's "
                                   "online section, else 0). Solved in the plain form (auto chooses it).")


def resolve_online(spec, **given):
    """OnlineOptions: the problem file's ``online`` section (or the defaults), with every option
    given on the command line (not None) replacing its field."""
    import dataclasses

    from amcp_drake.model.options import OnlineOptions

    base = spec.online if spec.online is not None else OnlineOptions()
    changes = {k: v for k, v in given.items() if v is not None}
    return dataclasses.replace(base, **changes)


# -- composite options and the set-up every run command shares -----------------------------------
def _stack(*decorators: Callable) -> Callable:
    """The decorators applied as if written one above the other (so click lists them in this order)."""

    def apply(func: Callable) -> Callable:
        for decorator in reversed(decorators):
            func = decorator(func)
        return func

    return apply


def problem_options(x0_template: bool = True) -> Callable:
    """``[PROBLEM]``, ``--example`` and (``x0_template``) ``--x0-template``: the problem a command reads
    (:func:`load_problem_spec`, :func:`with_x0_template`)."""
    return _stack(problem_argument, example_option, *([x0_template_option] if x0_template else []))


#: The online options of :func:`online_options`, in the order of OnlineOptions' fields they replace.
ONLINE_OPTION_NAMES = ("update", "window", "projection", "d_theta", "pe_window", "pe_level", "cost")


def online_options(func: Callable) -> Callable:
    """--update, --window, --projection (:func:`update_options`) and --d-theta, --pe, --pe-level, --cost
    (:func:`section4_options`), handed to the command as one argument ``online``: a dict of the seven
    values (None where not given), ready for :func:`prepare_run` / :func:`resolve_online`."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        online = {name: kwargs.pop(name) for name in ONLINE_OPTION_NAMES}
        return func(*args, online=online, **kwargs)

    return _stack(update_options, section4_options)(wrapper)


#: What :func:`require_scenario` says is missing, unless a command says more.
SCENARIO_EXPECTED = "a scenario in the problem file (x0, theta_star)"


def require_scenario(spec, expected: str = SCENARIO_EXPECTED, fix: str = ""):
    """``spec.scenario``; a ProblemError naming the field ``scenario`` when the problem has none."""
    if spec.scenario is None:
        raise ProblemError("scenario", expected, "none", fix)
    return spec.scenario


class RunSetup(NamedTuple):
    """What a closed-loop command has decided before anything is built (:func:`prepare_run`)."""

    spec: object  #: the ProblemSpec (PROBLEM or --example, with --x0-template, --x0, --theta-star applied)
    steps: int  #: --steps, else the scenario's
    options: object  #: the OnlineOptions: the file's online section with the options given replacing it
    design: object = None  #: the OfflineDesign of --design (checked), or None: the command designs


def prepare_run(problem_file: str | None, example: str | None, x0_template: str | None, steps: int | None,
                online: dict, max_memory: float, scenario_expected: str = SCENARIO_EXPECTED,
                scenario_fix: str = "", formulation: str = "plain", design_file: str | None = None,
                x0: str | None = None, theta_star: str | None = None) -> RunSetup:
    """The set-up of ``amcp run``, ``certify`` and ``compare``: load the problem, apply --x0-template
    (refused together with --design), --x0 and --theta-star, require a scenario, take the steps from it
    unless --steps is given, resolve the online options, load and check --design, and refuse a run
    larger than --max-memory (:func:`check_run_size`, for ``formulation``, with the design when one is
    given), in this order."""
    if design_file is not None and x0_template is not None:
        raise ProblemError("--x0-template, --design", "at most one of them (the design file fixes X0)", "both")
    spec = with_x0_template(load_problem_spec(problem_file, example), x0_template)
    spec = with_scenario(spec, x0, theta_star)
    scenario = require_scenario(spec, scenario_expected, scenario_fix)
    steps = scenario.steps if steps is None else steps
    options = resolve_online(spec, **online)
    d = load_design_file(spec, design_file)
    check_run_size(spec, steps, options, max_memory, design=d, formulation=formulation)
    return RunSetup(spec, steps, options, d)
