"""Bad input, one table: every case exits 2 through the CLI
entry point (in-process, click's CliRunner) with a message naming the field or option, and writes
nothing (no new file anywhere below the test folder, which is also the working directory).

Each row: (id, build, args, exit code, regex). ``build(folder)`` writes the inputs and returns a dict
of names -> paths that ``args`` refer to as ``{name}``. Rows marked with ``after`` also check the
folder afterwards (stale staging folders removed). The required cases come first (by kind of input),
then at least 40 more (from "our own" on).

Every row fails on code without the input checks (run with memory limited by ulimit -v and
pytest-timeout): a traceback, exit 0/1, a run that does not end, or a message that does not name the
field. Cases that code already handled (a top-level list, a missing cost.Q, pe-figure --out naming a
file) are not rows.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import re
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from amcp_drake.cli import main
from tests.guards import GUARD_SECONDS
from tests.recorded_runs import TRAJECTORY_DATA, trajectory

STALE = ".certify-staging-" + "0123456789abcdef" * 2


def example() -> dict:
    """Example 1's problem file as a dict, with a 3-step scenario (so a wrongly accepted run is short)."""
    data = json.loads((resources.files("amcp_drake") / "data" / "lorenzen2019.json").read_text())
    data["scenario"]["steps"] = 3
    return data


# -- builders ----------------------------------------------------------------------------------------
def text(name: str, content: str | bytes) -> Callable[[Path], dict]:
    def build(folder: Path) -> dict:
        path = folder / name
        path.write_bytes(content if isinstance(content, bytes) else content.encode("utf-8"))
        return {"file": path}

    return build


def problem(change: Callable[[dict], Any], raw: dict[str, str] | None = None) -> Callable[[Path], dict]:
    """Example 1 changed by ``change``; ``raw`` replaces quoted placeholders by literal JSON text
    (NaN, 1e400, 400-digit integers, duplicate keys: things json.dumps cannot write)."""

    def build(folder: Path) -> dict:
        data = example()
        change(data)
        content = json.dumps(data)
        for placeholder, literal in (raw or {}).items():
            assert f'"{placeholder}"' in content
            content = content.replace(f'"{placeholder}"', literal)
        path = folder / "problem.json"
        path.write_text(content)
        return {"file": path}

    return build


def traj(change: Callable[[dict], Any], raw: dict[str, str] | None = None, gz: bool = True) -> Callable[[Path], dict]:
    def build(folder: Path) -> dict:
        data = trajectory()
        change(data)
        content = json.dumps(data)
        for placeholder, literal in (raw or {}).items():
            assert f'"{placeholder}"' in content
            content = content.replace(f'"{placeholder}"', literal)
        path = folder / ("trajectory.json.gz" if gz else "trajectory.json")
        path.write_bytes(gzip.compress(content.encode()) if gz else content.encode())
        return {"file": path}

    return build


def files(**named: Callable[[Path], Path]) -> Callable[[Path], dict]:
    def build(folder: Path) -> dict:
        return {name: make(folder) for name, make in named.items()}

    return build


def a_file(folder: Path) -> Path:
    path = folder / "a-file"
    path.write_text("x")
    return path


def a_dir(folder: Path) -> Path:
    path = folder / "a-dir"
    path.mkdir()
    return path


def good_traj(folder: Path) -> Path:
    path = folder / "good.json.gz"
    path.write_bytes(TRAJECTORY_DATA.read_bytes())
    return path


def stale_staging(folder: Path) -> Path:
    """D/ with the staging folder a killed certify leaves (no writer holds its lock)."""
    out = folder / "D"
    (out / STALE).mkdir(parents=True)
    (out / STALE / "certificate.json").write_text("{half")
    (out / STALE / ".lock").write_text("")
    return out


