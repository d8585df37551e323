"""``amcp campaign``: verification campaigns at scale on Dask.

Exit codes: 0 every problem passed; 1 a problem failed (its replay commands are printed); 2 bad
input: a bad option, a --store that is a directory, damaged, not a campaign store, or made with
other settings (each difference named). ``--report`` on a damaged store writes what could be read
and exits 2.
"""

from __future__ import annotations

import sqlite3
import sys
from pathlib import Path

import click

from amcp_drake.cli.common import (
    EXIT_BAD_INPUT,
    EXIT_OK,
    bad_input_exits_2,
    echo,
    exit_verdict,
    interruptible,
    max_memory_option,
    output_file_callback,
    parse_range,
    store_path_callback,
    write_error,
)


def _counts_line(counts: dict[str, int]) -> str:
    return f"problems stored: {sum(counts.values())} ({', '.join(f'{k}: {v}' for k, v in sorted(counts.items()))})"


def summary_text(store) -> str:
    """The closing summary: claims x backends, coverage fractions, slowest and failing problems."""
    lines = []
    lines.append(_counts_line(store.problem_counts()))
    lines.append("")
    lines.append(f"{'claim':34s} {'backend':8s} {'pass':>6s} {'fail':>6s} {'not run':>8s}")
    for claim, backend, p, f, n in store.claim_table():
        lines.append(f"{claim:34s} {backend:8s} {p:6d} {f:6d} {n:8d}")
    lines.append("")
    lines.append(f"{'coverage':34s} {'backend':8s} {'fraction':>9s} {'runs':>6s}")
    for key, backend, frac, count in store.coverage_table():
        lines.append(f"{key:34s} {backend:8s} {frac:9.2f} {count:6d}")
    lines += [""] + answer_lines(store.answer_table())
    lines += [""] + draw_lines(store.labels())
    lines.append("")
    lines.append("slowest problems: " + ", ".join(f"#{idx} {sec:.1f} s" for _, idx, sec in store.slowest()))
    failures = store.failures()
    lines.append(f"failing problems: {len(failures)}")
    for seed, idx, folder, message, commands in failures:
        if commands:
            lines.append(f"  seed {seed} #{idx}: replay with")
            lines += [f"    {command}" for command in commands]
        elif folder:  # a store of schema 1 (the first store layout) recorded no commands
            lines.append(f"  seed {seed} #{idx}: {folder}")
        else:
            lines.append(f"  seed {seed} #{idx}: (no replay files: " + ((message or "").splitlines() or [""])[0] + ")")
    return "\n".join(lines)


def draw_lines(labels: list[tuple[int, int, dict[str, str]]]) -> list[str]:
    """The problems by state dimension n, and the draws the offline design rejected before each
    stored problem (the generator's labels "design attempts" and "rejected draws"), grouped by reason."""
    by_n: dict[str, int] = {}
    rejected = 0
    reasons: dict[str, int] = {}
    for _, _, lab in labels:
        if "n" in lab:
            by_n[lab["n"]] = by_n.get(lab["n"], 0) + 1
        rejected += max(int(lab.get("design attempts", "1")) - 1, 0)
        for reason in filter(None, lab.get("rejected draws", "").split(" | ")):
            key = reason.split(": ", 1)[-1].split("; last:")[0]  # "AutoDesignError: 14 design failed, ..."
            reasons[key] = reasons.get(key, 0) + 1
    lines = ["problems by state dimension: " + (", ".join(f"n={n}: {c}" for n, c in sorted(by_n.items(), key=lambda kv: int(kv[0])))
                                               or "(no labels)")]
    lines.append(f"draws rejected by the offline design (and replaced by the next draw): {rejected}")
    lines += [f"  {count:4d} x {reason}" for reason, count in sorted(reasons.items(), key=lambda kv: -kv[1])]
    return lines


def answer_lines(rows: list[tuple[str, str, float, int, int]]) -> list[str]:
    """Fallback and re-solve rates per backend and kind: of the backend's answers of each problem, the share
    that was not its first answer, and the problems with at least one such step."""
    # per (backend, problem): its answers over the campaign and the problems that recorded any (a kind's own
    # key is stored only where it occurred, so its row counts only those problems)
    totals = {(backend, key[: -len("_answers")]): (total, problems) for key, backend, total, _, problems in rows
              if key.endswith("_answers")}
    lines = [f"{'solver answers':44s} {'backend':8s} {'steps':>7s} {'rate':>9s} {'problems':>9s}"]
    for key, backend, total, with_any, problems in rows:
        for outcome in ("resolved", "fallback", "not_solved"):
            head, sep, kind = key.partition(f"_{outcome}")
            if sep and (kind == "" or kind.startswith("_")) and head.startswith("answers_"):
                answered, of_problems = totals.get((backend, head), (0.0, problems))
                rate = f"{total / answered:9.2%}" if answered else f"{'-':>9s}"
                label = f"{head[len('answers_'):]} {outcome}{(' ' + kind[1:]) if kind else ''}"
                lines.append(f"{label:44s} {backend:8s} {int(total):7d} {rate} {int(with_any):5d}/{of_problems}")
                break
    if len(lines) == 1:
        lines.append("(no solver answers recorded)")
    return lines


