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
    """``value`` as one table cell: its pipes escaped (an escaped one left as it is, so a text's own
    backslash before a pipe reads as the escape), line breaks as spaces (a row is one line). Set
    into a row with a space before each delimiter, as ``row`` does: a cell ending in a backslash
    would otherwise escape the delimiter after it."""
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
_FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})")
_QUOTE = re.compile(r"^ {0,3}(> ?)+")
_OTHER_BLOCK = re.compile(r"^ {0,3}(#{1,6}(\s|$)|(\*\s*){3,}$|(_\s*){3,}$|(-\s*){3,}$)")  # a heading, a break


def malformed_rows(text: str) -> list[tuple[int, int, int]]:
    """(line number, cells, header's cells) of every table row in ``text`` whose cell count is not
    its header's: the rows a reader shows cut short or padded, or, for a delimiter row that differs
    from its header, a table that is not drawn at all. As GitHub-flavoured markdown finds tables: a
    line with a pipe over a delimiter row, the outer pipes optional, its rows every line up to a
    blank one or another block (a fence, a heading, a break, the end of its block quote), inside a
    block quote too; not in fenced (``` or ~~~) or indented code."""
    lines, out, fence, i = text.splitlines(), [], None, 0
    while i < len(lines):
        line = lines[i]
        if fence:
            mark = _FENCE.match(line)
            if mark and mark.group(1)[0] == fence[0] and len(mark.group(1)) >= len(fence) \
                    and not line.strip().strip(fence[0]):
                fence = None
            i += 1
            continue
        if mark := _FENCE.match(line):
            fence = mark.group(1)
            i += 1
            continue
        quote = _QUOTE.match(line)
        body = line[quote.end():] if quote else line
        below = lines[i + 1][quote.end():] if quote and i + 1 < len(lines) else (lines[i + 1] if i + 1 < len(lines) else "")
        if not body.startswith("    ") and "|" in body and _DELIMITER.match(below) and "-" in below:
            width = len(cells_of(body))
            i += 1
            prefix = quote.group(0) if quote else ""
            while i < len(lines):
                here = _QUOTE.match(lines[i])
                if (here.group(0) if here else "") != prefix:  # the block quote ends, or one begins
                    break
                row = lines[i][len(prefix):]
                if not row.strip() or _FENCE.match(row) or _OTHER_BLOCK.match(row):  # another block begins
                    break
                if len(cells_of(row)) != width:
                    out.append((i + 1, len(cells_of(row)), width))
                i += 1
            continue
        i += 1
    return out
