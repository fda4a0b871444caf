"""Frequency responses of state-space realisations, and a cache that their owner holds."""

from __future__ import annotations

from collections import OrderedDict
from typing import Protocol

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from .._validation import is_frozen
from .batch2x2 import inv2x2
from .blockdiag import block_response, block_schur
from ._pole_kernel import pole_residue_eval
from .kernels import keep_parts, kernel_path

__all__ = ["dlti_frequency_response", "unit_circle", "ss_response", "content_key", "received_response",
           "FrequencyResponseCache"]


class HasResponse(Protocol):
    """A realisation the cache can key and evaluate (:class:`~roadcollab.lti.realisation.StateSpaceData`)."""

    @property
    def A(self) -> np.ndarray: ...
    @property
    def B(self) -> np.ndarray: ...
    @property
    def C(self) -> np.ndarray: ...
    @property
    def D(self) -> np.ndarray: ...

    def frequency_response(self, omega_dt: np.ndarray) -> np.ndarray: ...

    def receiver_schur(self) -> tuple[np.ndarray, np.ndarray]: ...


def dlti_frequency_response(Ad: ArrayLike, Bd: ArrayLike, Cd: ArrayLike, Dd: ArrayLike, omega_dt: np.ndarray, *,
                            schur: tuple[np.ndarray, np.ndarray] | None = None,
                            eig: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """Frequency response ``C (zI - A)^-1 B + D`` at ``z = exp(j omega dt)``.

    Parameters
    ----------
    Ad, Bd, Cd, Dd : ndarray
        Discrete realisation, shapes (n, n), (n, m), (p, n), (p, m).
    omega_dt : (M,) ndarray
        Normalised frequencies, rad/sample.
    schur : (T, U), optional
        A complex Schur form of ``Ad`` already computed: the block-diagonal path is taken with it.
    eig : (lam, V), optional
        ``np.linalg.eig(Ad)`` if already computed (see :func:`ss_response`).

    Returns
    -------
    (M, p, m) complex ndarray
    """
    return ss_response(Ad, Bd, Cd, Dd, unit_circle(omega_dt), schur=schur, eig=eig)


_UNIT_CIRCLE: list[tuple[np.ndarray, np.ndarray]] = []
_UNIT_CIRCLE_BY_ARRAY: list[tuple[np.ndarray, np.ndarray]] = []


def unit_circle(omega_dt: ArrayLike) -> np.ndarray:
    """``exp(j omega_dt)``, read-only, kept for the last four frequency vectors.

    A vehicle evaluates its systems on the same one or two vectors (every bin, the active bins) all the
    time, and the 3000-3400 complex exponentials cost 55-60 us per evaluation (four per ``paper``
    message), against about 5 us to find them here. An entry is used only for a vector equal to it
    element for element, or for the very read-only array it was computed from (a grid's, found by
    identity while :func:`~roadcollab._validation.is_frozen` holds).

    Parameters
    ----------
    omega_dt : (M,) array_like
        Normalised frequencies, rad/sample.

    Returns
    -------
    (M,) complex ndarray
    """
    for source, z in tuple(_UNIT_CIRCLE_BY_ARRAY):
        # The same frozen array as before (a grid's): found without comparing its entries (3-5 us
        # each, four per paper segment). The list holds the array, so its id cannot be reused.
        if source is omega_dt and is_frozen(source):
            return z
    om = np.asarray(omega_dt, dtype=float)
    kept = [z for key, z in tuple(_UNIT_CIRCLE) if key.shape == om.shape and np.array_equal(key, om)]
    if kept:
        z = kept[0]
    else:
        z = np.exp(1j * om)
        z.flags.writeable = False
        keep_parts(z)             # its real and imaginary parts, as the compiled kernels take them
        key = om.copy()
        key.flags.writeable = False
        _UNIT_CIRCLE.insert(0, (key, z))
        del _UNIT_CIRCLE[4:]
    if isinstance(omega_dt, np.ndarray) and is_frozen(omega_dt):
        _UNIT_CIRCLE_BY_ARRAY.insert(0, (omega_dt, z))
        del _UNIT_CIRCLE_BY_ARRAY[4:]
    return z


def ss_response(A: ArrayLike, B: ArrayLike, C: ArrayLike, D: ArrayLike, points: np.ndarray, *, schur: tuple[np.ndarray, np.ndarray] | None = None,
                eig: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """``C (x I - A)^-1 B + D`` at complex points ``x`` (``s`` or ``z``), shape (M, p, m).

    Parameters
    ----------
    A, B, C, D : array_like
        Realisation, shapes (n, n), (n, m), (p, n), (p, m); with ``n = 0`` the result is ``D``
        at every point. Continuous (``A`` in 1/s) for ``s`` points, discrete for ``z`` points.
    points : complex array_like
        Evaluation points, flattened to (M,): ``s = j omega`` (rad/s) for a continuous
        realisation, ``z = exp(j omega dt)`` for a discrete one.
    schur : (T, U), optional
        A complex Schur form ``A = U T U^H`` already computed (a certified message's systems carry
        one): the block-diagonal path is taken directly.
    eig : (lam, V), optional
        ``np.linalg.eig(A)`` if already computed (a system's stability certificate memoises it):
        used instead of computing it again to choose between the pole-residue and Schur paths.

    Returns
    -------
    (M, p, m) complex ndarray
    """
    # Diagonalise once: (xI - A)^-1 = V diag(1/(x - lambda)) V^-1, so every output/input pair
    # is one matrix product [1/(x - lambda)] @ [Cv_pn Bv_nm] (about 10x faster than M solves).
    # Its error grows like cond(V) * eps, and near transmission zeros the partial fractions
    # cancel, so realisations with close or repeated poles (series connections) go through the
    # backward-stable complex Schur form instead. The limit cond(V) < 1e2 (not 1e3) is measured:
    # obfuscated S~ with cond(V) ~ 300 were evaluated 4x less accurately than by Schur at 0.5 Hz,
    # and the receiver's worst estimate change under Algorithm 2 fell from 1.2e-9 to 1.4e-10
    # (900 messages); the benchmark did not resolve a cost (paper 27 vs 29 ms, noise 2x).
    # Those go through the Schur form block-diagonalised into clusters of close eigenvalues
    # (:mod:`~roadcollab.lti.blockdiag`): as accurate as the full back substitution (obfuscated
    # T~, S~ of order 12-22 against a 40-digit reference: the same 1e-12..2e-11 relative per bin),
    # at 0.4-0.6 ms instead of 1.1-4 ms (measured on the loaded 2-core machine).
    x = np.asarray(points, dtype=complex)
    x = x if x.ndim == 1 else x.reshape(-1)      # a 1-D vector itself: the kernels find its parts by identity
    Af, Bf, Cf, Df = (np.asarray(a, dtype=float) for a in (A, B, C, D))
    p, m = Df.shape
    if Af.shape[0] == 0:
        empty: np.ndarray = np.broadcast_to(Df.astype(complex), (x.size, p, m)).copy()
        return empty
    if schur is None:
        lam, V = np.linalg.eig(Af) if eig is None else eig
        if np.linalg.cond(V) < 1e2:
            Cv = Cf @ V
            Bv = np.linalg.solve(V, Bf)
            R = (Cv[:, :, None] * Bv[None, :, :]).transpose(1, 0, 2).reshape(lam.size, p * m)
            if kernel_path() == "compiled":
                return pole_residue_eval(lam, R, Df, x)
            # np.reciprocal, not 1.0 / x: numpy's complex division (Smith's algorithm) was 7x
            # slower on 3000 x 18 points (1.2 ms vs 0.18 ms, measured); and laid out (n, M), whose
            # rows are long, rather than (M, n) with a short inner axis (2.5x faster for n = 4..8).
            H: np.ndarray = (np.reciprocal(x[None, :] - lam[:, None]).T @ R).reshape(x.size, p, m) + Df
            return H
    return block_response(block_schur(Af, Bf, Cf, schur=schur), Df, x)


def _schur_frequency_response(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, z: np.ndarray
                              ) -> np.ndarray:
    """``C (zI - A)^-1 B + D`` via ``A = U T U^H``: one back substitution for all ``z``.

    ``X`` is kept as (n, m, M) so each step is one BLAS product over every frequency
    (about 10x faster than a per-row einsum; measured 1 ms vs 10 ms for n = 20, M = 3400).
    """
    T, U = scipy.linalg.schur(A, output="complex")
    Bt = U.conj().T @ B
    Ct = C @ U
    n, m = B.shape
    X = np.empty((n, m, z.size), complex)
    inv_diag = 1.0 / (z[None, :] - np.diag(T)[:, None])          # (n, M), one pass
    for i in range(n - 1, -1, -1):
        if i + 1 < n:
            acc = (T[i, i + 1:] @ X[i + 1:].reshape(n - i - 1, m * z.size)).reshape(m, z.size)
            acc += Bt[i][:, None]
        else:
            acc = np.repeat(Bt[i][:, None].astype(complex), z.size, axis=1)
        acc *= inv_diag[i]
        X[i] = acc
    H = (Ct @ X.reshape(n, m * z.size)).reshape(C.shape[0], m, z.size)
    out: np.ndarray = H.transpose(2, 0, 1) + D
    return out


def content_key(*arrays: ArrayLike) -> bytes:
    """The exact bytes of float64 arrays with their shapes: a cache key that two different
    inputs can never share (no hash to collide; comparing keys of a few kB is microseconds).

    Parameters
    ----------
    *arrays : array_like

    Returns
    -------
    bytes
    """
    parts: list[bytes] = []
    for a in arrays:
        c = np.ascontiguousarray(a, dtype=float)
        parts += [repr(c.shape).encode(), c.tobytes()]
    return b"|".join(parts)


def received_response(system: HasResponse, omega_dt: np.ndarray) -> np.ndarray:
    """The response a receiver computes for a sender's realisation: a function of its bytes only.

    ``C (zI - A)^-1 B + D`` at ``z = exp(j omega_dt)`` through the complex Schur form of ``A``
    (``receiver_schur``), whether the system was decoded from bytes, with or without the
    receiver's :class:`~roadcollab.lti.realisation.SystemCache`, or handed over in memory by a sender
    in the same process. A sender's own object would otherwise take the path its memos choose (an
    eigendecomposition, then the pole-residue or the Schur path): the relay in memory and the
    relay over the wire then differed by up to 5e-13 in 72 of 80 ``paper`` estimates (measured).
    On one kernel path: memos are keyed by bytes, so a receiver whose caches were filled on the
    other path (:func:`~roadcollab.lti.kernels.use_kernels`) keeps that path's forms and responses.

    Parameters
    ----------
    system : StateSpaceData
    omega_dt : (M,) array_like
        Normalised frequencies, rad/sample.

    Returns
    -------
    (M, p, m) complex ndarray
    """
    A = np.asarray(system.A, dtype=float)
    if A.shape[0] == 0 or not np.isfinite(A).all():     # no Schur form: as the system itself evaluates
        return system.frequency_response(omega_dt)
    return dlti_frequency_response(A, system.B, system.C, system.D, omega_dt, schur=system.receiver_schur())


class FrequencyResponseCache:
    """A receiver's responses of received realisations on a grid (:func:`received_response`),
    memoised by content (least recently used).

    A receiving vehicle holds one: a sender's unchanged clear ``T`` and ``S`` are evaluated
    twice and then kept, an obfuscated message is new every time. The key is the exact bytes of
    ``A``, ``B``, ``C``, ``D`` and the frequencies (:func:`content_key`), so a hit is the response of
    exactly that realisation; results are identical with or without the cache (a pure function).

    A response is kept only when its realisation is seen a second time: on the first sighting only
    a 64-bit hash of the key is remembered (an admission filter: a hash collision can only admit a
    response early, never return a wrong one). ``paper`` sends new realisations every segment, and
    keeping each of them (about 0.2 MB) filled the cache with 64 responses, 14 MB per receiving
    vehicle, that were never hit again.

    Parameters
    ----------
    size : int
        Entries kept.
    """

    def __init__(self, size: int = 64) -> None:
        self.size = int(size)
        self._store: OrderedDict[tuple[bytes, bytes, bool], np.ndarray] = OrderedDict()
        self._seen: OrderedDict[int, None] = OrderedDict()
        self._grid: tuple[np.ndarray, bytes] | None = None

    def response(self, system: HasResponse, omega_dt: np.ndarray, *, inverse: bool = False) -> np.ndarray:
        """``received_response(system, omega_dt)``, read-only, from the cache when seen before.

        Parameters
        ----------
        system : StateSpaceData
        omega_dt : (M,) array_like
            Normalised frequencies, rad/sample.
        inverse : bool
            Return the per-bin inverse of the (2x2) response instead, memoised beside it (a
            receiver applies ``T^-1`` every segment: 0.1 ms per segment saved for an unchanged ``T``).

        Returns
        -------
        (M, p, m) complex ndarray
        """
        key = (content_key(system.A, system.B, system.C, system.D), self._grid_key(omega_dt), bool(inverse))
        hit = self._store.get(key)
        if hit is not None:
            self._store.move_to_end(key)
            return hit
        if inverse:
            H = inv2x2(self.response(system, omega_dt))
        else:
            H = received_response(system, np.asarray(omega_dt, dtype=float))
        H.setflags(write=False)
        tag = hash(key)
        if tag not in self._seen:           # first sighting: remember the key's hash only
            self._seen[tag] = None
            if len(self._seen) > 4 * self.size:
                self._seen.popitem(last=False)
            return H
        self._store[key] = H
        if len(self._store) > self.size:
            self._store.popitem(last=False)
        return H

    def _grid_key(self, omega_dt: np.ndarray) -> bytes:
        """:func:`content_key` of the frequencies, kept for the last frozen array passed (a receiver passes
        the same one every segment). Its 24 kB of bytes were copied and hashed into the key of every
        received ``T~`` and ``S~``: 2 x 4.5 us per ``paper`` segment (measured). The same bytes object is
        returned for the same array, so its hash is computed once. Kept only while the array cannot
        change: read-only, and owning its data or viewing read-only arrays only; the memo holds a
        reference, so the array's ``id`` cannot be reused meanwhile."""
        memo = self._grid
        if memo is not None and memo[0] is omega_dt and is_frozen(omega_dt):
            return memo[1]
        key = content_key(omega_dt)
        if is_frozen(omega_dt):
            self._grid = (omega_dt, key)
        return key

    def clear(self) -> None:
        """Forget every memoised response."""
        self._store.clear()
        self._seen.clear()
        self._grid = None
