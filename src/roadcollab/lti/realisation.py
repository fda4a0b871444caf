"""Discrete state-space realisations and their interconnection (series, similarity)."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar, cast

import numpy as np
import numpy.typing as npt
import scipy.linalg

from .._validation import freeze, is_frozen
from .response import content_key, dlti_frequency_response
from .blockdiag import complex_schur as _complex_schur
from ._hide_kernel import qr_similarity as _compiled_qr_similarity
from .kernels import kernel_path
from .stability import hidden_radius_and_gain, spectral_radius_and_gain

if TYPE_CHECKING:
    import control

_T = TypeVar("_T")


__all__ = ["StateSpaceData", "SystemCache", "continuous_poles", "series", "minreal", "random_orthogonal", "similarity",
           "random_similarity"]


def continuous_poles(poles_z: npt.ArrayLike, dt: float) -> np.ndarray:
    """Discrete poles mapped to the s-plane, ``log(z) / dt`` (rad/s; ``-inf`` for ``z = 0``).

    Parameters
    ----------
    poles_z : array_like
        Discrete poles.
    dt : float
        Sample period, s.

    Returns
    -------
    complex ndarray
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.asarray(np.log(np.asarray(poles_z, dtype=complex)) / dt)


@dataclass(frozen=True, eq=False)
class StateSpaceData:
    """A discrete-time state-space realisation ``(A, B, C, D)`` with sample period ``dt``.

    Attributes
    ----------
    A : (n, n) ndarray
    B : (n, m) ndarray
    C : (p, n) ndarray
    D : (p, m) ndarray
    dt : float
        Sample period, s.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float

    @property
    def order(self) -> int:
        return int(self.A.shape[0])

    def poles(self) -> np.ndarray:
        """Discrete poles (eigenvalues of A)."""
        return np.linalg.eigvals(self.A) if self.order else np.zeros(0, complex)

    def continuous_poles(self) -> np.ndarray:
        """Poles mapped back to the s-plane, ``log(z) / dt`` (rad/s)."""
        return continuous_poles(self.poles(), self.dt)

    def frequency_response(self, omega_dt: np.ndarray) -> np.ndarray:
        """Response at ``z = exp(j omega_dt)``, shape (M, p, m).

        A pure function of the realisation (a receiver evaluates a sender's systems through
        :func:`~roadcollab.lti.response.received_response` and its cache instead). The
        last response is also memoised on this object, keyed by the exact bytes of the matrices
        and the frequencies (a sender's ``Psi`` is evaluated once for obfuscating and again, on the
        same bins, when Theorem 1 is measured: 2.9 s of the default reproduction, measured), except
        for a system decoded through a :class:`SystemCache`, whose receiver's cache keeps responses.

        Parameters
        ----------
        omega_dt : (M,) array_like
            Normalised frequencies, rad/sample.

        Returns
        -------
        (M, p, m) complex ndarray
        """
        omega_dt = np.asarray(omega_dt, dtype=float)
        # A system a receiver decoded through its SystemCache is evaluated by received_response through
        # its FrequencyResponseCache, which keeps what is seen again: no memo here (its copy of a
        # 3000-bin response cost 60 us per received T~, S~, measured).
        received = bool(self.__dict__.get("_received"))
        full_key = None if received else content_key(self.A, self.B, self.C, self.D, omega_dt)
        last = None if full_key is None else self._memo_get("_response", full_key)
        if last is not None:
            return np.array(last, copy=True)
        key = self._digest()
        H = dlti_frequency_response(self.A, self.B, self.C, self.D, omega_dt, schur=self._memo_get("_schur", key),
                                    eig=self._memo_get("_eig", key))
        if full_key is not None:
            object.__setattr__(self, "_response", (full_key, H.copy()))
        return H

    def _digest(self) -> bytes:
        """The exact bytes of ``A`` (with its shape): the key of this object's memos. The bytes
        themselves, not a hash of them, so a memo can never be applied to another matrix. Kept while
        ``A`` cannot change (:func:`~roadcollab._validation.is_frozen`, checked at every use): a
        ``paper`` vehicle-segment asks 16 times, 1.1 us each for a 22-state ``A`` (measured)."""
        memo = self.__dict__.get("_digest_memo")
        if memo is not None and memo[0] is self.A and is_frozen(self.A):
            return cast(bytes, memo[1])
        A = np.ascontiguousarray(self.A, dtype=float)
        key = repr(A.shape).encode() + A.tobytes()
        if is_frozen(self.A):
            object.__setattr__(self, "_digest_memo", (self.A, key))
        return key

    def _memo_get(self, name: str, key: bytes) -> Any:
        """The value memoised as ``name`` under exactly ``key``, else None."""
        memo = self.__dict__.get(name)
        return memo[1] if memo is not None and memo[0] == key else None

    def _memo(self, name: str, compute: Callable[[], _T]) -> _T:
        """The value memoised as ``name`` for the current ``A``, computing (and keeping) it if needed
        (a frozen dataclass: a private memo, not a field)."""
        key = self._digest()
        value = self._memo_get(name, key)
        if value is None:
            value = compute()
            object.__setattr__(self, name, (key, value))
        return cast(_T, value)

    def schur(self) -> tuple[np.ndarray, np.ndarray]:
        """Complex Schur form ``A = U T U^H``, memoised on this object (keyed by ``A``'s bytes).

        The stability certificate and the frequency response of a received system share it.

        Returns
        -------
        T, U : (n, n) complex ndarray
        """
        return self._memo("_schur", lambda: _complex_schur(np.asarray(self.A, dtype=float)))

    def seed_schur(self, T: np.ndarray, U: np.ndarray) -> None:
        """Keep ``A = U T U^H`` (the caller vouches) as :meth:`schur` of the current ``A``. A certificate
        from it is still checked against ``A`` itself.

        Parameters
        ----------
        T, U : (n, n) complex ndarray
            ``T`` upper triangular, ``U`` unitary.
        """
        object.__setattr__(self, "_schur", (self._digest(), (T, U)))

    def receiver_schur(self) -> tuple[np.ndarray, np.ndarray]:
        """The Schur form a receiver of these bytes has: :meth:`schur` of a system decoded through a
        :class:`SystemCache` (its certificate made it), else the same computation, not kept (the system of
        a sender in the same process keeps its memos as they were).

        Returns
        -------
        T, U : (n, n) complex ndarray
        """
        return self.schur() if self.__dict__.get("_received") else _complex_schur(np.asarray(self.A, dtype=float))

    def eig(self) -> tuple[np.ndarray, np.ndarray]:
        """``np.linalg.eig(A)``, memoised on this object (keyed by ``A``'s bytes).

        The stability certificate and the frequency response share it (the response needs it to
        choose between the pole-residue and Schur paths: computing it twice cost 0.08-0.1 ms per
        obfuscated system, measured).

        Returns
        -------
        lam : (n,) complex ndarray
        V : (n, n) complex ndarray
        """
        def eig() -> tuple[np.ndarray, np.ndarray]:
            lam, V = np.linalg.eig(np.asarray(self.A, dtype=float))
            return np.asarray(lam), np.asarray(V)

        return self._memo("_eig", eig)

    def stability(self) -> tuple[float, float]:
        """Spectral radius of ``A`` and its certified transient gain (:mod:`~roadcollab.lti.stability`).

        Memoised on this object by ``A``'s exact bytes, so a message validated when it is
        built is not certified again when it is encoded (0.3-0.6 ms per system measured), while a
        changed ``A`` (arrays are mutable) is certified afresh. The certificate comes from the
        memoised eigendecomposition (:meth:`eig`) or, when that fails, the memoised Schur form
        (:meth:`schur`); the frequency response reuses whichever exists. A system a receiver got
        through its :class:`SystemCache` is certified from the Schur form directly: the receiver
        evaluates an obfuscated system through that form anyway (its eigenvectors are too ill
        conditioned for the pole-residue path), so the eigen route would be extra work. On the
        compiled path every system is certified that way, so a sender's check of its outgoing
        message is the receiver's check of the same bytes.

        Returns
        -------
        radius, gain : float
            As :func:`~roadcollab.lti.stability.spectral_radius_and_gain`.
        """
        return self._memo("_stability", self._certify)

    def _certify(self) -> tuple[float, float]:
        """:meth:`stability` without the memo."""
        A = np.asarray(self.A, dtype=float)
        if self.order == 0 or not np.isfinite(A).all():
            return spectral_radius_and_gain(A)
        if self.__dict__.get("_received"):
            return spectral_radius_and_gain(A, schur=self.schur())
        if kernel_path() == "compiled":
            form = self._memo_get("_cert_form", self._digest())
            if form is not None:
                # A hidden T~, S~ whose sender knows a triangular form from the parts' Schur forms
                # (random_similarity): the certificate without a Schur decomposition, 2 x 45 us of
                # every paper segment (docs/speed.md, "Ninth pass"); checked against A all the same.
                radius, gain = hidden_radius_and_gain(A, *form)
                if math.isfinite(gain):
                    return radius, gain
            # The computation a receiver makes on these bytes (the branch above): a Schur form instead
            # of an eigendecomposition (docs/speed.md, "Fifth pass"). Not memoised as the object's
            # Schur form, so its frequency response takes the same path as before.
            return spectral_radius_and_gain(A, schur=_complex_schur(A))
        return spectral_radius_and_gain(A, schur=self.schur, eig=self.eig())

    def to_control(self) -> control.StateSpace:
        """The realisation as a discrete :class:`control.StateSpace`."""
        import control

        return control.ss(self.A, self.B, self.C, self.D, self.dt)


class SystemCache:
    """Received realisations by content, so an unchanged sender system keeps its memos.

    A receiver decoding a message asks for the :class:`StateSpaceData` of the received bytes;
    when exactly those bytes (``A``, ``B``, ``C``, ``D``, ``dt``: the key is the bytes themselves,
    :func:`~roadcollab.lti.response.content_key`) were seen before it gets the same object back,
    whose stability certificate and Schur form are already memoised. The ``none`` mechanism sends
    the same ``T`` and ``S`` every segment: certifying them again cost 0.3-0.6 ms per segment.
    Least recently used entries are dropped beyond ``size``.

    Parameters
    ----------
    size : int
        Systems kept.
    """

    def __init__(self, size: int = 16) -> None:
        self.size = int(size)
        self._store: OrderedDict[bytes, StateSpaceData] = OrderedDict()

    def get(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, dt: float) -> StateSpaceData:
        """The system with exactly these arrays, from the cache when seen before.

        Parameters
        ----------
        A, B, C, D : ndarray
            The realisation (read-only arrays are kept as given).
        dt : float
            Sample period, s.

        Returns
        -------
        StateSpaceData
        """
        key = content_key(A, B, C, D, np.array([[dt]]))
        hit = self._store.get(key)
        if hit is not None:
            self._store.move_to_end(key)
            return hit
        sys = StateSpaceData(A, B, C, D, dt)
        object.__setattr__(sys, "_received", True)   # certified from its Schur form (see StateSpaceData.stability)
        self._store[key] = sys
        if len(self._store) > self.size:
            self._store.popitem(last=False)
        return sys


def series(first: StateSpaceData, second: StateSpaceData) -> StateSpaceData:
    """Realisation of ``second * first`` (``first`` acts on the input first).

    .. code-block:: text

        u -> [A1 B1; C1 D1] -> v -> [A2 B2; C2 D2] -> y

        A = [[A1,     0 ],      B = [[B1   ],
             [B2 C1,  A2]]           [B2 D1]]
        C = [D2 C1,  C2],       D = D2 D1

    Parameters
    ----------
    first, second : StateSpaceData
        Systems with the same sample period; ``first``'s outputs feed ``second``'s inputs.

    Returns
    -------
    StateSpaceData
        Order ``first.order + second.order``.
    """
    n1, n2 = first.order, second.order
    A = np.zeros((n1 + n2, n1 + n2))
    A[:n1, :n1] = first.A
    A[n1:, :n1] = second.B @ first.C
    A[n1:, n1:] = second.A
    B = np.vstack([first.B, second.B @ first.D])
    C = np.hstack([second.D @ first.C, second.C])
    D = second.D @ first.D
    return StateSpaceData(A, B, C, D, first.dt)


def minreal(sys: StateSpaceData, *, tol: float = 0.0) -> StateSpaceData:
    """Minimal realisation: the uncontrollable and unobservable states removed (SLICOT ``TB01PD``).

    The same call and padding as python-control's ``StateSpace.minreal`` (so the same realisation to
    the bit), without importing python-control: that import cost 1.33 s of the default reproduction
    for this one call, slycot's 0.1-0.5 s.

    Parameters
    ----------
    sys : StateSpaceData
    tol : float
        Tolerance of the controllability and observability rank decisions (0: SLICOT's default).

    Returns
    -------
    StateSpaceData
        Order ``nr <= sys.order``; own arrays (not views of SLICOT's work arrays).
    """
    n, (p, m) = sys.order, sys.D.shape
    if n == 0:
        return StateSpaceData(sys.A.copy(), sys.B.copy(), sys.C.copy(), sys.D.copy(), sys.dt)
    from slycot import tb01pd

    # TB01PD works on B (n, max(m, p)) and C (max(m, p), n) arrays (it dualises internally).
    B = np.empty((n, max(m, p)))
    B[:, :m] = sys.B
    C = np.empty((max(m, p), n))
    C[:p, :] = sys.C
    A, B, C, nr = tb01pd(n, m, p, np.array(sys.A, dtype=float), B, C, tol=tol)
    return StateSpaceData(A[:nr, :nr].copy(), B[:nr, :m].copy(), C[:p, :nr].copy(),
                          np.array(sys.D, dtype=float), sys.dt)


def random_orthogonal(n: int, rng: np.random.Generator) -> np.ndarray:
    """Haar-random orthogonal matrix (QR of a Gaussian matrix with sign fix).

    Parameters
    ----------
    n : int
        Size.
    rng : numpy.random.Generator

    Returns
    -------
    (n, n) ndarray
    """
    if n == 0:
        return np.zeros((0, 0))
    Q, R = np.linalg.qr(rng.standard_normal((n, n)))
    return Q * np.sign(np.diag(R))


def random_similarity(sys: StateSpaceData, rng: np.random.Generator, *,
                      schur: tuple[np.ndarray, np.ndarray] | None = None) -> StateSpaceData:
    """``similarity(sys, random_orthogonal(sys.order, rng), balance=True)``: the hiding transform of an
    obfuscated realisation. On the compiled path the ``QR`` factor, its sign fix and the products are
    one numba call (:mod:`~roadcollab.lti._hide_kernel`; same ``Q`` to round-off, the generator advanced
    by the same draw).

    Parameters
    ----------
    sys : StateSpaceData
    rng : numpy.random.Generator
    schur : (R, U), optional
        A complex Schur form of ``sys.A`` (e.g. :func:`~roadcollab.lti.composed_schur.series_schur`).
        On the compiled path the result keeps the triangular form it implies, and its stability
        certificate starts from that form instead of a Schur decomposition of its own
        (:meth:`StateSpaceData.stability`).

    Returns
    -------
    StateSpaceData
    """
    n = sys.order
    if kernel_path() != "compiled" or n == 0:
        return similarity(sys, random_orthogonal(n, rng), balance=True)
    G = rng.standard_normal((n, n))
    A, B, C, scale = _balanced(sys)
    A2, B2, C2, Q = _compiled_qr_similarity(G, A, B, C)
    out = StateSpaceData(A2, B2, C2, sys.D.copy(), sys.dt)
    freeze(out.A, out.B, out.C, out.D)     # new arrays, to be sent: their memos are found by identity
    if schur is not None:
        object.__setattr__(out, "_cert_form", (out._digest(), (schur[0], schur[1], scale, Q)))
    return out


def _balanced(sys: StateSpaceData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(A, B, C, scale)`` with the states scaled by LAPACK ``dgebal`` (powers of two, no permutation):
    ``D^-1 A D``, ``D^-1 B``, ``C D`` for ``D = diag(scale)``."""
    # LAPACK dgebal directly: what scipy.linalg.matrix_balance(A, permute=False, separate=True)
    # calls, the same output bit for bit, without its wrapper (29 -> 9 us at n = 18, measured).
    A, _, _, scale, info = scipy.linalg.lapack.dgebal(np.asarray(sys.A, dtype=float), scale=1, permute=0)
    if info < 0:
        raise ValueError(f"dgebal failed (info={info})")
    return A, sys.B / scale[:, None], sys.C * scale[None, :], scale


def similarity(sys: StateSpaceData, Q: np.ndarray, *, balance: bool = False) -> StateSpaceData:
    """Realisation ``(Q^T A Q, Q^T B, C Q, D)`` for orthogonal ``Q``: same transfer matrix,
    same conditioning, no visible block structure.

    Parameters
    ----------
    sys : StateSpaceData
    Q : (n, n) ndarray
        Orthogonal.
    balance : bool
        First scale the states by powers of two (``scipy.linalg.matrix_balance``, exact in
        floating point) so that the rows and columns of ``A`` have comparable norms. A series
        connection of high-gain systems carries coupling entries up to 1e3 x its dynamics, and
        the dense product ``Q^T A Q`` spreads their rounding into every entry. Measured on the
        obfuscated ``T~``, ``S~`` of the default reproduction (540 messages, the receiver's
        estimate from the obfuscated vs. the clear message): worst relative change 1.4e-8
        without balancing, 2.0e-10 with it (99th percentile 1.0e-10 vs 1.6e-11); against a
        40-digit reference one ``Psi1 S Psi2`` response went from 6e-9 to 4e-12 relative.
        Forming the product in extended precision, or as ``I + Q^T (A - I) Q``, changed
        neither figure.

    Returns
    -------
    StateSpaceData
    """
    A, B, C = _balanced(sys)[:3] if balance and sys.order else (sys.A, sys.B, sys.C)
    return StateSpaceData(Q.T @ A @ Q, Q.T @ B, C @ Q, sys.D.copy(), sys.dt)
