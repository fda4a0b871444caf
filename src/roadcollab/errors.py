"""Exception types of roadcollab.

Every type subclasses :class:`ValueError`, so callers that already catch ``ValueError`` keep working.
"""

from __future__ import annotations

__all__ = ["FileFormatError", "MessageError", "ParameterError"]


class ParameterError(ValueError):
    """A parameter or argument has a wrong value, type or shape.

    The message names the parameter and gives the expected versus the actual value.
    """


class MessageError(ValueError):
    """A received (untrusted) message is malformed, truncated, oversized or unsafe to use."""


class FileFormatError(ParameterError):
    """An input file (drive CSV, parameters file, road profile) is missing, too large or malformed.

    The message starts with the file's path and, where there is one, the line and the field.
    A :class:`ParameterError` (so a ``ValueError``), so callers catching either keep working.
    """
