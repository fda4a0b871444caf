"""Exception types of roadcollab.

Both subclass :class:`ValueError`, so callers that already catch ``ValueError`` keep working.
"""

from __future__ import annotations

__all__ = ["MessageError", "ParameterError"]


class ParameterError(ValueError):
    """A parameter or argument has a wrong value, type or shape.

    The message names the parameter and gives the expected versus the actual value.
    """


class MessageError(ValueError):
    """A received (untrusted) message is malformed, truncated, oversized or unsafe to use."""
