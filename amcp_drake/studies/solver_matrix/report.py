"""The matrix as a terminal table, ``solvers.json`` and ``solvers.html`` (each written atomically)."""

from __future__ import annotations

import html
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from amcp_drake.studies.solver_matrix.corpus import KINDS, write_json_atomic, write_text_atomic
from amcp_drake.studies.solver_matrix.runner import TOLERANCES, VERDICTS, MatrixRun, summary

MATRIX_FORMAT, MATRIX_VERSION = "amcp-solver-matrix", 1
#: One letter per verdict in the terminal grid.
LETTERS = {"correct": "C", "honest failure": "F", "wrong": "W", "crash": "X", "timeout": "T", "n/a": "."}
COLOURS = {"correct": "#c8e6c9", "honest failure": "#fff3c4", "wrong": "#ffab91", "crash": "#ef5350", "timeout": "#b39ddb",
           "n/a": "#eeeeee"}


def to_json(run: MatrixRun, extra: dict[str, Any] | None = None) -> dict[str, Any]:
    from amcp_drake.studies.solver_matrix.solvers import versions

    return {
        "format": MATRIX_FORMAT, "version": MATRIX_VERSION, "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "settings": run.settings, "tolerances": TOLERANCES[run.settings], "time_limit_s": run.time_limit,
        "versions": versions(), "wall_s": run.wall_s, "configurations": run.configurations,
        "problems": [{"id": p.id, "kind": p.kind, "equation": p.equation, "class": p.problem_class, "n": p.n,
                      "rows": int(p.A.shape[0]), "size": p.size, "reference": p.reference.get("status"),
                      "hard_case": bool(p.provenance.get("hard_case"))} for p in run.problems],
        "summary": summary(run), "cells": [asdict(c) for c in run.cells], **(extra or {}),
    }


def _fmt_time(value: float | None) -> str:
    return "-" if value is None else f"{1e3 * value:.1f}"


def terminal_table(run: MatrixRun) -> str:
    """The per-configuration summary, then the grid (one letter per cell, legend below)."""
    summ = summary(run)
    head = ["solver", *VERDICTS, "median wall ms", "median cpu ms"]
    rows = [[c, *(str(s["counts"][v]) for v in VERDICTS), _fmt_time(s["median_wall_s"]), _fmt_time(s["median_cpu_s"])]
            for c, s in summ.items()]
    lines = [_table(head, rows), ""]
    cells = {(c.problem, c.solver): c for c in run.cells}
    width = max(len(p.id) for p in run.problems) if run.problems else 10
    lines.append("columns: " + ", ".join(f"{i + 1}={c}" for i, c in enumerate(run.configurations)))
    lines.append(" " * (width + 2) + "".join(f"{i + 1:>3}" for i in range(len(run.configurations))))
    for p in run.problems:
        marks = "".join(f"{LETTERS[cells[(p.id, c)].verdict]:>3}" if (p.id, c) in cells else "  ?" for c in run.configurations)
        lines.append(f"{p.id:<{width}}  {marks}")
    lines.append("C correct, F honest failure, W wrong, X crash, T timeout, . n/a (problem class not taken); "
                 f"tolerances ({run.settings}): feasibility {TOLERANCES[run.settings]['feas']:g}, "
                 f"optimality {TOLERANCES[run.settings]['opt']:g}")
    return "\n".join(lines)


def _table(head: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(head, *rows)]
    fmt = lambda r: "  ".join(str(x).ljust(w) if i == 0 else str(x).rjust(w) for i, (x, w) in enumerate(zip(r, widths)))  # noqa: E731
    return "\n".join([fmt(head), "  ".join("-" * w for w in widths), *map(fmt, rows)])


