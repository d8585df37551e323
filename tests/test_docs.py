"""The documentation speaks of the software and points into the repository.

* README.md stays short (under 100 lines) with exactly one Python block, the tested one of
  docs/api-snippet.md;
* README.md, docs/, benchmarks/, the CLI's help texts, the Python sources and the tests name no
  "session N", "issue N" or section of the spec file, which is not in the repository (the paper's
  mathematics is in docs/explanation/paper.md);
* every repository path they name exists;
* every decision of docs/decisions.md has a context, a decision and a consequence;
* the text escapes of the documentation site (tools/plain_math.py, used by tools/mkdocs_hooks.py)
  turn the stars of θ* and the bars of X_{l|k} in table rows into literal characters, and nothing else.

`make docs` builds the site itself with warnings as errors; these checks run without MkDocs.
"""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC_FILES = sorted([ROOT / "README.md", ROOT / "benchmarks" / "README.md", *(ROOT / "docs").rglob("*.md")])
CLI_FILES = sorted((ROOT / "amcp_drake" / "cli").glob("*.py"))
#: The Python sources (comments, docstrings, messages) name no "session N" or "issue N" either.
SOURCE_FILES = sorted(path for root in ("amcp_drake", "reference", "properties") for path in (ROOT / root).rglob("*.py")
                      if path not in CLI_FILES)
#: Nor do the tests (their data files under tests/data are recorded data, not text) and the benchmarks'
#: scripts and recorded results (the JSON and images excepted).
TEST_FILES = sorted((ROOT / "tests").glob("*.py"))
BENCHMARK_FILES = sorted(path for path in (ROOT / "benchmarks").rglob("*")
                         if path.suffix in (".py", ".md", ".txt") and path not in DOC_FILES)
#: "session" or "issue" (also plural) before a number, and "spec" before a section sign (written in
#: brackets so that this line does not match itself)
HISTORY = re.compile(r"sessions? [0-9]|issues? [0-9]+|spec [§]", re.IGNORECASE)
#: a path into the repository named in the text (placeholders such as NAME or <x> are not paths)
REPO_PATH = re.compile(r"(?<![\w/.-])((?:amcp_drake|reference|properties|tests|benchmarks|examples|docs|tools)/[\w./*-]+)")


def _plain_math():
    spec = importlib.util.spec_from_file_location("plain_math", ROOT / "tools" / "plain_math.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(encoding="utf-8"), flags=re.S)


def test_the_readme_is_short_and_its_python_snippet_is_the_tested_one():
    """The README's one Python block is docs/api-snippet.md's, which tests/test_api_verdict.py runs
    against `amcp certify`."""
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) < 100
    blocks = _python_blocks(ROOT / "README.md")
    assert len(blocks) == 1
    assert blocks == _python_blocks(ROOT / "docs" / "api-snippet.md")


@pytest.mark.parametrize("path", DOC_FILES + CLI_FILES + SOURCE_FILES + TEST_FILES + BENCHMARK_FILES,
                         ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history_in_the_docs_the_help_texts_and_the_code(path):
    lines = [f"{i}: {line}" for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if HISTORY.search(line)]
    assert lines == [], "history belongs in CHANGELOG.md:\n" + "\n".join(lines)


@pytest.mark.parametrize("path", DOC_FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_repository_path_named_in_the_docs_exists(path):
    missing = []
    for match in REPO_PATH.finditer(path.read_text(encoding="utf-8")):
        name = match.group(1).rstrip(".,;:)")
        if "..." in name or "NAME" in name:
            continue
        exists = any(ROOT.glob(name)) if "*" in name else (ROOT / name).exists()
        if not exists:
            missing.append(name)
    assert missing == []


def test_every_decision_has_context_decision_and_consequence():
    text = (ROOT / "docs" / "decisions.md").read_text(encoding="utf-8")
    entries = re.split(r"^### ", text, flags=re.M)[1:]
    assert len(entries) >= 30
    incomplete = [entry.splitlines()[0] for entry in entries
                  if not all(re.search(rf"\*\*{word}[.:]?\*\*", entry) for word in ("Context", "Decision", "Consequence"))]
    assert incomplete == []
    assert "\n## Additional decisions" in text, "the tail heading where new decisions are appended"


def test_plain_math_escapes_symbol_stars_and_nothing_else():
    pm = _plain_math()
    assert pm.escape_symbol_stars("θ* ∈ Θ_k, A(θ*) x, v*_{0|k}, θ̂*") == r"θ\* ∈ Θ_k, A(θ\*) x, v\*_{0|k}, θ̂\*"
    for unchanged in ("*emphasis* of words", "**bold**", "`θ*` in code", "x ** 2"):
        assert pm.escape_symbol_stars(unchanged) == unchanged


def test_plain_math_escapes_subscript_bars_in_table_rows_outside_code():
    pm = _plain_math()
    row = "| `tube` | x_k ∈ X_{0|k} and X_{l+1|k} | `{a|b}` | min |"
    assert pm.escape_subscript_bars(row) == r"| `tube` | x_k ∈ X_{0\|k} and X_{l+1\|k} | `{a|b}` | min |"
    assert pm.escape_subscript_bars(r"| X_{0\|k} |") == r"| X_{0\|k} |"  # already escaped: unchanged


EXIT_CODE_PAGES = [ROOT / "README.md", ROOT / "docs" / "getting-started.md", ROOT / "docs" / "reference" / "cli.md",
                   ROOT / "docs" / "certificate.md"]


@pytest.mark.parametrize("path", EXIT_CODE_PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_page_that_lists_exit_codes_lists_all_four(path):
    """The CLI's exit codes (cli/common.py) are 0, 1, 2 and 3 (certify's premise not met); a page that
    explains them names each one with its meaning."""
    from amcp_drake.cli import common

    text = " ".join(path.read_text(encoding="utf-8").split())
    assert common.EXIT_PREMISE_NOT_MET == 3
    for code, word in [(0, "claim"), (1, "fail"), (2, "bad"), (3, "premise")]:
        assert re.search(rf"(\b{code}\b.{{0,80}}{word})|({word}.{{0,80}}\b{code}\b)", text, re.IGNORECASE), \
            f"{path.name} does not explain exit code {code}"


def test_license_and_citation_files_exist_and_agree_with_the_project_metadata():
    """LICENSE holds the licence pyproject.toml declares; CITATION.cff names the paper's DOI and the version."""
    import tomllib

    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert meta["license"] == "BSD-3-Clause"
    assert "BSD 3-Clause License" in (ROOT / "LICENSE").read_text(encoding="utf-8")
    cff = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert f"version: {meta['version']}" in cff
    assert "doi: 10.1016/j.automatica.2019.02.023" in cff
