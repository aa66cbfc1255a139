"""The column widths and row heights of the certificate's tables, worked out before Typst
sets them (pipelines.reports.typeset).

Typst finds a row's height by laying out each of its cells once more before it sets them,
and an `auto` column's width by measuring every cell of it: together more than half of a
certificate's typesetting. Both are known beforehand from the widths of the texts (the
sum of their characters' advances, measured by Typst itself): a table across the page's
width, as a browser lays out `width: 100%` (each column at least its widest cell, the
room left shared in proportion), or, too wide for the page, shrunk as Typst shrinks
`auto` columns; a row whose every text fits its column on one line gets the height of
one line, any other row stays `auto` (Typst measures it, and wraps its texts).
"""

from __future__ import annotations

from collections.abc import Callable

Cell = tuple[str, bool]  # the text, set in bold
# (width in pt, True if it stays one line of the table's text when it is wide enough)
Measure = Callable[[str, bool], tuple[float, bool]]
# A text's width is the sum of its characters' advances; kerning moves it by a few tenths
# of a point at most (0.18 pt in the sample certificates): each text is given this much
# more room (factor, pt), so a row held to one line never wraps.
KERNING_SPARE = (1.01, 0.5)


def column_widths(natural: list[float], available: float) -> list[float]:
    """Widths (pt) of columns whose widest cells are `natural` wide, in a table `available`
    wide: widened in proportion when they fit; else Typst's own shrink of `auto` columns
    (the columns narrower than the fair share keep their width, the others share the
    rest equally), so a long text wraps in its own column and a short one stays whole."""
    total = sum(natural)
    if total <= 0:
        return [available / len(natural)] * len(natural)
    if total < available:
        return [w / total * available for w in natural]
    fair, room, wide = -float("inf"), available, len(natural)
    changed = True
    while changed and wide > 0:
        changed, last = False, fair
        fair = room / wide
        for w in natural:
            if last < w <= fair:  # fits its fair share: keeps its width, leaves the rest
                room -= w
                wide -= 1
                changed = True
    return [min(w, fair) for w in natural]


def plan(
    rows: list[list[Cell]], measure: Measure, available: float, padding: float
) -> tuple[list[float], list[bool]]:
    """The columns' widths (pt) and, per row, whether it is one line high.

    Parameters
    ----------
    rows : the table's rows (a header first, if it has one), each a list of cells.
    measure : a text's width (pt) and whether it stays one line when wide enough.
    available : the table's width (pt).
    padding : a cell's padding, left plus right (pt).
    """
    factor, spare = KERNING_SPARE
    sized = [
        [(w * factor + spare, single) for w, single in (measure(t, bold) for t, bold in row)]
        for row in rows
    ]
    natural = [max(row[i][0] for row in sized) + padding for i in range(len(rows[0]))]
    widths = column_widths(natural, available)
    one_line = [
        all(single and w + padding <= width for (w, single), width in zip(row, widths, strict=True))
        for row in sized
    ]
    return widths, one_line
