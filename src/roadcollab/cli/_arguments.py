"""Range-checked option types and the one-line argument errors of every ``roadcollab`` command.

Every numeric option has a stated range (in its help, and in ``docs/options.md``) checked while the
command line is parsed, before anything is imported or computed. A value outside it, NaN, infinity or
text that is not a number is refused by argparse with one line naming the option::

    roadcollab reproduce: error: argument --speed: expected a speed from 1 to 60 m/s, got 0.01

Ranges that depend on another option (e.g. ``--segment-length`` against ``--grid-step``) are checks
registered with :func:`add_check`; :class:`CommandParser` runs them right after parsing, so they too
end in one line naming the options.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any, Callable, Generic, Literal, NoReturn, Protocol, TypeVar, cast, overload

from ..reporting.wording import plural

__all__ = ["CommandParser", "Range", "add_check", "ranged", "ranged_list", "count", "help_range", "iso_class", "plural",
           "SEED_MAX", "SPEED", "NOISE", "UNCERTAINTY", "GAMMA", "SEED", "WORKERS", "MAX_ROWS", "MAX_FILE_MB"]

#: Largest root seed: ``config.json`` records it, and JSON readers keep integers exactly up to 2^53.
SEED_MAX = 2 ** 53

_V = TypeVar("_V", covariant=True)


class RangedType(Protocol, Generic[_V]):
    """What :func:`ranged` and :func:`ranged_list` return: an argparse ``type`` carrying its :class:`Range`."""

    range: Range
    __name__: str

    def __call__(self, text: str, /) -> _V: ...


def _with_range(parse: Callable[[str], Any], rng: Range, what: str) -> RangedType[Any]:
    """``parse`` with its ``range`` attribute and argparse's ``__name__`` (named in some messages)."""
    typed = cast("RangedType[Any]", parse)
    typed.range = rng
    typed.__name__ = what
    return typed


@dataclass(frozen=True)
class Range:
    """The accepted values of one numeric option: ``low <= v <= high``, in the option's unit.

    Parameters
    ----------
    what : str
        What the value is, in the user's words (``"speed"``, ``"number of runs"``).
    low, high : float
        Inclusive bounds, in ``unit``.
    unit : str
        Unit written after the numbers (``"m/s"``; ``""`` for counts).
    integer : bool
        Whole numbers only.
    """

    what: str
    low: float
    high: float
    unit: str = ""
    integer: bool = False

    def text(self) -> str:
        """``"1 to 60 m/s"``: the range as the help and the messages write it."""
        unit = f" {self.unit}" if self.unit else ""
        return f"{_num(self.low)} to {_num(self.high)}{unit}"

    def parse(self, text: str) -> float | int:
        """The value of ``text`` if it is a number in the range; ``argparse.ArgumentTypeError`` otherwise.

        Parameters
        ----------
        text : str
            The value as typed.

        Returns
        -------
        int or float
            An int when ``integer``.

        Raises
        ------
        argparse.ArgumentTypeError
            Not a (whole) number, NaN, infinite or outside ``[low, high]``.
        """
        kind = "a whole number" if self.integer else "a number"
        want = f"expected {'an' if self.what[0] in 'aeiou' else 'a'} {self.what} from {self.text()}"
        shown = text if len(text) <= 40 else text[:40] + "..."
        try:
            value = int(text) if self.integer else float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{want}, got {shown!r} (not {kind})") from None
        # NaN fails both comparisons; infinity fails the upper bound. The value is shown as typed.
        if not (self.low <= value <= self.high):
            raise argparse.ArgumentTypeError(f"{want}, got {shown.strip()}")
        return value


def _num(v: float) -> str:
    """A bound or value as a person writes it: ``60``, ``0.05``, ``2,000,000``, ``9.007e+15``."""
    if float(v).is_integer() and abs(v) < 1e16:
        return f"{int(v):,}"
    return f"{v:g}"


@overload
def ranged(what: str, low: float, high: float, unit: str = "", *, integer: Literal[True]) -> RangedType[int]: ...


@overload
def ranged(what: str, low: float, high: float, unit: str = "", *, integer: bool = False
           ) -> RangedType[float | int]: ...


def ranged(what: str, low: float, high: float, unit: str = "", *, integer: bool = False
           ) -> RangedType[Any]:
    """argparse ``type``: a number in ``[low, high]`` (see :class:`Range`); the range is ``type.range``.

    Parameters
    ----------
    what : str
        What the value is (``"speed"``).
    low, high : float
        Inclusive bounds, in ``unit``.
    unit : str
        Unit of the bounds.
    integer : bool
        Whole numbers only.

    Returns
    -------
    callable
        ``parse(text) -> int | float`` with a ``range`` attribute (the :class:`Range`).
    """
    rng = Range(what, low, high, unit, integer)

    def parse(text: str) -> float | int:
        return rng.parse(text)

    return _with_range(parse, rng, what)


