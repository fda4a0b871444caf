"""Run records shared by every report: CSV of every plotted number, ``config.json`` and Markdown tables.

Every run writes its seed, full configuration and the package version next to its outputs. A CSV
with fixed columns is a list of frozen row dataclasses (the fields are the columns, in order)
written by :func:`write_rows`; tables whose columns depend on the run (one per drive or condition)
are dicts with the column list their result type computes, written by :func:`write_csv`.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import platform
import sys
from pathlib import Path

import numpy as np

from .. import __version__
from ..lti.kernels import kernel_path
from .output_folder import staged_file, staged_output

__all__ = ["write_rows", "row_columns", "write_csv", "write_config", "strict_json", "markdown_table", "fmt",
           "output_dir", "staged_output", "staged_file", "run_header"]


def _plain(value):
    """JSON-ready version of numpy scalars, arrays, tuples and paths."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None  # strict JSON has no NaN or Infinity
    if isinstance(value, Path):
        return str(value)
    return value


def strict_json(value, **kw) -> str:
    """Strict JSON text of ``value`` (numpy types converted; NaN and infinities become ``null``).

    Parameters
    ----------
    value : object
        Dicts, lists, tuples, numpy scalars and arrays, paths and plain JSON types.
    **kw
        Passed to :func:`json.dumps` (e.g. ``indent=2``).

    Returns
    -------
    str
        Text that ``json.loads`` of any strict parser reads (``allow_nan=False`` holds).
    """
    return json.dumps(_plain(value), allow_nan=False, **kw)


def fmt(value) -> str:
    """Compact number formatting for Markdown tables (4 significant digits).

    Parameters
    ----------
    value : object
        A bool, integer or float (Python or numpy); anything else is shown with ``str``.

    Returns
    -------
    str
        ``"True"``/``"False"``, the integer, the float to 4 significant digits, or ``str(value)``.
    """
    if isinstance(value, (bool, np.bool_)):
        return str(bool(value))
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return str(value)


def write_csv(path, rows: list[dict], columns: list[str] | None = None) -> Path:
    """Write dict rows to CSV with full float precision (repr).

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    rows : list of dict
        One dict per row, holding every key of ``columns``. Python and numpy floats are written
        as ``repr(float(v))``, other values as ``str(v)``.
    columns : list of str, optional
        Column order and header (default: the keys of the first row; none if ``rows`` is empty).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    columns = columns or list(rows[0].keys()) if rows else (columns or [])
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow([repr(float(r[c])) if isinstance(r[c], (float, np.floating)) else r[c] for c in columns])
    return path


def row_columns(row_type: type) -> list[str]:
    """The CSV columns of a row type: its dataclass fields, in order.

    Parameters
    ----------
    row_type : type
        A dataclass.

    Returns
    -------
    list of str
    """
    return [f.name for f in dataclasses.fields(row_type)]


def write_rows(path, rows, row_type: type) -> Path:
    """Write typed rows to CSV: the header is ``row_type``'s fields, each row one instance.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    rows : sequence of row_type
        Frozen dataclass instances; floats are written as by :func:`write_csv`.
    row_type : type
        The rows' dataclass (gives the header even without rows).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    TypeError
        A row is not a ``row_type``.
    """
    for r in rows:
        if type(r) is not row_type:
            raise TypeError(f"rows must be {row_type.__name__}, got {type(r).__name__}")
    columns = row_columns(row_type)
    # Rows are flat records of scalars: their fields as they are (``dataclasses.asdict`` deep-copies every
    # value, which took a second for the reproduction's few thousand rows).
    return write_csv(path, [{c: getattr(r, c) for c in columns} for r in rows], columns)


def write_config(path, *, command: str, seed: int | None, config: dict, extra: dict | None = None) -> Path:
    """Write ``config.json``: command, seed, configuration, package and platform versions, kernel path.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    command : str
        The command line of the run.
    seed : int or None
        Root seed (None if the run has none).
    config : dict
        Full configuration; numpy scalars and arrays, tuples and paths become JSON types.
    extra : dict, optional
        More top-level keys, converted the same way (they replace standard keys of the same name).

    Returns
    -------
    Path
        ``path``.
    """
    record = {
        "command": command,
        "seed": seed,
        "roadcollab_version": __version__,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "platform": platform.platform(),
        "kernels": kernel_path(),     # compiled or reference: the same numbers to round-off, not bit for bit
        "config": config,
    }
    if extra:
        record.update(extra)
    path = Path(path)
    path.write_text(strict_json(record, indent=2) + "\n")
    return path


def markdown_table(rows: list, columns: list[str], headers: list[str] | None = None) -> str:
    """A GitHub-flavoured Markdown table.

    Parameters
    ----------
    rows : list of dict or of dataclass instances
        One per table row, holding every key (field) of ``columns``.
    columns : list of str
        Keys (fields) shown, in order; values formatted by :func:`fmt` (numbers to 4 significant digits).
    headers : list of str, optional
        Header text of each column (default: ``columns``).

    Returns
    -------
    str
        The table, one line per row, without a trailing newline.
    """
    headers = headers or columns
    rows = [dataclasses.asdict(r) if dataclasses.is_dataclass(r) and not isinstance(r, type) else r for r in rows]
    out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for r in rows:
        out.append("| " + " | ".join(fmt(r[c]) for c in columns) + " |")
    return "\n".join(out)


def output_dir(out) -> Path:
    """The output folder of a run, created if missing.

    Parameters
    ----------
    out : str or Path
        Folder (parents created too; an existing folder is kept and its files overwritten later).

    Returns
    -------
    Path
        ``out``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def run_header(title: str, command: str, elapsed: float) -> list[str]:
    """The first lines of a study's ``report.md``: title, command line and wall-clock time.

    Parameters
    ----------
    title : str
        Markdown heading, e.g. ``"# roadcollab attack: ..."``.
    command : str
        The command line of the run.
    elapsed : float
        Wall-clock time of the run, s.

    Returns
    -------
    list of str
        Report lines (to be joined with newlines), ending with an empty line.
    """
    return [title, "", f"Command: `{command}`  ", f"{elapsed:.1f} s.", ""]
