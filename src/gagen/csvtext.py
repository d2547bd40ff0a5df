"""Text in the CSV files gagen writes and reads (no SymPy, no NumPy).

A spreadsheet opening a CSV treats a cell that starts with `=`, `+`, `-` or `@` (and, in
some, a tab or a carriage return) as a formula: a joint named `=HYPERLINK(...)` in a
description would run in a user's spreadsheet ("CSV injection"). So every text cell gagen
writes (names from a description, expressions in them) goes through `text_cell`, which
puts an apostrophe in front of such a cell, as spreadsheets expect: they show the text,
and hide the apostrophe. Numbers are written as numbers (a negative number stays `-1.5`).
`read_name` undoes `text_cell`, so gagen reads back the names it wrote.
"""

from __future__ import annotations

FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
_ESCAPE = "'"


def text_cell(text: str) -> str:
    """`text` as a CSV cell a spreadsheet shows as text (an apostrophe before a formula's
    first character; also before an apostrophe that `read_name` would take away)."""
    if text.startswith(FORMULA_STARTS) or (
            text.startswith(_ESCAPE) and text[1:2].startswith(FORMULA_STARTS + (_ESCAPE,))):
        return _ESCAPE + text
    return text


def read_name(cell: str) -> str:
    """The text of a cell `text_cell` wrote (other cells are returned as they are)."""
    if cell.startswith(_ESCAPE) and cell[1:2] and cell[1:2].startswith(
            FORMULA_STARTS + (_ESCAPE,)):
        return cell[1:]
    return cell
