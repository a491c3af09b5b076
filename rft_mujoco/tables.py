"""Every table the package prints, drawn in one place: aligned plain-text columns under a rule.

::

    shape     elements  max err %
    --------  --------  ---------
    sphere         412       1.93

:func:`table` draws a whole table from its rows; :class:`Columns` draws a table whose rows arrive one at
a time during a long run (fixed widths, so each row can be printed as soon as it is measured). Callers
format their numbers (each knows its precision) and pass strings or anything ``str()`` renders.

With the environment variable ``RFT_MUJOCO_TABLES=markdown`` every table is printed as a markdown pipe
table instead, to paste into a page (``RFT_MUJOCO_TABLES=markdown python -m rft_mujoco bench``)::

    | shape  | elements | max err % |
    |:-------|---------:|----------:|
    | sphere |      412 |      1.93 |

Why not ``rich``: the core library (``rft_mujoco.describe``/``summary``, the studies) depends on numpy and
MuJoCo only, and rich is in the ``train`` extra; several studies print rows as they are measured
(minutes apart), which rich's ``Table`` cannot do (it measures every row before drawing); and rich
fits a table to the console, 80 columns when the output is a file or a pipe: an 8-column table of
numbers piped through ``cat`` came out (rich 15.0, this machine) with its titles wrapped over three lines
and its numbers cut with an ellipsis (``1234.5…``), in the logs that the docs quote. This module is the
one formatter instead.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence

GAP = "  "
"""Between two columns (plain style)."""

LEFT, RIGHT = "<", ">"

STYLE_VARIABLE = "RFT_MUJOCO_TABLES"
"""The environment variable that chooses the style of every table: ``plain`` (default) or ``markdown``."""
STYLES = ("plain", "markdown")


def style() -> str:
    """The style tables are drawn in now: :data:`STYLE_VARIABLE`, ``plain`` when unset."""
    value = os.environ.get(STYLE_VARIABLE, "plain").strip().lower() or "plain"
    if value not in STYLES:
        raise ValueError(f"{STYLE_VARIABLE} must be one of {', '.join(STYLES)}, got {value!r}")
    return value


def _line(cells: Sequence[str], widths: Sequence[int], align: str) -> str:
    """One line: each cell padded to its column's width, aligned as ``align`` says."""
    padded = [c.ljust(w) if a == LEFT else c.rjust(w) for c, w, a in zip(cells, widths, align)]
    if style() == "markdown":
        return "| " + " | ".join(p.replace("|", "\\|") for p in padded) + " |"
    return GAP.join(padded).rstrip()


def _rule(widths: Sequence[int], align: str) -> str:
    """The line under the titles: dashes as wide as each column (markdown: with its alignment)."""
    if style() == "markdown":
        return "|" + "|".join(":" + "-" * (w + 1) if a == LEFT else "-" * (w + 1) + ":"
                              for w, a in zip(widths, align)) + "|"
    return _line(["-" * w for w in widths], widths, align)


def _align(align: str | None, n: int) -> str:
    """``align`` checked for ``n`` columns; default: the first column left, the others right (numbers)."""
    if align is None:
        return LEFT + RIGHT * (n - 1)
    if len(align) != n or set(align) - {LEFT, RIGHT}:
        raise ValueError(f"align must be one '<' (left) or '>' (right) per column ({n}), got {align!r}")
    return align


class Columns:
    """A table with fixed column widths, for rows printed as they come.

    Args:
        headers: the column titles.
        widths: each column's width in characters, at least its title's (default: the titles' widths);
            a longer cell widens its own line only.
        align: one ``'<'`` (left) or ``'>'`` (right) per column; default: first left, others right.
    """

    def __init__(self, headers: Sequence[object], widths: Sequence[int] | None = None, align: str | None = None):
        self.headers = [str(h) for h in headers]
        if not self.headers:
            raise ValueError("a table needs at least one column, got no headers")
        n = len(self.headers)
        widths = [len(h) for h in self.headers] if widths is None else [int(w) for w in widths]
        if len(widths) != n:
            raise ValueError(f"widths must give one width per column ({n}), got {len(widths)}")
        self.widths = [max(w, len(h)) for w, h in zip(widths, self.headers)]
        self.align = _align(align, n)

    def header(self) -> str:
        """The titles and the rule under them (two lines)."""
        return "\n".join([_line(self.headers, self.widths, self.align), _rule(self.widths, self.align)])

    def row(self, cells: Sequence[object]) -> str:
        """One row; ValueError unless it has one cell per column."""
        cells = [str(c) for c in cells]
        if len(cells) != len(self.headers):
            raise ValueError(f"a row needs one cell per column ({len(self.headers)}: {self.headers}), "
                             f"got {len(cells)}: {cells}")
        return _line(cells, self.widths, self.align)


def table(headers: Sequence[object], rows: Iterable[Sequence[object]], align: str | None = None) -> str:
    """The whole table: titles, rule and one line per row, each column as wide as its widest cell.

    ``align``: one ``'<'`` (left) or ``'>'`` (right) per column; default: first left, others right."""
    rows = [[str(c) for c in r] for r in rows]
    columns = Columns(headers, align=align)
    for r in rows:
        if len(r) != len(columns.headers):
            raise ValueError(f"a row needs one cell per column ({len(columns.headers)}: {columns.headers}), "
                             f"got {len(r)}: {r}")
    columns.widths = [max([w, *(len(r[i]) for r in rows)]) for i, w in enumerate(columns.widths)]
    return "\n".join([columns.header(), *(columns.row(r) for r in rows)])