def big_redundant_w(folder: Path) -> Path:
    """A 5 MB problem file: Example 1 plus 220,000 rows of W.H inside the box |w_i| <= 0.1."""
    data = example()
    rng = np.random.default_rng(0)
    angle = rng.uniform(0.0, 2.0 * np.pi, 220_000)
    radius = rng.uniform(1.0, 7.0, (220_000, 1))  # ‖a‖₁ <= 7√2 < 10: implied by the box rows
    data["W"]["H"] += (np.c_[np.cos(angle), np.sin(angle)] * radius).round(6).tolist()
    path = folder / "big.json"
    path.write_text(json.dumps(data))
    assert path.stat().st_size > 5e6
    return path


def set_(path: str, value: Any) -> Callable[[dict], None]:
    """``set_("cost.R", [[True]])``: set a field by its dotted path (list indices as [i])."""

    def change(data: dict) -> None:
        keys = re.findall(r"[^.\[\]]+", path)
        target = data
        for key in keys[:-1]:
            target = target[int(key)] if key.isdigit() else target[key]
        last = keys[-1]
        if last.isdigit():
            target[int(last)] = value
        else:
            target[last] = value

    return change


def delete(path: str) -> Callable[[dict], None]:
    def change(data: dict) -> None:
        *head, last = path.split(".")
        target = data
        for key in head:
            target = target[key]
        del target[last]

    return change


def no_stale_staging(folder: Path) -> None:
    assert not list((folder / "D").glob(".certify-staging-*"))


NESTED = "[" * 100_000 + "]" * 100_000

