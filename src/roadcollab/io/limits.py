"""What an input file may hold before it is read: size and row limits, ASCII numbers, physical bounds.

Every reader of :mod:`roadcollab.io` checks a file against a :class:`FileLimits` *before* reading it
(the size from ``stat``, so a 2.5 GB file is refused without reading a byte), stops counting rows at
the limit, and parses numbers with :func:`parse_ascii_number` (plain ASCII decimal notation only:
``float()`` would accept Arabic-Indic or full-width digits and ``1_000``). Every error is a
:class:`~roadcollab.errors.FileFormatError` whose message starts with the file's path.

The command line raises the limits with ``--max-rows`` and ``--max-file-mb``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from .._validation import check_int, check_real
from ..errors import FileFormatError

__all__ = ["DEFAULT_MAX_ROWS", "DEFAULT_MAX_FILE_MB", "PARAMS_MAX_BYTES", "MAX_ACCEL", "FileLimits",
           "check_file_size", "parse_ascii_number", "short_repr"]

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


def check_file_size(path: Path, what: str, max_bytes: int, flag: str | None = "--max-file-mb") -> None:
    """Refuse a missing file or one larger than ``max_bytes`` (from ``stat``; nothing is read).

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
        ``"<path>: ..."``: not an existing file, unreadable, or too large.
    """
    if not path.is_file():
        raise FileFormatError(f"{path}: {what} not found (expected an existing file)")
    try:
        size = path.stat().st_size
    except OSError as err:
        raise FileFormatError(f"{path}: cannot read {what}: {err.strerror or err}") from None
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