def to_html(data: dict[str, Any]) -> str:
    esc = html.escape
    configs = data["configurations"]
    cells = {(c["problem"], c["solver"]): c for c in data["cells"]}
    out = ["<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>Solver conformance matrix</title>",
           "<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;font-size:12px}"
           "td,th{border:1px solid #bbb;padding:2px 5px}th.v{writing-mode:vertical-rl;transform:rotate(180deg)}"
           "td.c{text-align:center}caption{text-align:left;font-weight:bold;margin:.5em 0}</style></head><body>",
           "<h1>Solver conformance matrix</h1>",
           f"<p>Settings <b>{esc(data['settings'])}</b>; verdict tolerances: feasibility {data['tolerances']['feas']:g}, "
           f"optimality {data['tolerances']['opt']:g} (relative); time limit {data['time_limit_s']:g} s per solve; "
           f"created {esc(data['created'])}; versions: {esc(', '.join(f'{k} {v}' for k, v in data['versions'].items()))}.</p>",
           "<table id='summary'><caption>Per solver configuration</caption><tr><th>solver</th>"
           + "".join(f"<th>{esc(v)}</th>" for v in VERDICTS) + "<th>median wall (ms)</th><th>median CPU (ms)</th></tr>"]
    for config, s in data["summary"].items():
        out.append(f"<tr data-solver=\"{esc(config, quote=True)}\"><td>{esc(config)}</td>" + "".join(
            f"<td class='c' style='background:{COLOURS[v] if s['counts'][v] else '#fff'}'>{s['counts'][v]}</td>" for v in VERDICTS)
            + f"<td class='c'>{_fmt_time(s['median_wall_s'])}</td><td class='c'>{_fmt_time(s['median_cpu_s'])}</td></tr>")
    out.append("</table>")
    out.append("<table id='matrix'><caption>Per problem (hover a cell for the status and detail)</caption><tr><th>problem</th>"
               "<th>kind</th><th>eq.</th><th>n</th>" + "".join(f"<th class='v'>{esc(c)}</th>" for c in configs) + "</tr>")
    for p in data["problems"]:
        row = [f"<tr><td>{esc(p['id'])}</td><td>{esc(p['kind'])}</td><td>{esc(p['equation'])}</td><td>{p['n']}</td>"]
        for c in configs:
            cell = cells.get((p["id"], c))
            if cell is None:
                row.append("<td></td>")
                continue
            tip = esc(f"{cell['verdict']}: {cell['status']} {cell['detail']}".strip(), quote=True)
            row.append(f"<td class='c' title=\"{tip}\" data-problem=\"{esc(p['id'], quote=True)}\" "
                       f"data-solver=\"{esc(c, quote=True)}\" data-verdict=\"{esc(cell['verdict'], quote=True)}\" "
                       f"style='background:{COLOURS[cell['verdict']]}'>"
                       f"{LETTERS[cell['verdict']]}</td>")
        out.append("".join(row) + "</tr>")
    out.append("</table><p>C correct, F honest failure, W wrong (success reported, answer infeasible or suboptimal "
               "beyond the tolerance), X crash, T timeout, . the solver does not take this problem class.</p>")
    out.append("<p>Kinds: " + "; ".join(f"{esc(k)} {esc(v[0])}: {esc(v[1])}" for k, v in KINDS.items()) + ".</p>")
    out.append("</body></html>")
    return "\n".join(out)


def markdown(data: dict[str, Any]) -> str:
    """The summary and the per-kind matrix of a solvers.json as Markdown tables (for docs)."""
    lines = ["| solver | " + " | ".join(VERDICTS) + " | median wall ms | median CPU ms |",
             "|---|" + "---:|" * (len(VERDICTS) + 2)]
    for config, s in data["summary"].items():
        lines.append(f"| {config} | " + " | ".join(str(s["counts"][v]) for v in VERDICTS)
                     + f" | {_fmt_time(s['median_wall_s'])} | {_fmt_time(s['median_cpu_s'])} |")
    kinds = list(dict.fromkeys(p["kind"] for p in data["problems"]))
    kind_of = {p["id"]: p["kind"] for p in data["problems"]}
    lines += ["", "Per kind of problem, correct / total taken (W wrong, X crash, T timeout, F honest failure):", "",
              "| solver | " + " | ".join(f"{k} {KINDS[k][0]}" for k in kinds) + " |", "|---|" + "---|" * len(kinds)]
    for config in data["configurations"]:
        row = []
        for kind in kinds:
            cells = [c for c in data["cells"] if c["solver"] == config and kind_of[c["problem"]] == kind and c["verdict"] != "n/a"]
            if not cells:
                row.append("n/a")
                continue
            text = f"{sum(c['verdict'] == 'correct' for c in cells)}/{len(cells)}"
            marks = [f"{sum(c['verdict'] == v for c in cells)}{LETTERS[v]}" for v in ("wrong", "crash", "timeout", "honest failure")
                     if any(c["verdict"] == v for c in cells)]
            row.append(text + (" " + " ".join(marks) if marks else ""))
        lines.append(f"| {config} | " + " | ".join(row) + " |")
    return "\n".join(lines)


def write_outputs(out_dir: Path, data: dict[str, Any]) -> tuple[Path, Path]:
    return (write_json_atomic(out_dir / "solvers.json", data, indent=1),
            write_text_atomic(out_dir / "solvers.html", to_html(data)))


__all__ = ["LETTERS", "MATRIX_FORMAT", "MATRIX_VERSION", "markdown", "terminal_table", "to_html", "to_json", "write_outputs"]