#: (id, build, args, exit code, regex the output must match)
ROWS: list[tuple] = [
    # ---- malformed files, extreme numbers, impossible options, paths and stores ---------------------
    ("binary-problem-file", text("p.json", bytes(range(256)) * 4), ["design", "{file}"], 2,
     r"file: expected UTF-8 .*p\.json contains NUL bytes \(binary data\)"),
    ("utf16-bom-problem-file", lambda f: text("p.json", json.dumps(example()).encode("utf-16"))(f),
     ["design", "{file}"], 2, r"p\.json is UTF-16 \(little-endian, with byte-order mark\)"),
    ("cost.Q-1e308", problem(set_("cost.Q.0.0", 1e308)), ["run", "{file}"], 2, r"cost\.Q\[0\]\[0\]: .*magnitude"),
    ("W.H-1e308", problem(set_("W.H.0.0", 1e308)), ["run", "{file}"], 2, r"W\.H\[0\]\[0\]: .*magnitude"),
    ("cost.N-400-digits", problem(set_("cost.N", "BIG"), {"BIG": "9" * 400}), ["run", "{file}"], 2,
     r"cost\.N: expected an integer of at most 18 digits; received an integer of 400 digits"),
    ("json-nested-100000", text("p.json", NESTED), ["design", "{file}"], 2, r"nested at most 64 levels"),
    ("trajectory-nan-cost", traj(set_("records.10.cost", "NAN"), {"NAN": "NaN"}),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"records\[10\]\.cost: expected a finite"),
    ("trajectory-truncated-gzip",
     lambda f: text("t.json.gz", TRAJECTORY_DATA.read_bytes()[:3000])(f),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"expected a complete gzip file.*truncated"),
    ("run-seed-negative", problem(lambda d: None), ["run", "{file}", "--seed", "-1"], 2, r"'--seed'.*-1"),
    ("certify-huge-steps", problem(lambda d: None), ["certify", "{file}", "--steps", str(10**30), "--out",
                                                     "{folder}/out"], 2, r"'--steps'"),
    ("baseline-seeds-negative", problem(lambda d: None), ["baseline", "{file}", "--seeds", "-1"], 2, r"'--seeds'.*-1"),
    ("out-below-a-regular-file", files(t=good_traj, f=a_file),
     ["certify", "--trajectory", "{t}", "--out", "{f}/sub"], 2, r"'--out'.*lies below the file"),
    ("out-in-proc", files(t=good_traj), ["certify", "--trajectory", "{t}", "--out", "/proc/amcp-out"], 2,
     r"'--out'.*cannot create files in /proc"),
    ("campaign-store-is-a-directory", files(d=a_dir), ["campaign", "--systems", "1", "--store", "{d}"], 2,
     r"'--store'.*is a directory"),
    # ---- a large redundant input (not an error: the redundant rows are removed, with a note) --------
    ("W.H-5MB-redundant-rows", files(file=big_redundant_w), ["design", "{file}"], 0,
     r"note: W\.H: removed 220000 of 220004 rows implied by the others"),
    # ---- unknown trajectory versions -----------------------------------------------------------------
    ("trajectory-version-99", traj(set_("version", 99)), ["certify", "--trajectory", "{file}", "--out",
                                                        "{folder}/out"], 2, r"version: expected one of \[1\].*99"),
    # ---- misspelt keys, booleans as numbers, duplicate keys, sections of the wrong type ---------------
    ("typo-top-level-onlien", problem(set_("onlien", {"update": "none"})), ["run", "{file}"], 2,
     r"onlien: .*unknown key 'onlien'\. Did you mean 'online'\?"),
    ("typo-in-system", problem(set_("system.B1", [[0.0], [0.0]])), ["run", "{file}"], 2,
     r"system\.B1: .*unknown key 'B1'\. Did you mean '(B|B0)'\?"),
    ("typo-in-cost", problem(set_("cost.horizon", 20)), ["run", "{file}"], 2, r"cost\.horizon: .*unknown key"),
    ("typo-in-W", problem(set_("W.h", [1, 1, 1, 1])), ["run", "{file}"], 2, r"W\.h: .*unknown key 'h'"),
    ("typo-in-Theta", problem(set_("Theta.hh", [1.0])), ["run", "{file}"], 2,
     r"Theta\.hh: .*unknown key 'hh'\. Did you mean 'h'\?"),
    ("bool-in-cost.R", problem(set_("cost.R", [[True]])), ["run", "{file}"], 2,
     r"cost\.R\[0\]\[0\]: expected a number \(booleans are not numbers\); received true"),
    ("duplicate-keys", problem(set_("cost.N", "DUP"), {"DUP": '10, "N": 20'}), ["run", "{file}"], 2,
     r"cost\.N: expected each key once per JSON object"),
    ("design-is-5", problem(set_("design", 5)), ["run", "{file}"], 2,
     r"design: expected a JSON object or null; received 5"),
    # ---- problems too large for memory ----------------------------------------------------------------
    ("cost.N-1000000", problem(set_("cost.N", 1_000_000)), ["run", "{file}"], 2,
     r"problem size.*cost\.N = 1000000.*estimated memory [\d,.]+ GiB.*--max-memory"),
    ("cost.N-1000000-certify", problem(set_("cost.N", 1_000_000)), ["certify", "{file}", "--out", "{folder}/out"],
     2, r"problem size.*cost\.N = 1000000.*estimated memory"),
    # ---- zero or empty options, stale staging folders -------------------------------------------------
    ("run-steps-0", problem(lambda d: None), ["run", "{file}", "--steps", "0"], 2, r"'--steps'.*0 is not in the range"),
    ("certify-out-empty", files(t=good_traj), ["certify", "--trajectory", "{t}", "--out", ""], 2,
     r"'--out'.*empty string"),
    ("stale-staging-removed-on-exit-2", files(D=stale_staging, p=lambda f: text("p.json", "[1, 2")(f)["file"]),
     ["certify", "{p}", "--out", "{D}"], 2, r"valid JSON", no_stale_staging),

    # ==== our own: encodings ===========================================================================
    ("utf16-no-bom", text("p.json", json.dumps(example()).encode("utf-16-le")), ["design", "{file}"], 2, r"UTF-16 \(little-endian\) without byte-order mark"),
    ("utf32-bom", text("p.json", json.dumps(example()).encode("utf-32")), ["design", "{file}"], 2, r"UTF-32 \(little-endian"),
    ("latin1-name", lambda f: text("p.json", json.dumps(example()).replace(
        '"lorenzen2019"', '"Lorenzen–Cannon"').encode("cp1252"))(f),
     ["design", "{file}"], 2, r"p\.json: byte 0x96 at offset \d+ is not UTF-8"),
    ("gzip-problem-file", text("p.json", gzip.compress(json.dumps(example()).encode())), ["design", "{file}"], 2, r"p\.json contains NUL bytes \(binary data\)"),
    ("problem-is-a-directory", files(file=a_dir), ["design", "{file}"], 2, r"a-dir is a directory"),
    ("problem-path-empty", problem(lambda d: None), ["design", ""], 2, r"PROBLEM: .*empty string"),
    ("trajectory-utf16", lambda f: text("t.json", json.dumps(trajectory()).encode("utf-16"))(f), ["certify", "--trajectory", "{file}", "--out",
                                                           "{folder}/out"], 2, r"t\.json is UTF-16"),
    ("trajectory-corrupt-gzip", text("t.json.gz", b"\x1f\x8b\x08\x00" + b"garbage" * 50), ["certify", "--trajectory", "{file}", "--out", "{folder}/out"],
     2, r"expected (gzip-compressed JSON|a complete gzip file)"),
    # ==== numbers out of range =========================================================================
    ("nan-literal-in-Theta.h", problem(set_("Theta.h.0", "NAN"), {"NAN": "NaN"}), ["design", "{file}"], 2,
     r"Theta\.h\[0\]: expected a finite number \(NaN and Infinity are not JSON\)"),
    ("infinity-in-cost.Q", problem(set_("cost.Q.1.1", "INF"), {"INF": "Infinity"}), ["design", "{file}"], 2,
     r"cost\.Q\[1\]\[1\]: expected a finite number"),
    ("1e400-in-system.A0", problem(set_("system.A0.0.1", "BIG"), {"BIG": "1e400"}), ["design", "{file}"], 2,
     r"system\.A0\[0\]\[1\]: expected a finite number .*1e400"),
    ("-1e10-in-Z.F", problem(set_("Z.F.0.1", -1e10)), ["design", "{file}"], 2, r"Z\.F\[0\]\[1\]: .*magnitude"),
    ("1e10-in-theta_hat0", problem(set_("theta_hat0.2", 1e10)), ["design", "{file}"], 2,
     r"theta_hat0\[2\]: .*magnitude"),
    ("1e300-in-system.A.1", problem(set_("system.A.1.0.0", 1e300)), ["design", "{file}"], 2,
     r"system\.A\[1\]\[0\]\[0\]: .*magnitude"),
    ("1e300-in-design.K", problem(set_("design.K", [[1e300, 0.0]])), ["design", "{file}"], 2,
     r"design\.K\[0\]\[0\]: .*magnitude"),
    ("20-digit-seed", problem(set_("scenario.seed", "BIG"), {"BIG": "1" * 20}), ["design", "{file}"], 2,
     r"scenario\.seed: expected an integer of at most 18 digits"),
    ("cost.N-float", problem(set_("cost.N", 2.5)), ["design", "{file}"], 2, r"cost\.N: expected an integer; received 2\.5"),
    ("cost.N-true", problem(set_("cost.N", True)), ["design", "{file}"], 2,
     r"cost\.N: expected an integer \(booleans are not numbers\); received true"),
    ("cost.N-string", problem(set_("cost.N", "10")), ["design", "{file}"], 2, r"cost\.N: expected an integer; received \"10\""),
    ("scenario.steps-huge", problem(set_("scenario.steps", 10**9)), ["design", "{file}"], 2,
     r"scenario\.steps: expected a value <= 100000"),
    ("x0_facets-huge", problem(set_("design.x0_facets", 10**12)), ["design", "{file}"], 2,
     r"design size.*design\.x0_facets = 1000000000000 facets.*--max-memory"),
    ("d_theta-1e300", problem(set_("online", {"d_theta": 1e300})), ["design", "{file}"], 2,
     r"online\.d_theta: expected a value <= 1e\+09"),
    ("bool-in-theta_hat0", problem(set_("theta_hat0.1", False)), ["design", "{file}"], 2,
     r"theta_hat0\[1\]: expected a number \(booleans are not numbers\); received false"),
    ("bool-in-W.H", problem(set_("W.H.3.1", True)), ["design", "{file}"], 2, r"W\.H\[3\]\[1\]: .*booleans"),
    # ==== shapes and layout ============================================================================
    ("W.H-empty", problem(set_("W.H", [])), ["design", "{file}"], 2, r"W\.H: expected a list of at least 1 item"),
    ("W.H-row-empty", problem(set_("W.H.2", [])), ["design", "{file}"], 2, r"W\.H\[2\]: expected a list of at least 1"),
    ("W.H-row-is-number", problem(set_("W.H.1", 5)), ["design", "{file}"], 2, r"W\.H\[1\]: expected a list"),
    ("cost.Q-string-entry", problem(set_("cost.Q.0.1", "0")), ["design", "{file}"], 2,
     r"cost\.Q\[0\]\[1\]: expected a number; received \"0\""),
    ("version-true", problem(set_("version", True)), ["design", "{file}"], 2,
     r"version: expected 1 \(the only problem-file version this amcp reads\); received true"),
    ("version-1.0", problem(set_("version", 1.0)), ["design", "{file}"], 2,
     r"version: expected 1 \(the only problem-file version this amcp reads\); received 1\.0 \(a number\)"),
    ("Theta-is-list", problem(set_("Theta", [[1, 0, 0]])), ["design", "{file}"], 2,
     r"Theta: expected a JSON object; received \[\[1, 0, 0\]\]"),
    ("scenario-is-string", problem(set_("scenario", "default")), ["design", "{file}"], 2,
     r"scenario: expected a JSON object or null"),
    ("bool-in-scenario.x0", problem(set_("scenario.x0.0", True)), ["design", "{file}"], 2,
     r"scenario\.x0\[0\]: expected a number \(booleans are not numbers\); received true"),
    ("name-empty", problem(set_("name", "")), ["design", "{file}"], 2, r"name: expected a string of at least 1"),
    ("disturbance-gaussian", problem(set_("scenario.disturbance", "gaussian")), ["design", "{file}"], 2,
     r"scenario\.disturbance: expected one of \"uniform\", \"vertices\", \"zero\""),
    ("keep_redundant_rows-string", problem(set_("keep_redundant_rows", "yes")), ["design", "{file}"], 2,
     r"keep_redundant_rows: expected true or false"),
    ("design.centre_dynamics-typo", problem(set_("design.centre_dynamics", "nominl")), ["design", "{file}"], 2,
     r"design\.centre_dynamics: expected one of \"nominal\", \"zero\""),
    # ==== unknown keys (closest key suggested) =========================================================
    ("typo-system.A00", problem(set_("system.A00", [[1.0]])), ["design", "{file}"], 2,
     r"system\.A00: .*Did you mean 'A0'\?"),
    ("typo-scenario.sed", problem(set_("scenario.sed", 3)), ["design", "{file}"], 2,
     r"scenario\.sed: .*Did you mean 'seed'\?"),
    ("typo-online.updat", problem(set_("online", {"updat": "none"})), ["design", "{file}"], 2,
     r"online\.updat: .*Did you mean 'update'\?"),
    ("typo-design.x0_facet", problem(set_("design.x0_facet", 8)), ["design", "{file}"], 2,
     r"design\.x0_facet: .*Did you mean 'x0_facets'\?"),
    ("typo-Z.g", problem(set_("Z.g", [[0.0]])), ["design", "{file}"], 2, r"Z\.g: .*unknown key 'g'"),
    ("typo-theta_hat", problem(set_("theta_hat", [0, 0, 0])), ["design", "{file}"], 2,
     r"theta_hat: .*Did you mean 'theta_hat0'\?"),
    ("duplicate-key-nested", problem(set_("scenario.seed", "DUP"), {"DUP": '0, "seed": 1'}), ["design", "{file}"], 2,
     r"scenario\.seed: expected each key once"),
    ("duplicate-key-top", problem(set_("name", "DUP"), {"DUP": '"a", "name": "b"'}), ["design", "{file}"], 2,
     r"name: expected each key once"),
    # ==== options ======================================================================================
    ("run-every-0", problem(lambda d: None), ["run", "{file}", "--every", "0"], 2, r"'--every'.*0 is not in the range"),
    ("run-save-empty", problem(lambda d: None), ["run", "{file}", "--save", ""], 2, r"'--save'.*empty string"),
    ("run-save-below-file", files(file=lambda f: problem(lambda d: None)(f)["file"], f=a_file),
     ["run", "{file}", "--save", "{f}/t.json"], 2, r"'--save'.*lies below the file"),
    ("run-save-in-proc", problem(lambda d: None), ["run", "{file}", "--save", "/proc/amcp/t.json"], 2,
     r"'--save'.*cannot create files in /proc"),
    ("run-steps-huge", problem(lambda d: None), ["run", "{file}", "--steps", str(10**9)], 2, r"'--steps'"),
    ("run-seed-2**64", problem(lambda d: None), ["run", "{file}", "--seed", str(2**64)], 2, r"'--seed'"),
    ("run-max-memory-tiny", problem(lambda d: None), ["run", "{file}", "--max-memory", "1"], 2,
     r"problem size.*estimated memory [\d.]+ MiB.*--max-memory"),
    ("compare-out-is-a-directory", files(file=lambda f: problem(lambda d: None)(f)["file"], d=a_dir),
     ["compare", "{file}", "--out", "{d}"], 2, r"'--out'.*is a directory"),
    ("compare-steps-0", problem(lambda d: None), ["compare", "{file}", "--steps", "0"], 2, r"'--steps'"),
    ("compare-seed-negative", problem(lambda d: None), ["compare", "{file}", "--seed", "-3"], 2, r"'--seed'"),
    ("certify-seed-2**70", problem(lambda d: None), ["certify", "{file}", "--seed", str(2**70), "--out",
                                                     "{folder}/out"], 2, r"'--seed'"),
    ("certify-out-deep-below-file", files(t=good_traj, f=a_file),
     ["certify", "--trajectory", "{t}", "--out", "{f}/a/b/c"], 2, r"'--out'.*lies below the file"),
    ("baseline-seeds-billion", problem(lambda d: None), ["baseline", "{file}", "--seeds", str(10**9)], 2, r"'--seeds'"),
    ("baseline-grid-1", problem(lambda d: None), ["baseline", "{file}", "--grid", "1"], 2, r"'--grid'"),
    ("baseline-steps-0", problem(lambda d: None), ["baseline", "{file}", "--steps", "0"], 2, r"'--steps'"),
    ("bool-design.mu_state_bound", problem(set_("design.mu_state_bound", True)), ["design", "{file}"], 2,
     r"design\.mu_state_bound: expected a number or null \(booleans are not numbers\); received true"),
    ("pe-figure-steps-huge", files(), ["pe-figure", "--steps", str(10**12)], 2, r"'--steps'"),
    ("campaign-store-empty", files(), ["campaign", "--systems", "1", "--store", ""], 2, r"'--store'.*empty string"),
    ("campaign-store-below-file", files(f=a_file), ["campaign", "--systems", "1", "--store", "{f}/s.sqlite"], 2,
     r"'--store'.*lies below the file"),
    ("campaign-report-is-a-directory", files(d=a_dir, s=a_file), ["campaign", "--store", "{s}", "--report", "{d}"],
     2, r"'--report'.*is a directory"),
    # ==== trajectories =================================================================================
    ("trajectory-version-string", traj(set_("version", "1")), ["certify", "--trajectory", "{file}", "--out",
                                                             "{folder}/out"], 2, r"version: expected one of \[1\]"),
    ("trajectory-version-missing", traj(delete("version")), ["certify", "--trajectory", "{file}", "--out",
                                                            "{folder}/out"], 2, r"version: expected one of \[1\].*null"),
    ("trajectory-version-1.0", traj(set_("version", 1.0)), ["certify", "--trajectory", "{file}", "--out",
                                                           "{folder}/out"], 2, r"version: expected one of \[1\].*1\.0"),
    ("trajectory-problem-version-1.0", traj(set_("problem.version", 1.0)),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"problem\.version: expected 1 .*received 1\.0"),
    ("trajectory-record-k-1.0", traj(set_("records.1.k", 1.0)),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"records\[1\]\.k: expected an integer"),
    ("trajectory-meta-seed-0.0", traj(set_("meta.seed", 0.0)),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"meta\.seed: expected an integer or null"),
    ("trajectory-backend-bogus", traj(set_("backend", "bogus")), ["certify", "--trajectory", "{file}", "--out",
                                                                "{folder}/out"], 2,
     r"backend: expected one of \"cvxpy\", \"drake\"; received \"bogus\""),
    ("trajectory-answer-check-1MB", traj(set_("records.1.answers", [{"problem": "tube_qp", "outcome": "first",
                                                                      "kind": "", "check": "c" * 1_000_000}])),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2,
     r"records\[1\]\.answers\[0\]\.check: expected a string of at most 200 characters; received \"c{56}\.\.\., "
     r"1,000,000 characters"),
    ("trajectory-design-backend-bogus", traj(set_("design.backend", "bogus")),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"design\.backend: expected one of \"cvxpy\""),
    ("trajectory-infinity-x", traj(set_("x.3.1", "INF"), {"INF": "-Infinity"}),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"x\[3\]\[1\]: expected a finite number"),
    ("trajectory-duplicate-key", traj(set_("backend", "DUP"), {"DUP": '"drake", "backend": "cvxpy"'}),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"backend: expected each key once"),
    ("trajectory-records-not-list", traj(set_("records", {"0": 1})), ["certify", "--trajectory", "{file}", "--out",
                                                                     "{folder}/out"], 2, r"records: expected a list"),
    ("trajectory-problem-unknown-key", traj(set_("problem.cost.horizon", 3)),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"problem\.cost\.horizon: .*unknown key"),
    ("trajectory-missing-x", traj(delete("x")), ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2,
     r"x: expected a value; received nothing \(key missing\)"),
    ("trajectory-nested-deep", text("t.json", '{"format": "amcp-trajectory", "meta": ' + NESTED + "}"),
     ["certify", "--trajectory", "{file}", "--out", "{folder}/out"], 2, r"nested at most 64 levels"),
]

