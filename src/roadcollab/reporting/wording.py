"""Wording shared by the reports and the terminal: counts with their nouns in the right number."""

from __future__ import annotations

__all__ = ["plural"]


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``"1 run"``, ``"2 runs"``: a count with its noun in the right number.

    Parameters
    ----------
    n : int
    noun : str
        Singular.
    nouns : str, optional
        Plural (default ``noun + "s"``).

    Returns
    -------
    str

    Examples
    --------
    >>> plural(1, "run"), plural(2, "run"), plural(0, "vehicle-segment")
    ('1 run', '2 runs', '0 vehicle-segments')
    """
    return f"{n} {noun if n == 1 else (nouns or noun + 's')}"
