"""Run records shared by every report: CSV of every plotted number, ``config.json`` and Markdown tables.

Every run writes its seed, full configuration and the package version next to its outputs. A CSV
with fixed columns is a list of frozen row dataclasses (the fields are the columns, in order)
written by :func:`write_rows`; tables whose columns depend on the run (one per drive or condition)
are dicts with the column list their result type computes, written by :func:`write_csv`.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import json
import math
import os
import platform
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from .. import __version__
from ..errors import ParameterError

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
    """Write ``config.json``: command, seed, configuration, package and platform versions.

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
        "config": config,
    }
    if extra:
        record.update(extra)
    path = Path(path)
    path.write_text(strict_json(record, indent=2) + "\n")
    return path


def markdown_table(rows: list[dict], columns: list[str], headers: list[str] | None = None) -> str:
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
    rows = [dataclasses.asdict(r) if dataclasses.is_dataclass(r) else r for r in rows]
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


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _sibling(out: Path, kind: str) -> Path:
    """A new hidden folder beside ``out`` (same file system, so a rename moves it), ParameterError if impossible."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.{kind}-", dir=out.parent))
        tmp.chmod(0o777 & ~_umask())  # mkdtemp makes 0700; the results get the usual permissions
        return tmp
    except OSError as err:
        raise ParameterError(f"--out {out}: cannot write there: {err.strerror or err}") from None


@contextlib.contextmanager
def staged_output(out):
    """Write a run's outputs into a temporary sibling folder and move it to ``out`` only at the end.

    The sibling is created on entry, so an unusable ``out`` fails before any compute; a run that
    fails or is killed leaves ``out`` (the previous results) untouched (a killed run leaves a hidden
    ``.NAME.partial-*`` folder beside it). On success the previous ``out`` is renamed aside, the new
    folder renamed into place and the old one deleted: two renames on one file system.

    Parameters
    ----------
    out : str or Path
        The final output folder; if it exists it must be a folder (it is replaced as a whole).

    Yields
    ------
    Path
        The folder to write into.

    Raises
    ------
    ParameterError
        ``out`` exists and is not a folder, or its parent cannot be created or written.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ParameterError(f"--out {out}: expected a folder, got an existing file")
    tmp = _sibling(out, "partial")
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = _sibling(out, "old") if out.exists() else None
    try:
        if old is not None:
            os.replace(out, old / out.name)
        os.replace(tmp, out)
    except OSError as err:
        raise ParameterError(f"--out {out}: cannot move the results into place: {err.strerror or err} "
                             f"(they are in {tmp})") from None
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged_file(path):
    """Write one file under a temporary sibling name and rename it to ``path`` at the end.

    The parent folder is created and checked on entry (before any compute); a failed run leaves
    ``path`` untouched.

    Parameters
    ----------
    path : str or Path
        The final file; if it exists it must be a regular file (it is replaced).

    Yields
    ------
    Path
        The temporary file to write.

    Raises
    ------
    ParameterError
        ``path`` is a folder, or its parent cannot be created or written.
    """
    path = Path(path)
    if path.is_dir():
        raise ParameterError(f"--out {path}: expected a file, got an existing folder")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.partial-", dir=path.parent)
        os.close(fd)
        os.chmod(name, 0o666 & ~_umask())
    except OSError as err:
        raise ParameterError(f"--out {path}: cannot write there: {err.strerror or err}") from None
    tmp = Path(name)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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
