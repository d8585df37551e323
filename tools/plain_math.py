"""Plain-text mathematics in Markdown: the escapes the documentation site applies to every page and
docstring (``tools/mkdocs_hooks.py``). Pure text functions, tested in ``tests/test_docs.py``."""

from __future__ import annotations

import re

#: a star that follows a symbol (a Greek letter, a one-letter Latin symbol, a combining accent, the
#: closing brace of a subscript) and is not followed by a letter or a star: θ*, θ*_k, A(θ*), v*_{0|k};
#: the star that closes *emphasis* follows a word of two or more letters and is left alone
SYMBOL_STAR = re.compile(r"(?:(?<=[Α-Ωα-ω\u0300-\u036f}])|(?<=\b[A-Za-z]))\*(?![A-Za-z*])")
CODE_SPAN = re.compile(r"(`+)(?:.+?)\1")
#: a subscript in braces that holds an unescaped bar: {l|k}, {0|k}, {l+1|k}
SUBSCRIPT_BAR = re.compile(r"\{[^{}|`]*(?<!\\)\|[^{}`]*\}")


def outside_code(line: str, fix) -> str:
    """``line`` with ``fix`` applied to the text outside its code spans."""
    out, pos = [], 0
    for match in CODE_SPAN.finditer(line):
        out.append(fix(line[pos:match.start()]))
        out.append(match.group(0))
        pos = match.end()
    out.append(fix(line[pos:]))
    return "".join(out)


def escape_symbol_stars(line: str) -> str:
    """``line`` with the stars of SYMBOL_STAR escaped outside code spans."""
    return outside_code(line, lambda text: SYMBOL_STAR.sub(r"\\*", text))


def escape_subscript_bars(line: str) -> str:
    """A table row ``line`` with the bars inside subscript braces escaped (``{l\\|k}``), outside code."""
    return outside_code(line, lambda text: SUBSCRIPT_BAR.sub(
        lambda m: re.sub(r"(?<!\\)\|", r"\\|", m.group(0)), text))