def report_html(store, damage: list[str] | None = None) -> str:
    """The store rendered as a self-contained HTML page (jinja2); ``damage``: what could not be read
    of a damaged store (shown first)."""
    import jinja2

    template = jinja2.Environment(autoescape=True).from_string(
        "<!doctype html><html><head><meta charset='utf-8'><title>amcp campaign</title>"
        "<style>body{font-family:sans-serif} td,th{padding:2px 8px} .fail{color:#b00}</style></head><body>"
        "<h1>amcp campaign</h1>"
        "{% if damage %}<div id='damage' class='fail'><p>The store is damaged; this report shows only what could "
        "be read:</p><ul>{% for d in damage %}<li>{{ d }}</li>{% endfor %}</ul></div>{% endif %}"
        "<p>{{ counts }}</p>"
        "<h2>Claims</h2><table id='claims'><tr><th>claim</th><th>backend</th><th>pass</th><th>fail</th><th>not run</th></tr>"
        "{% for c, b, p, f, n in claims %}<tr><td>{{ c }}</td><td>{{ b }}</td><td>{{ p }}</td>"
        "<td class='{{ 'fail' if f else '' }}'>{{ f }}</td><td>{{ n }}</td></tr>{% endfor %}</table>"
        "<h2>Coverage</h2><table id='coverage'><tr><th>key</th><th>backend</th><th>fraction</th><th>runs</th></tr>"
        "{% for k, b, fr, n in coverage %}<tr><td>{{ k }}</td><td>{{ b }}</td><td>{{ '%.2f' % fr }}</td><td>{{ n }}</td></tr>{% endfor %}</table>"
        "<h2>Failing problems</h2><ul id='failures'>{% for s, i, d, m, cmds in failures %}<li>seed {{ s }} #{{ i }}: "
        "{% if cmds %}{% for c in cmds %}<code>{{ c }}</code> {% endfor %}{% else %}{{ d or m }}{% endif %}</li>"
        "{% else %}<li>none</li>{% endfor %}</ul></body></html>")
    return template.render(counts=_counts_line(store.problem_counts()), claims=store.claim_table(),
                           coverage=store.coverage_table(), failures=store.failures(), damage=damage or [])


@click.command("campaign")
@click.option("--systems", type=click.IntRange(min=1), default=200, show_default=True, help="Number of random problems.")
@click.option("--backends", default="drake,cvxpy", show_default=True, help="Comma-separated backends.")
@click.option("--seed", type=click.IntRange(min=0), default=0, show_default=True, help="Campaign seed.")
@click.option("--scheduler", default=None, help="Address of an existing Dask scheduler (tcp://host:port).")
@click.option("--workers", type=click.IntRange(min=1), default=2, show_default=True, help="LocalCluster workers.")
@click.option("--store", "store_path", default="amcp-campaign.sqlite", show_default=True, type=click.Path(),
              callback=store_path_callback,
              help="SQLite store, written as each problem finishes; it records the campaign's settings.")
@click.option("--steps", type=click.IntRange(min=2), default=15, show_default=True, help="Closed-loop steps per problem.")
@click.option("--resume", is_flag=True, help="Continue an interrupted campaign with the same settings (stored "
              "problems are skipped; other settings are refused).")
@click.option("--report", "report_file", default=None, type=click.Path(), callback=output_file_callback,
              help="Only render the store as HTML to this file (no run).")
@click.option("--state-dims", "state_dims", default="1-3", show_default=True,
              help="State dimensions n of the drawn problems, A-B or one n (1..8). From n = 4 on the problems use "
                   "the automatic design (bounded-complexity templates first), each design candidate under "
                   "--max-memory and a 60 s budget; the range is recorded in the store.")