def ranged_list(what: str, low: float, high: float, unit: str = "", *, integer: bool = False,
                most: int = 50) -> RangedType[tuple[float | int, ...]]:
    """argparse ``type``: comma-separated numbers, each in ``[low, high]``, at most ``most`` of them.

    Parameters
    ----------
    what, low, high, unit, integer
        As :func:`ranged`, for each element.
    most : int
        Longest list (a grid of several lists multiplies their lengths).

    Returns
    -------
    callable
        ``parse(text) -> tuple`` with a ``range`` attribute.
    """
    rng = Range(what, low, high, unit, integer)

    def parse(text: str) -> tuple[float | int, ...]:
        parts = [p.strip() for p in text.split(",")]
        if not text.strip() or "" in parts:
            raise argparse.ArgumentTypeError(f"expected comma-separated {what}s from {rng.text()} such as "
                                             f"{low:g},{high:g}, got {text[:40]!r}")
        if len(parts) > most:
            raise argparse.ArgumentTypeError(f"expected at most {most} values, got {len(parts)}")
        return tuple(rng.parse(p) for p in parts)

    return _with_range(parse, rng, what)


def add_check(parser: argparse.ArgumentParser, check: Callable[[argparse.Namespace], str | None]) -> None:
    """Register a check of several options, run by :class:`CommandParser` right after parsing.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The command's parser.
    check : callable
        ``check(args)`` returns None when the options fit together, else the message (naming the options).
    """
    checks = getattr(parser, "roadcollab_checks", None)
    if checks is None:
        checks = []
        cast(Any, parser).roadcollab_checks = checks   # argparse has no place for them: an attribute of ours
    checks.append(check)


class CommandParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are one line on stderr (exit status 2) and which runs the
    checks of :func:`add_check` right after parsing.

    argparse's own ``error`` prints the whole usage (up to 20 lines for ``reproduce``) before the
    message; the one line says where the usage is instead.
    """

    def parse_known_args(self, args=None, namespace=None):
        ns, extra = super().parse_known_args(args, namespace)
        for check in getattr(self, "roadcollab_checks", ()):
            problem = check(ns)
            if problem:
                self.error(problem)
        return ns, extra

    def error(self, message: str) -> NoReturn:
        text = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {text} (see '{self.prog} --help')\n")


# --- the ranges shared by several commands (docs/options.md says why each) -------------------------

#: Road vehicles: 1 m/s (walking pace; below it a window of road takes 10^5+ samples and gigabytes)
#: to 60 m/s (216 km/h).
SPEED = ranged("speed", 1, 60, "m/s")
#: Accelerometer noise std: 0 (ideal sensor) to 10 m/s^2 (1 g, beyond any usable sensor).
NOISE = ranged("noise standard deviation", 0, 10, "m/s^2")
#: Relative parameter uncertainty of each vehicle's model: FleetSpec accepts 0 to 0.3.
UNCERTAINTY = ranged("relative uncertainty", 0, 0.3)
#: Observer parameter gamma of eq. 4 (corner gamma (1 + gamma) / 2 rad/s).
GAMMA = ranged("observer gamma", 0.01, 10_000)
SEED = ranged("seed", 0, SEED_MAX, integer=True)
#: Local worker processes: each holds a few hundred MB.
WORKERS = ranged("number of worker processes", 1, 64, integer=True)
#: At most the 5e7 samples a road model holds (a small limit only refuses files, clearly).
MAX_ROWS = ranged("row limit", 1, 50_000_000, integer=True)
MAX_FILE_MB = ranged("file size limit", 0.01, 10_000, "MB")


def count(what: str, low: int, high: int) -> RangedType[int]:
    """argparse ``type``: a whole number of ``what`` from ``low`` to ``high`` (see :func:`ranged`)."""
    return ranged(what, low, high, integer=True)


def help_range(parse: RangedType[object]) -> str:
    """``"1 to 60 m/s"``: the range of a :func:`ranged` type, for the option's help."""
    return parse.range.text()


def iso_class(text: str) -> str:
    """argparse ``type``: an ISO 8608 roughness class letter A (smoothest) to H, any case.

    Parameters
    ----------
    text : str
        The option's value as typed.

    Returns
    -------
    str
        The upper-case letter.

    Raises
    ------
    argparse.ArgumentTypeError
        Anything but one letter A-H.
    """
    key = text.strip().upper()
    if len(key) != 1 or key not in "ABCDEFGH":
        raise argparse.ArgumentTypeError(f"expected an ISO 8608 roughness class A to H, got {text[:40]!r}")
    return key
