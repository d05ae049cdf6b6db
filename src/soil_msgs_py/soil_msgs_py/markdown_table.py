"""Markdown tables whose cells may hold any text. GitHub-flavoured markdown splits a row at every
unescaped '|', inside code spans too, so a cell holding |F|, a formula's |v_z| or a user's soil
name with a pipe becomes extra columns: the content after it is dropped, and a header row with
more cells than its delimiter row is no table at all. A table whose cells may hold text (names,
labels, formulas, a user's soils and groups) is written with ``row`` (or ``cell`` for one value
set into a row of fixed text)."""
from __future__ import annotations

import re
from typing import Iterable

_UNESCAPED_PIPE = re.compile(r"(?<!\\)\|")


def cell(value) -> str:
    """``value`` as one table cell: its pipes escaped (an escaped one left as it is), line breaks
    as spaces (a row is one line)."""
    text = " ".join(str(value).splitlines())
    return _UNESCAPED_PIPE.sub(r"\\|", text)


def row(values: Iterable) -> str:
    """One table row: ``| a | b |``, each value a ``cell``."""
    return "| " + " | ".join(cell(v) for v in values) + " |"


def header(names: Iterable) -> list[str]:
    """A table's header row and its delimiter row."""
    names = list(names)
    return [row(names), "|" + "---|" * len(names)]


def cells_of(line: str) -> list[str]:
    """The cells a GitHub-flavoured markdown reader sees in a table row (split at unescaped pipes,
    the outer ones optional): the check that a row holds as many cells as its header."""
    text = line.strip()
    text = text[1:] if text.startswith("|") else text
    text = text[:-1] if text.endswith("|") and not text.endswith("\\|") else text
    return [c.strip() for c in _UNESCAPED_PIPE.split(text)]


_DELIMITER = re.compile(r"^\s*\|?\s*:?-+:?\s*(\|\s*:?-+:?\s*)*\|?\s*$")


def malformed_rows(text: str) -> list[tuple[int, int, int]]:
    """(line number, cells, header's cells) of every table row in ``text`` (outside code fences)
    whose cell count is not its header's: the rows a reader shows cut short or padded, or, for a
    delimiter row that differs from its header, a table that is not drawn at all."""
    lines, out, fenced, i = text.splitlines(), [], False, 0
    while i < len(lines):
        if lines[i].lstrip().startswith("```"):
            fenced = not fenced
        elif (not fenced and lines[i].lstrip().startswith("|") and i + 1 < len(lines)
              and _DELIMITER.match(lines[i + 1])):
            width = len(cells_of(lines[i]))
            i += 1
            while i < len(lines) and lines[i].lstrip().startswith("|"):
                if len(cells_of(lines[i])) != width:
                    out.append((i + 1, len(cells_of(lines[i])), width))
                i += 1
            continue
        i += 1
    return out
