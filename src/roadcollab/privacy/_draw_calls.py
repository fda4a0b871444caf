"""Python entry points of the compiled ``Psi`` draw (:mod:`._draw_kernel`): the loop's arguments from the
spec, and the accepted candidates realised.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._draw_kernel import _KERNEL, _build

__all__ = ["draw_loop", "draw_loops"]


def draw_loop(spec: Any, powers: np.ndarray, rng: np.random.Generator, max_attempts: int, dt: float
              ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...], tuple[np.ndarray, np.ndarray]] | None:
    """Run the rejection loop compiled, and realise the accepted candidate.

    Parameters
    ----------
    spec : ObfuscationSpec
    powers : (degree + 1, K) ndarray
        ``w^k`` at the warped frequencies (``obfuscator_design._warped_powers``).
    rng : numpy.random.Generator
        Advanced exactly as the reference loop advances it.
    max_attempts : int
    dt : float
        Sample period of the discretisation, s.

    Returns
    -------
    (poles, numerators, (Ad, Bd, Cd, Dd), (T, U)) or None
        Poles (n,) rad/s, numerators (2, 2, n + 1), the discrete realisation (order 2 n) of the
        accepted candidate and a complex Schur form ``Ad = U T U^H`` of it (``T`` diagonal, ``U``
        unitary, both (2 n, 2 n) complex, to round-off); None if no candidate was accepted in
        ``max_attempts``.
    """
    return draw_loops(spec, powers, rng, max_attempts, dt, 1)[0]


def draw_loops(spec: Any, powers: np.ndarray, rng: np.random.Generator, max_attempts: int, dt: float, count: int
               ) -> list[tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...], tuple[np.ndarray, np.ndarray]] | None]:
    """:func:`draw_loop` ``count`` (1 or 2) times in a row, the loops in one compiled call for two: numba
    takes a ``Generator`` argument apart on every call (7 us, measured), a ``paper`` send draws two ``Psi``.
    The second draw starts only after the first is accepted, from the generator as the first left it: the
    same numbers as two calls.

    Parameters
    ----------
    spec, powers, rng, max_attempts, dt
        As :func:`draw_loop`.
    count : {1, 2}

    Returns
    -------
    list
        Per draw, what :func:`draw_loop` returns; after a draw that found nothing (None) no other is made
        and the list ends there.
    """
    _build()
    plf = np.log(spec.pole_frequency_range)
    zlf = np.log(spec.zero_frequency_range)
    lo, hi = spec.order_range
    rec = np.empty(1 + 6 * 3 * hi + 8)      # the values the last candidate drew, in order (kept for inspection)
    if count not in (1, 2):
        raise ValueError(f"count must be 1 or 2, got {count}")
    poles = np.empty((count, hi), complex)
    num = np.empty((count, 4, hi + 1))
    args = (rng, int(lo), int(hi), float(plf[0]), float(plf[1]), float(spec.pole_damping_range[0]),
            float(spec.pole_damping_range[1]), float(zlf[0]), float(zlf[1]),
            float(spec.zero_damping_range[0]), float(spec.zero_damping_range[1]),
            float(spec.complex_fraction), float(np.log(0.5)), float(np.log(2.0)), float(spec.coupling),
            float(spec.min_pole_separation), float(spec.min_zero_distance), float(spec.max_condition),
            float(spec.max_gain_range), np.ascontiguousarray(powers), int(max_attempts), rec)
    ns = _KERNEL["loop"](*args, poles, num)[:count]
    out: list[tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...], tuple[np.ndarray, np.ndarray]] | None] = []
    for n, p, c in zip(ns, poles, num):
        if n < 0:
            out.append(None)
            break
        p, c = p[:n].copy(), np.ascontiguousarray(c[:, :n + 1])
        Ad, Bd, Cd, Dd, Tz, Uz = _KERNEL["realise"](p, c, n, float(dt))
        out.append((p, c.reshape(2, 2, n + 1), (Ad, Bd, Cd, Dd), (Tz, Uz)))
    return out
