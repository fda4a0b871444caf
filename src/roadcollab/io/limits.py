"""What an input file may hold before it is read: size and row limits, ASCII numbers, physical bounds.

Every reader of :mod:`roadcollab.io` checks a file against a :class:`FileLimits` *before* reading it
(the size from ``stat``, so a 2.5 GB file is refused without reading a byte), stops counting rows at
the limit, and parses numbers with :func:`parse_ascii_number` (plain ASCII decimal notation only:
``float()`` would accept Arabic-Indic or full-width digits and ``1_000``). Every error is a
:class:`~roadcollab.errors.FileFormatError` whose message starts with the file's path.

The command line raises the limits with ``--max-rows`` and ``--max-file-mb``.
"""

from __future__ import annotations

import errno
import math
import os
import re
import stat
from dataclasses import dataclass
from pathlib import Path

from .._validation import check_int, check_real
from ..errors import FileFormatError

__all__ = ["DEFAULT_MAX_ROWS", "DEFAULT_MAX_FILE_MB", "PARAMS_MAX_BYTES", "MAX_ACCEL", "FileLimits",
           "check_regular_file", "check_file_size", "parse_ascii_number", "short_repr"]

DEFAULT_MAX_ROWS = 2_000_000       # 2.8 h at 200 Hz, 20 km of profile at 1 cm
DEFAULT_MAX_FILE_MB = 200.0        # 2 M rows of full-precision CSV take about 120 MB
PARAMS_MAX_BYTES = 1_000_000       # a parameters file holds nine numbers
MAX_ACCEL = 200.0                  # m/s^2 (about 20 g): beyond it a body-tip sample is a logger glitch
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)


@dataclass(frozen=True)
class FileLimits:
    """Largest input file a reader accepts.

    Parameters
    ----------
    max_rows : int
        Data rows per file (default 2,000,000); reading stops with an error at the first row past it.
    max_file_mb : float
        File size in MB (10^6 bytes, default 200), checked with ``stat`` before reading.
    """

    max_rows: int = DEFAULT_MAX_ROWS
    max_file_mb: float = DEFAULT_MAX_FILE_MB

    def __post_init__(self) -> None:
        check_int("max_rows", self.max_rows, low=1)
        check_real("max_file_mb", self.max_file_mb, low=0.0, low_open=True)

    @property
    def max_bytes(self) -> int:
        """``max_file_mb`` in bytes."""
        return int(self.max_file_mb * 1e6)


def check_regular_file(path: Path, what: str) -> os.stat_result:
    """Refuse anything but an existing, readable regular file, with a message for each kind; nothing is opened.

    A FIFO or a device is recognised from ``stat`` before any ``open`` (opening a FIFO blocks until a
    writer appears; ``/dev/zero`` never ends), so the check never blocks.

    Parameters
    ----------
    path : Path
        The file as given.
    what : str
        What the file is, for the message (e.g. ``"drive CSV"``).

    Returns
    -------
    os.stat_result
        Of the file (symlinks followed).

    Raises
    ------
    FileFormatError
        ``"<path>: <what> ..."``: not found, a dangling symlink, a symlink loop, a folder, a FIFO, a
        device, a socket, or not readable.
    """
    path = Path(path)
    try:
        st = path.stat()
    except OSError as err:
        raise FileFormatError(f"{path}: {what} {_stat_problem(path, err)}") from None
    mode = st.st_mode
    kind = ("a folder" if stat.S_ISDIR(mode) else "a named pipe (FIFO)" if stat.S_ISFIFO(mode) else
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode) else
            None if stat.S_ISREG(mode) else "not a regular file")
    if kind is not None:
        raise FileFormatError(f"{path}: expected {what} to be a regular file, got {kind}")
    if not os.access(path, os.R_OK):
        raise FileFormatError(f"{path}: cannot read {what}: permission denied")
    return st


def _stat_problem(path: Path, err: OSError) -> str:
    """Why ``stat`` of ``path`` failed, in words: not found, dangling or looping symlink, a parent that is a file."""
    if err.errno == errno.ELOOP:
        return "is a symlink loop (the links never reach a file)"
    if err.errno == errno.ENOENT and path.is_symlink():
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
        return f"is a dangling symlink (its target {target} does not exist)"
    if err.errno == errno.ENOENT:
        return "not found (expected an existing file)"
    if err.errno == errno.ENOTDIR:
        return "not found (a folder in its path is a file)"
    if err.errno == errno.EACCES:
        return "cannot be reached: permission denied on a folder in its path"
    if err.errno == errno.ENAMETOOLONG:
        return "not found: the path is too long"
    return f"cannot be read: {err.strerror or err}"


def check_file_size(path: Path, what: str, max_bytes: int, flag: str | None = "--max-file-mb") -> None:
    """Refuse anything but a regular file (:func:`check_regular_file`) or one larger than ``max_bytes``
    (from ``stat``; nothing is read).

    Parameters
    ----------
    path : Path
        The file.
    what : str
        What the file is, for the message (e.g. ``"drive CSV"``).
    max_bytes : int
        Largest accepted size, bytes.
    flag : str or None
        The command-line option that raises the limit, named in the message (None: none).

    Raises
    ------
    FileFormatError
        ``"<path>: ..."``: not an existing regular file (each kind its own message), unreadable, or too large.
    """
    size = check_regular_file(path, what).st_size
    if size > max_bytes:
        raise_hint = f"; raise the limit with {flag}" if flag else ""
        raise FileFormatError(f"{path}: {what} is {size / 1e6:.4g} MB, larger than the limit of "
                              f"{max_bytes / 1e6:.4g} MB{raise_hint}")


def parse_ascii_number(text: str) -> float | None:
    """The finite float of a plain ASCII decimal number, or None.

    Parameters
    ----------
    text : str
        One field, surrounding whitespace already removed.

    Returns
    -------
    float or None
        None for anything but ``[+-]digits[.digits][e[+-]digits]`` in ASCII (no ``nan``, ``inf``,
        underscores or non-ASCII digits) and for values that overflow to infinity (``1e400``).
    """
    if len(text) > 64 or not _NUMBER.fullmatch(text):
        return None
    v = float(text)
    return v if math.isfinite(v) else None


def short_repr(value, width: int = 60) -> str:
    """``repr(value)`` cut to ``width`` characters (a hostile value must not flood the message).

    Parameters
    ----------
    value : object
    width : int
        Longest result, characters.

    Returns
    -------
    str
    """
    try:
        text = repr(value)
    except (ValueError, RecursionError):  # a huge int beyond sys.get_int_max_str_digits, deep nesting
        text = f"<{type(value).__name__}>"
    return text if len(text) <= width else f"{text[:width]}... ({len(text)} characters)"