@max_memory_option
@interruptible(lambda kw, exc: _interrupted(kw, exc))
@bad_input_exits_2
def campaign_cmd(systems, backends, seed, scheduler, workers, store_path, steps, resume, report_file, max_memory,
                 state_dims):
    """Verification campaign of random problems on Dask, stored in SQLite.

    Draws random problems (the library's numpy generator, amcp_drake.studies.random_problems), runs
    every claim check on each closed loop for each backend, fans out on Dask, and keeps every result in
    SQLite. --state-dims 4-6 draws systems of 4 to 6 states."""
    from amcp_drake.model.errors import ProblemError
    from amcp_drake.studies.campaign_store import CampaignStore

    chosen = tuple(b.strip() for b in backends.split(",") if b.strip())
    if not chosen or any(b not in ("drake", "cvxpy") for b in chosen):
        raise ProblemError("--backends", "a comma-separated subset of drake,cvxpy", repr(backends))
    from amcp_drake.studies.random_problems import MAX_STATE_DIM

    dims = parse_range("--state-dims", state_dims, 1, MAX_STATE_DIM)
    if report_file:
        sys.exit(_report(store_path, report_file))
    from amcp_drake.studies.campaign import run_campaign

    try:
        counts = run_campaign(store_path, systems, chosen, seed=seed, scheduler=scheduler, workers=workers,
                              resume=resume, steps=steps, max_memory_mb=max_memory, state_dims=(dims[0], dims[-1]))
    except (sqlite3.OperationalError, OSError) as exc:  # creating the store on a full disk, say
        from amcp_drake.studies.campaign import store_write_error

        raise store_write_error(store_path, exc) from None
    store = CampaignStore(store_path)
    echo(f"submitted {counts['submitted']}, stored {counts['stored']}, skipped (already stored) {counts['skipped']}")
    echo(summary_text(store))
    ok = not store.failures()
    store.close()
    exit_verdict(ok)


def _interrupted(kwargs: dict, exc: BaseException) -> str:
    """The line printed when a campaign is interrupted: what the store holds and the command that resumes."""
    import shlex

    command = ["amcp", "campaign", "--systems", str(kwargs["systems"]), "--backends", kwargs["backends"], "--seed",
               str(kwargs["seed"]), "--steps", str(kwargs["steps"]), "--store", str(kwargs["store_path"])]
    if kwargs.get("scheduler"):
        command += ["--scheduler", kwargs["scheduler"]]
    stored = getattr(exc, "stored", None)
    held = (f"{stored} of {kwargs['systems']} problems stored in {kwargs['store_path']}" if stored is not None
            else f"stopped before the first result; {kwargs['store_path']} holds what it held before")
    return f"{held}; resume with: {shlex.join(command + ['--resume'])}"


def _report(store_path: str, report_file: str) -> int:
    """``--report``: render the store. A damaged store is salvaged row by row (read-only, from a copy):
    what could be read is rendered with the damage listed first, and the exit code is 2."""
    from amcp_drake.model.errors import CampaignStoreError, ProblemError
    from amcp_drake.studies.campaign_store import CampaignStore, inspect_store, salvage

    try:
        state = inspect_store(store_path)
    except CampaignStoreError as exc:
        if Path(store_path).is_dir():
            raise
        found = salvage(store_path)
        if found.store is None:
            echo(f"error: {exc}. Nothing could be read: " + "; ".join(found.damage) + ". No report written.",
                       err=True)
            return EXIT_BAD_INPUT
        try:
            _write_report(report_html(found.store, found.damage), report_file)
            counts = found.store.problem_counts()
        finally:
            found.store.close()
        read = ", ".join(f"{n} rows of {table}" for table, n in found.rows.items())
        echo(f"error: {exc}", err=True)
        echo(f"the store is damaged; {report_file} shows what could be read: {read}; problems by status: "
                   f"{counts or 'none'}. Unreadable: " + "; ".join(found.damage), err=True)
        return EXIT_BAD_INPUT
    if state.kind == "new":
        raise ProblemError("--store", "an existing campaign store to report on",
                           f"{store_path}: " + ("an empty file" if Path(store_path).exists() else "no such file"))
    store = CampaignStore(store_path, allow_legacy=True)
    try:
        _write_report(report_html(store), report_file)
    finally:
        store.close()
    echo(f"report written to {report_file}")
    return EXIT_OK


def _write_report(html: str, report_file: str) -> None:
    """Write the report atomically; a failed write (a full disk) is a ProblemError naming ``--report``."""
    from amcp_drake.model.problem_io import write_text_atomic

    try:
        write_text_atomic(html, report_file)
    except OSError as exc:
        raise write_error("--report", report_file, exc) from None
