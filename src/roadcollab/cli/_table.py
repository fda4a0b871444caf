"""Tables on the terminal that fit it: headers and labels wrap at spaces, numbers are never cut, and a
table too wide for the terminal (80 columns when piped) is split into parts that each repeat the first
column."""

from __future__ import annotations

from typing import Sequence

__all__ = ["print_table", "split_columns", "fit_widths", "table_width"]

#: Columns a rich table with the default box spends around each column's text: one space of
#: padding either side and one rule; plus the closing rule.
_PER_COLUMN, _EDGE = 3, 1


def _unbreakable(text: str) -> int:
    """Width of the longest word of ``text`` (cells wrap at spaces only, so a number is never cut)."""
    return max((len(w) for w in str(text).split()), default=0)


def _min_widths(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> list[int]:
    """Narrowest width of each column: its longest word, header or cell."""
    return [max([_unbreakable(c)] + [_unbreakable(r[i]) for r in rows]) for i, c in enumerate(columns)]


def _natural_widths(columns: Sequence[str], rows: Sequence[Sequence[str]]) -> list[int]:
    """Width of each column with nothing wrapped."""
    return [max([len(c)] + [len(r[i]) for r in rows]) for i, c in enumerate(columns)]


def fit_widths(mins: Sequence[int], natural: Sequence[int], width: int) -> list[int]:
    """Text widths that fit ``width``: the natural ones if they fit, else the narrowest ones widened
    one column at a time (the one furthest from its natural width first) while the table fits.

    Parameters
    ----------
    mins, natural : sequence of int
        Narrowest (longest word) and unwrapped width of each column.
    width : int
        Terminal width, columns.

    Returns
    -------
    list of int
        Between ``mins`` and ``natural`` column by column.
    """
    if table_width(natural) <= width:
        return list(natural)
    w = list(mins)
    spare = width - table_width(w)
    while spare > 0:
        i = max(range(len(w)), key=lambda j: natural[j] - w[j])
        if natural[i] <= w[i]:
            break
        w[i] += 1
        spare -= 1
    return w


def table_width(widths: Sequence[int]) -> int:
    """Terminal columns a table with these text widths takes, box and padding included.

    Parameters
    ----------
    widths : sequence of int
        Text width of each column, characters.

    Returns
    -------
    int
    """
    return sum(widths) + _PER_COLUMN * len(widths) + _EDGE


def split_columns(widths: Sequence[int], width: int) -> list[list[int]]:
    """Column indices of each part of a table too wide for ``width``; every part keeps column 0.

    Parameters
    ----------
    widths : sequence of int
        Narrowest text width of each column.
    width : int
        Terminal width, columns.

    Returns
    -------
    list of list of int
        One part if everything fits; otherwise greedy parts, each ``[0, ...]`` in the original order.
        A column that does not fit even beside column 0 gets a part of its own with it.
    """
    if table_width(widths) <= width or len(widths) <= 1:
        return [list(range(len(widths)))]
    parts, current = [], [0]
    for i in range(1, len(widths)):
        if len(current) > 1 and table_width([widths[j] for j in current + [i]]) > width:
            parts.append(current)
            current = [0]
        current.append(i)
    parts.append(current)
    return parts


def print_table(title: str, columns: Sequence[str], rows: Sequence[Sequence[str]], *, width: int | None = None
                ) -> None:
    """Print a rich table with right-justified columns to stdout, within the terminal's width.

    Headers and text cells wrap at spaces; a word (a number) is never cut. When even the narrowest
    layout is wider than the terminal (80 columns when stdout is piped), the table is printed in parts,
    each repeating the first column and titled ``(part k of m)``.

    Parameters
    ----------
    title : str
        Table title.
    columns : sequence of str
        Column headers.
    rows : sequence of sequence of str
        Cell texts, one sequence per row.
    width : int, optional
        Terminal width, columns (default: what rich detects, 80 when piped).
    """
    from rich.console import Console
    from rich.table import Table

    console = Console() if width is None else Console(width=width)
    mins, natural = _min_widths(columns, rows), _natural_widths(columns, rows)
    parts = split_columns(mins, console.width)
    for k, part in enumerate(parts, start=1):
        name = title if len(parts) == 1 else f"{title} (part {k} of {len(parts)})"
        # rich's own narrowing folds words (a long estimator name, a number): give it widths that fit.
        widths = fit_widths([mins[i] for i in part], [natural[i] for i in part], console.width)
        table = Table(title=name)
        for i, w in zip(part, widths):
            table.add_column(columns[i], justify="right", overflow="fold", width=w)
        for row in rows:
            table.add_row(*(row[i] for i in part))
        # A single column wider than the terminal (a huge label) still prints whole: widen for it alone.
        need = table_width(widths)
        out = console if need <= console.width else Console(width=need, file=console.file)
        out.print(table)
