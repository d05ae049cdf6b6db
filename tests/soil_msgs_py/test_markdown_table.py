"""Markdown tables keep their columns whatever their cells hold: a '|' in a cell (|F|, a formula's
|v_z|, a user's soil name) is escaped, and every table the repository carries is checked the way a
GitHub-flavoured markdown reader splits it."""
from __future__ import annotations

from pathlib import Path

from soil_msgs_py.markdown_table import cell, cells_of, header, malformed_rows, row

REPO = Path(__file__).resolve().parents[2]


def test_a_cell_holding_pipes_or_line_breaks_stays_one_cell():
    values = ["PINN force error, % of measured |F|", 6.33, r"already \|escaped\|", "two\nlines", "F = k · [|v_z| ≤ 0.005 m/s]"]
    line = row(values)
    assert len(cells_of(line)) == len(values)
    assert cells_of(line)[0] == r"PINN force error, % of measured \|F\|"
    assert cells_of(line)[2] == r"already \|escaped\|"  # not escaped twice
    assert cells_of(line)[3] == "two lines"
    assert cell(cell("|F|")) == cell("|F|") == r"\|F\|"
    assert malformed_rows("\n".join([*header(["target", "|F| [N]", "met"]), row(["|F| at 0.1 m", 1, "yes"])])) == []


def test_a_row_cut_by_a_pipe_and_a_header_wider_than_its_delimiter_are_found_outside_code_fences():
    text = "\n".join([
        "| target | value | met |", "|---|---|---|",
        "| force error, % of |F| | 6.3 | yes |",      # 5 cells: a reader shows 'F' as the value
        "| fine | 1 | yes |",
        "",
        "| soil | |F| at 0.1 m |", "|---|---|",       # a header of 4 cells over a delimiter of 2: no table
        "| Sand | 2.3 |",
        "",
        "```", "| a | b |", "|---|", "| c | d | e |", "```",   # code, not a table
    ])
    assert malformed_rows(text) == [(3, 5, 3), (7, 2, 4), (8, 2, 4)]
    # as GitHub-flavoured markdown finds tables: in a block quote, without the outer pipes, up to a
    # blank line; not inside a longer fence that holds a shorter one, nor in indented code
    more = "\n".join(["> | a | b |", "> |---|---|", "> | c | d | e |", "", "a | b", "--|--", "c | d | e", "",
                      "````", "```", "| x | y |", "|---|", "| p |", "````", "", "    | a | b |", "    |---|", "    | c |"])
    assert malformed_rows(more) == [(3, 3, 2), (7, 3, 2)]
    # a fence, a heading or the end of a block quote right after a table ends it (a reviewer's: the fence
    # had been read as a row and never opened, and its close hid the rest of the text)
    after = "\n".join(["| a | b |", "|---|---|", "| c | d |", "```", "", "| not | a | row |", "```", "# next",
                       "> | a | b |", "> |---|---|", "plain text after the quote", "",
                       "| a | b |", "|---|---|", "| short |"])
    assert malformed_rows(after) == [(15, 1, 2)]


def test_every_markdown_table_in_the_repository_keeps_its_columns():
    files = [p for p in REPO.rglob("*.md")
             if not any(part.startswith(".") or part in ("build", "install", "log", "out") for part in p.relative_to(REPO).parts)]
    assert len(files) > 10
    bad = {str(p.relative_to(REPO)): rows for p in files if (rows := malformed_rows(p.read_text()))}
    assert not bad, f"table rows whose cell count is not their header's (line, cells, header's): {bad}"