def _snapshot(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


@pytest.mark.parametrize("row", ROWS, ids=[row[0] for row in ROWS])
def test_bad_input(row, tmp_path, monkeypatch):
    case, build, args, code, pattern, *after = row
    folder = tmp_path / "in"
    folder.mkdir()
    names = {"folder": str(folder), **{k: str(v) for k, v in build(folder).items()}}
    argv = [a.format(**names) for a in args]
    monkeypatch.chdir(folder)  # relative defaults (amcp-out, amcp-campaign.sqlite) land here and are seen
    before = _snapshot(folder)
    result = CliRunner().invoke(main, argv)
    output = result.output  # stdout and stderr (click >= 8.2)
    assert result.exit_code == code, f"{case}: exit {result.exit_code}\n{output}\n{result.exception!r}"
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    assert "Traceback" not in output
    assert re.search(pattern, output, re.DOTALL), f"{case}: {pattern!r} not in\n{output}"
    created = _snapshot(folder) - before
    assert not created, f"{case}: wrote {sorted(created)}"  # nothing written, not even half a file
    for check in after:
        check(folder)


def test_table_size():
    """The table holds the required cases and at least 40 more (from utf16-no-bom on)."""
    ours = ROWS[[r[0] for r in ROWS].index("utf16-no-bom"):]
    assert len(ours) >= 40


# -- not through the CLI: writing, and live staging folders ------------------------------------------
def test_nan_in_a_record_is_refused_on_write_naming_the_field_and_writing_nothing(tmp_path):
    from amcp_drake.model.errors import TrajectoryError
    from amcp_drake.online.simulate import Trajectory

    loaded = Trajectory.load(TRAJECTORY_DATA)
    loaded.records[10].cost = float("nan")
    for name in ("t.json.gz", "t.json"):
        with pytest.raises(TrajectoryError, match=r"records\[10\]\.cost: expected a finite number"):
            loaded.save(tmp_path / name)
    assert list(tmp_path.iterdir()) == []


def test_staging_folder_of_a_live_writer_is_kept_and_removed_once_it_dies(tmp_path):
    """remove_stale_staging removes a staging folder only when no process holds its lock: a child
    process holds it (kept), then is killed (SIGKILL: no handler runs) and the folder goes."""
    import subprocess
    import sys

    from amcp_drake.certificate.report import remove_stale_staging

    live = tmp_path / STALE
    live.mkdir()
    (live / ".lock").write_text("")
    holder = subprocess.Popen([sys.executable, "-c", (
        "import fcntl, sys, time; h = open(sys.argv[1], 'rb'); fcntl.flock(h, fcntl.LOCK_EX); "
        "print('locked', flush=True); time.sleep(600)"), str(live / ".lock")], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert remove_stale_staging(tmp_path) == []
        assert live.is_dir()
    finally:
        holder.kill()
        holder.wait()
    assert remove_stale_staging(tmp_path) == [live]
    assert not live.exists()


def test_schema_bound_equals_the_validators_bound_and_sections_match_the_dataclasses():
    """data/problem.schema.json and the Python validators agree: the entry bound, and the keys of
    design, scenario and online (a field added to a dataclass must be added to the schema)."""
    from dataclasses import fields

    from amcp_drake.model.options import OnlineOptions
    from amcp_drake.model.problem import DesignOptions, Scenario
    from amcp_drake.model.problem_io import problem_schema
    from amcp_drake.model.validate import MAX_ABS_ENTRY

    schema = problem_schema()
    assert schema["$defs"]["entry"]["maximum"] == MAX_ABS_ENTRY == -schema["$defs"]["entry"]["minimum"]
    props = schema["properties"]
    for key, cls in (("design", DesignOptions), ("scenario", Scenario), ("online", OnlineOptions)):
        section = props[key]["anyOf"][0]["properties"]
        assert set(section) == {f.name for f in fields(cls)}, key


def test_files_written_by_amcp_load_back_unchanged(tmp_path, example_spec):
    """save_spec writes keep_redundant_rows: true, so a problem with redundant rows (as the campaign
    generators draw them) is read back with the same rows; a hand-written file is reduced."""
    from amcp_drake.model.problem_io import load_spec, save_spec

    pr = example_spec.problem
    redundant = pr.with_changes(H_w=np.vstack([pr.H_w, [[1.0, 1.0]]]))
    path = save_spec(dataclasses.replace(example_spec, problem=redundant), tmp_path / "p.json")
    again = load_spec(path)
    assert again.notes == () and np.array_equal(again.problem.H_w, redundant.H_w)
    data = json.loads(path.read_text())
    del data["keep_redundant_rows"]
    path.write_text(json.dumps(data))
    reduced = load_spec(path)
    assert np.array_equal(reduced.problem.H_w, pr.H_w)
    expected = ('W.H: removed 1 of 5 rows implied by the others (rows 4); 4 kept '
                '("keep_redundant_rows": true keeps every row)')
    assert reduced.notes == (expected,)


def test_a_killed_certify_leaves_a_staging_folder_that_the_next_run_removes(tmp_path):
    """SIGKILL ``amcp certify`` while it writes its bundle into a new D (once its staging folder holds
    the writer's lock file): D holds only the staging folder; the next ``amcp certify`` into D (here one
    that exits 2 on a bad problem) removes it. A folder killed in the instant between its creation and
    its lock file is left for STAGING_UNLOCKED_GRACE_S (certificate/report.py), not tested here."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "D"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    proc = subprocess.Popen([sys.executable, "-m", "amcp_drake", "certify", "--trajectory", str(TRAJECTORY_DATA),
                             "--out", str(out)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + GUARD_SECONDS
        while not list(out.glob(".certify-staging-*/.lock")):
            assert proc.poll() is None, "certify ended before its staging folder was seen"
            assert time.monotonic() < deadline
            time.sleep(0.005)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    left = [p.name for p in out.iterdir()]
    assert len(left) == 1 and left[0].startswith(".certify-staging-"), left
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2")
    result = CliRunner().invoke(main, ["certify", str(bad), "--out", str(out)])
    assert result.exit_code == 2, result.output
    assert list(out.iterdir()) == []
