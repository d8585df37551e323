"""MkDocs hook of the documentation site (mkdocs.yml, ``hooks``): mathematics written as plain text.

The pages and docstrings write subscripts and optimal values as plain text (x_k, Θ_k, [H_x]_i,
θ*, v*_{0|k}). Markdown would read a pair of underscores, or a star after a symbol, as the start of
emphasis and turn the text between into italics. This hook adds one Markdown extension to every
conversion (the pages and the API pages of mkdocstrings):

* underscores never mark emphasis (``_em_`` is not used in these docs; ``*em*`` and ``**bold**`` are);
* a star right after a mathematical symbol (θ*, θ̂*, v*, x*, Λ*, ...) and not followed by a letter or
  another star is a literal star;
* in a table row, the bar of a subscript (X_{l|k}, v*_{0|k}) is part of the cell, not a column break.

Code spans and fenced code are left as they are.
"""

from __future__ import annotations

import sys
from pathlib import Path

from markdown import Markdown
from markdown.extensions import Extension
from markdown.preprocessors import Preprocessor

sys.path.insert(0, str(Path(__file__).resolve().parent))
from plain_math import escape_subscript_bars, escape_symbol_stars  # the folder is on the path now


class SymbolStars(Preprocessor):
    """Escape the stars of mathematical symbols, and the subscript bars of table rows (after fenced
    code has been set aside)."""

    def run(self, lines: list[str]) -> list[str]:
        out = []
        for line in lines:
            line = escape_symbol_stars(line)
            if line.lstrip().startswith("|"):
                line = escape_subscript_bars(line)
            out.append(line)
        return out


class PlainMathText(Extension):
    """Underscores never mark emphasis; stars after symbols are literal."""

    def extendMarkdown(self, md: Markdown) -> None:  # noqa: N802 - the name Markdown calls
        delimiters = getattr(md, "delimiters", None)
        if delimiters is not None:  # Python-Markdown with delimiter runs: "_" is one delimiter
            delimiters.remove("_")
        if "em_strong2" in md.inlinePatterns:  # earlier Python-Markdown: the underscore pattern
            md.inlinePatterns.deregister("em_strong2")
        md.preprocessors.register(SymbolStars(md), "amcp_symbol_stars", 5)


def on_config(config):
    """Add the extension after the configured ones (MkDocs calls this with the validated config)."""
    config.markdown_extensions.append(PlainMathText())
    return config
