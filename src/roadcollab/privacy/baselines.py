"""Conventional privacy baselines, measured side by side with the obfuscating dynamics.

Three mechanisms the paper argues against, each applied to what vehicles exchange:

1. **Differential privacy** (Le Ny and Pappas, "Differentially private filtering",
   IEEE TAC 59(2), 2014): the Gaussian mechanism on the hardened message ``z``.
   Calibration uses the *analytic* Gaussian mechanism of Balle and Wang (ICML 2018),
   which is valid for every ``epsilon > 0``.
2. **Paillier homomorphic encryption** (:mod:`phe`): one ciphertext per fixed-point number.
3. **Authenticated encryption of the channel** (ChaCha20-Poly1305 from :mod:`cryptography`):
   protects against an eavesdropper only; the receiving vehicle still sees everything.

Differential-privacy model
--------------------------
Adjacency is per vehicle: two measurement records ``y, y'`` (N x 2, m/s^2) of one vehicle
are adjacent when ``||y - y'||_2 <= rho`` (l2 norm over the whole record, all samples and
both channels). The released map is the hardened exchange

.. math:: y \\mapsto z = W \\hat P^{-1} y,

applied per bin on the zero-padded DFT grid of ``nfft`` samples, i.e. a circular
convolution of the zero-padded record. By Parseval (the DFT is a scaled unitary map and the
bins ``k`` and ``nfft - k`` carry complex-conjugate 2x2 blocks with equal singular values)
its operator norm from ``R^(nfft x 2)`` to ``R^(nfft x 2)`` is

.. math:: \\|W \\hat P^{-1}\\| = \\max_k \\bar\\sigma\\big(W_k \\hat P^{-1}(e^{j\\omega_k})\\big),

the maximum over rfft bins of the largest singular value of the 2x2 block. A record has
only ``N <= nfft`` non-zero samples, which can only lower the norm, so
``rho * ||W P_hat^-1||`` is an upper bound on the l2 sensitivity (tight on the periodic
grid, and the calibration it gives is valid, at worst slightly conservative).

Randomness: numpy noise comes from ``np.random.default_rng(rng)`` and never from global
state. Paillier encryption and AEAD nonces use the operating system's secure randomness
(``phe`` draws its obfuscators with :class:`random.SystemRandom`, nonces come from
:func:`os.urandom`); that is intended and cannot be seeded.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.optimize
import scipy.special
from scipy.stats import norm

from .._validation import check_int, check_matrix, check_nonnegative, check_positive, check_real
from ..errors import MessageError, ParameterError
from ..lti.batch2x2 import sigma_max_2x2
from ..wire.message import ExchangeMessage, InversionMessage

__all__ = [
    "median_ms",
    "DPSpec",
    "l2_sensitivity",
    "gaussian_sigma",
    "classic_gaussian_sigma",
    "dp_sigmas",
    "dp_message",
    "PAILLIER_REL_PRECISION",
    "paillier_cost",
    "AEAD_KEY_BYTES",
    "AEAD_NONCE_BYTES",
    "AEAD_TAG_BYTES",
    "AEAD_OVERHEAD_BYTES",
    "new_key",
    "seal",
    "open_sealed",
    "aead_cost",
]


# ---------------------------------------------------------------------------------------------
# Timing
# ---------------------------------------------------------------------------------------------
def median_ms(fn: Callable[[], object], repeats: int) -> float:
    """Median wall-clock time of ``repeats`` calls of ``fn()``, ms.

    Each call is timed on its own with :func:`time.perf_counter`; the return values are
    discarded. The median is robust against the occasional garbage collection or scheduler
    pause.

    Parameters
    ----------
    fn : callable
        Called without arguments.
    repeats : int
        Number of timed calls (>= 1). There is no warm-up call.

    Returns
    -------
    float
        Median duration of one call, milliseconds.
    """
    if not callable(fn):
        raise ParameterError(f"fn must be callable, got {type(fn).__name__}")
    repeats = check_int("repeats", repeats, low=1)
    times = np.empty(repeats)
    for i in range(repeats):
        t0 = time.perf_counter()
        fn()
        times[i] = time.perf_counter() - t0
    return float(np.median(times) * 1e3)


# ---------------------------------------------------------------------------------------------
# 1. Differential privacy: Gaussian mechanism on z
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DPSpec:
    """Privacy levels of the differential-privacy baseline.

    Parameters
    ----------
    epsilons : tuple of float
        Privacy levels ``epsilon`` (> 0, dimensionless) evaluated side by side.
    delta : float
        ``delta`` of (epsilon, delta)-DP, in (0, 1).
    rho : float
        Adjacency radius, m/s^2: records ``y, y'`` (N x 2 body-tip accelerations) of one
        vehicle are adjacent when ``||y - y'||_2 <= rho``, the l2 norm taken over the whole
        record (every sample of both channels), not per sample.
    """

    epsilons: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0)
    delta: float = 1e-5
    rho: float = 0.5

    def __post_init__(self) -> None:
        try:
            eps = tuple(self.epsilons)
        except TypeError as err:
            raise ParameterError(f"epsilons must be a sequence of numbers, got {type(self.epsilons).__name__}") \
                from err
        if not eps:
            raise ParameterError("epsilons must not be empty")
        object.__setattr__(self, "epsilons", tuple(check_positive("epsilons[]", e) for e in eps))
        object.__setattr__(self, "delta", _check_delta(self.delta))
        object.__setattr__(self, "rho", check_positive("rho", self.rho))


def _check_delta(delta) -> float:
    return check_real("delta", delta, low=0.0, high=1.0, low_open=True, high_open=True)


def _bin_gains(P: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Largest singular value of ``weight[k] * inv(P[k])`` per bin (0 where weight is 0).

    Closed form for 2x2 blocks: ``sigma_max(P^-1) = 1 / sigma_min(P) = sigma_max(P) / |det P|``
    with ``sigma_max(P)^2 = (F + sqrt(F^2 - 4 |det P|^2)) / 2`` and ``F = ||P||_F^2``; the
    inverse is never formed.
    """
    gains = np.zeros(weight.shape)
    act = weight > 0
    smax, det = sigma_max_2x2(P[act])
    if np.any(det == 0.0):
        k = int(np.flatnonzero(act)[np.flatnonzero(det == 0.0)[0]])
        raise ParameterError(f"estimator.P_f is singular at active bin {k}: the sensitivity is unbounded")
    gains[act] = weight[act] * smax / det
    return gains


def l2_sensitivity(estimator, rho: float) -> float:
    """l2 sensitivity of the hardened message ``z = W P_hat^-1 y`` of one vehicle.

    Parameters
    ----------
    estimator : CollaborativeEstimator or compatible
        Anything with ``P_f`` (K, 2, 2), the nominal plant response on the rfft bins, and
        ``grid`` (:class:`~roadcollab.estimation.grid.SegmentGrid`, for ``weight``).
    rho : float
        Adjacency radius, m/s^2 (l2 norm over the record, see :class:`DPSpec`).

    Returns
    -------
    float
        ``rho * max_k sigma_max(W_k P_hat^-1(k))``, m/s: the largest l2 distance (over all
        ``nfft x 2`` samples of ``z``) between the messages of two adjacent records. Exact
        operator norm on the periodic grid, an upper bound for zero-padded records.

    Raises
    ------
    ParameterError
        If ``rho <= 0``, the estimator lacks a fitting ``P_f``/``grid``, or ``P_hat`` is
        singular at a bin where ``W > 0``.
    """
    rho = check_positive("rho", rho)
    grid = getattr(estimator, "grid", None)
    # The weight actually applied to z (the regulariser of the inverse), when the grid has one.
    weight = getattr(grid, "reg_weight", None)
    if weight is None:
        weight = getattr(grid, "weight", None)
    if weight is None or not hasattr(estimator, "P_f"):
        raise ParameterError(f"estimator must have P_f and grid.weight, got {type(estimator).__name__}")
    weight = check_matrix("estimator.grid.weight", weight, (None,))
    P = check_matrix("estimator.P_f", estimator.P_f, (weight.size, 2, 2), dtype=complex)
    return rho * float(np.max(_bin_gains(P, weight), initial=0.0))


def classic_gaussian_sigma(epsilon: float, delta: float, sensitivity: float) -> float:
    """Classic Gaussian-mechanism noise, ``sqrt(2 ln(1.25/delta)) * sensitivity / epsilon``.

    Dwork and Roth (2014), Theorem A.1. Only valid for ``0 < epsilon < 1`` (and it is loose
    there); kept as a reference for :func:`gaussian_sigma`.

    Parameters
    ----------
    epsilon : float
        In (0, 1).
    delta : float
        In (0, 1).
    sensitivity : float
        l2 sensitivity (>= 0), in the units of the released signal.

    Returns
    -------
    float
        Standard deviation, units of ``sensitivity``.
    """
    epsilon = check_real("epsilon", epsilon, low=0.0, high=1.0, low_open=True, high_open=True)
    delta = _check_delta(delta)
    sensitivity = check_nonnegative("sensitivity", sensitivity)
    return math.sqrt(2.0 * math.log(1.25 / delta)) * sensitivity / epsilon


def _log_b_minus(u: float, eps: float) -> float:
    """``log(Phi(-sqrt(eps u)) - e^eps Phi(-sqrt(eps (u + 2))))`` without cancellation or underflow."""
    la = scipy.special.log_ndtr(-math.sqrt(eps * u))
    lb = scipy.special.log_ndtr(-math.sqrt(eps * (u + 2.0)))
    # The difference is positive for every u >= 0 (the ratio of the two terms is < 1).
    return la + math.log(-math.expm1(min(eps + lb - la, -1e-300)))


def _b_plus(v: float, eps: float) -> float:
    """``Phi(sqrt(eps v)) - e^eps Phi(-sqrt(eps (v + 2)))`` (terms of order 1, no cancellation issue)."""
    return float(norm.cdf(math.sqrt(eps * v)) - math.exp(eps + scipy.special.log_ndtr(-math.sqrt(eps * (v + 2.0)))))


def _bracket_up(f, start: float = 1.0) -> float:
    """Smallest ``start * 2**i`` with ``f(x) <= 0`` (f decreasing)."""
    x = start
    while f(x) > 0.0:
        x *= 2.0
        if x > 1e300:  # pragma: no cover - only for absurd (epsilon, delta)
            raise ParameterError("gaussian_sigma: no finite noise level reaches the requested (epsilon, delta)")
    return x


def gaussian_sigma(epsilon: float, delta: float, sensitivity: float) -> float:
    """Noise level of the analytic Gaussian mechanism (Balle and Wang, ICML 2018, Algorithm 1).

    The smallest ``sigma`` for which adding ``N(0, sigma^2 I)`` to a function of l2
    sensitivity ``Delta`` is (epsilon, delta)-DP; it solves

    .. math:: \\Phi\\Big(\\frac{\\Delta}{2\\sigma} - \\frac{\\epsilon\\sigma}{\\Delta}\\Big)
              - e^{\\epsilon}\\,\\Phi\\Big(-\\frac{\\Delta}{2\\sigma} - \\frac{\\epsilon\\sigma}{\\Delta}\\Big)
              = \\delta .

    Unlike the classic ``sqrt(2 ln(1.25/delta)) Delta / epsilon`` (:func:`classic_gaussian_sigma`),
    which is only valid for ``epsilon < 1``, this is exact for every ``epsilon > 0`` and
    smaller than the classic value where both apply. Following Algorithm 1, with
    ``delta_0 = Phi(0) - e^eps Phi(-sqrt(2 eps))``: for ``delta >= delta_0`` find
    ``v* = sup{v >= 0: B+(v) <= delta}`` and ``alpha = sqrt(1 + v*/2) - sqrt(v*/2)``,
    otherwise ``u* = inf{u >= 0: B-(u) <= delta}`` and ``alpha = sqrt(1 + u*/2) + sqrt(u*/2)``;
    then ``sigma = alpha Delta / sqrt(2 eps)``. Roots by :func:`scipy.optimize.brentq`; the
    ``B-`` branch (every practical ``delta``) is solved in log space, accurate for tiny
    ``delta`` and large ``epsilon``.

    Parameters
    ----------
    epsilon : float
        > 0.
    delta : float
        In (0, 1).
    sensitivity : float
        l2 sensitivity ``Delta`` (>= 0), units of the released signal (m/s for ``z``).

    Returns
    -------
    float
        Noise standard deviation per sample, units of ``sensitivity`` (0 if it is 0).
    """
    eps = check_positive("epsilon", epsilon)
    delta = _check_delta(delta)
    sensitivity = check_nonnegative("sensitivity", sensitivity)
    if sensitivity == 0.0:
        return 0.0
    delta0 = _b_plus(0.0, eps)
    if delta >= delta0:
        # B+ increases from delta0 (v = 0) to 1 (v -> inf): v* is its crossing of delta.
        def f(v: float) -> float:
            return _b_plus(v, eps) - delta

        if f(0.0) == 0.0:
            v = 0.0
        else:
            v = scipy.optimize.brentq(f, 0.0, _bracket_up(lambda x: -f(x)), xtol=1e-300, rtol=4 * np.finfo(float).eps,
                                      maxiter=500)
        alpha = math.sqrt(1.0 + v / 2.0) - math.sqrt(v / 2.0)
    else:
        # B- decreases from delta0 (u = 0) to 0 (u -> inf): u* is its crossing of delta.
        log_delta = math.log(delta)

        def g(u: float) -> float:
            return _log_b_minus(u, eps) - log_delta

        u = scipy.optimize.brentq(g, 0.0, _bracket_up(g), xtol=1e-300, rtol=4 * np.finfo(float).eps, maxiter=500)
        alpha = math.sqrt(1.0 + u / 2.0) + math.sqrt(u / 2.0)
    return alpha * sensitivity / math.sqrt(2.0 * eps)


def dp_sigmas(estimator, spec: DPSpec = DPSpec()) -> dict[float, float]:
    """Analytic-Gaussian noise level for every ``epsilon`` of ``spec`` on one vehicle's message.

    Returns
    -------
    dict
        ``{epsilon: sigma}``, sigma in m/s (units of ``z``).
    """
    if not isinstance(spec, DPSpec):
        raise ParameterError(f"spec must be a DPSpec, got {type(spec).__name__}")
    sens = l2_sensitivity(estimator, spec.rho)
    return {e: gaussian_sigma(e, spec.delta, sens) for e in spec.epsilons}


def dp_message(message: InversionMessage, sigma: float, *, rng=None) -> InversionMessage:
    """Gaussian mechanism on a hardened message: ``z + N(0, sigma^2)`` on every sample.

    Parameters
    ----------
    message : InversionMessage
        A ``"hardened"`` message (one vehicle's ``z``); :func:`l2_sensitivity` calibrates
        for exactly that release.
    sigma : float
        Noise standard deviation (>= 0), m/s, e.g. from :func:`gaussian_sigma`.
    rng : None, int or numpy.random.Generator
        Passed to :func:`numpy.random.default_rng`.

    Returns
    -------
    InversionMessage
        A new ``"hardened"`` message (same grid and count) whose ``z`` has i.i.d.
        ``N(0, sigma^2)`` added to all ``nfft x 2`` samples, including the padded tail.
    """
    if not isinstance(message, InversionMessage):
        raise ParameterError(f"message must be an InversionMessage, got {type(message).__name__}")
    if message.mechanism != "hardened":
        raise ParameterError(f"message must be a 'hardened' message (one vehicle's z), got {message.mechanism!r}")
    z = check_matrix("message.z", message.z, (None, 2))
    sigma = check_nonnegative("sigma", sigma)
    gen = np.random.default_rng(rng)
    return InversionMessage(mechanism="hardened", sample_rate=message.sample_rate, n_samples=message.n_samples,
                            z=z + sigma * gen.standard_normal(z.shape), count=message.count)


# ---------------------------------------------------------------------------------------------
# 2. Paillier homomorphic encryption
# ---------------------------------------------------------------------------------------------
PAILLIER_REL_PRECISION = 1e-13
"""Default fixed-point resolution of :func:`paillier_cost`, relative to the message's peak magnitude."""


def _message_values(values) -> np.ndarray:
    if isinstance(values, InversionMessage):
        values = values.z
    arr = check_matrix("values", values, None).ravel()
    if arr.size == 0:
        raise ParameterError("values must contain at least one number, got 0")
    return arr


def _check_keypair(keypair, key_bits: int):
    from phe import paillier

    if (not isinstance(keypair, tuple) or len(keypair) != 2
            or not isinstance(keypair[0], paillier.PaillierPublicKey)
            or not isinstance(keypair[1], paillier.PaillierPrivateKey)):
        raise ParameterError("keypair must be a (PaillierPublicKey, PaillierPrivateKey) tuple, "
                             f"got {type(keypair).__name__}")
    pub, priv = keypair
    if priv.public_key != pub:
        raise ParameterError("keypair: the private key does not belong to the public key")
    if pub.n.bit_length() != key_bits:
        raise ParameterError(f"keypair has a {pub.n.bit_length()}-bit modulus, key_bits is {key_bits}")
    return pub, priv


def paillier_cost(values, *, key_bits: int = 2048, sample: int = 32, rng=None, keypair=None,
                  precision: float | None = None) -> dict:
    """Cost of sending a message as Paillier ciphertexts, one per fixed-point number (:mod:`phe`).

    Every value is encrypted separately with ``public_key.encrypt(x, precision=p)``, which
    stores ``round(x / 16**e)`` with the fixed exponent ``e = floor(log16(p))`` (resolution
    ``16**e <= p``). A ciphertext travels as the integer ``c`` modulo ``n^2`` plus its
    exponent: ``(c.bit_length() + 7) // 8 + 4`` bytes.

    Parameters
    ----------
    values : array_like or InversionMessage
        The numbers of one message (any shape, flattened; ``z`` of an InversionMessage).
    key_bits : int
        Modulus length, bits (2048 for the reported cost; 512 keeps tests fast).
    sample : int
        If there are more values than this, encrypt ``sample`` values chosen at random
        (without replacement) and extrapolate time and bytes to the whole message.
    rng : None, int or numpy.random.Generator
        Chooses the sample (numpy). Encryption itself draws its obfuscator with ``phe``'s
        secure randomness (:class:`random.SystemRandom`), which is intended and not seeded.
    keypair : (PaillierPublicKey, PaillierPrivateKey), optional
        Precomputed keys (2048-bit generation takes seconds); its modulus must have
        ``key_bits`` bits. Key generation is then not timed.
    precision : float, optional
        Absolute fixed-point resolution, units of ``values``. Default
        ``PAILLIER_REL_PRECISION * max|values|`` (1e-13 of the message's full scale, i.e.
        about 43 bits, plenty for double-precision signals).

    Returns
    -------
    dict
        ``ms_per_message`` (float, ms to encrypt every value), ``bytes_per_message`` (int),
        ``keygen_ms`` (float, ms; NaN when ``keypair`` was given), ``ms_per_value`` (median
        encryption time of one value, ms), ``decrypt_ms_per_value`` (median, ms),
        ``bytes_per_value`` (mean over the encrypted values),
        ``n_values`` (int), ``extrapolated_from`` (number of values actually encrypted if
        the totals were extrapolated, else None), ``key_bits``, ``precision`` (absolute),
        ``gmpy2`` (bool: whether ``phe`` uses gmpy2 for modular arithmetic; pure-Python
        ``pow`` is several times slower).

    Raises
    ------
    ParameterError
        For bad arguments.
    RuntimeError
        If a decrypted sample value differs from the original by more than
        ``max(1e-12 * max|values|, precision)`` (the round trip is checked on every sample).
    """
    from phe import paillier, util

    x = _message_values(values)
    key_bits = check_int("key_bits", key_bits, low=256, high=16384)
    sample = check_int("sample", sample, low=1)
    scale = float(np.max(np.abs(x)))
    if scale == 0.0:
        scale = 1.0
    if precision is None:
        precision = PAILLIER_REL_PRECISION * scale
    precision = check_positive("precision", precision)
    gen = np.random.default_rng(rng)

    n = x.size
    extrapolated = n > sample
    chosen = x[np.sort(gen.choice(n, size=sample, replace=False))] if extrapolated else x
    chosen = [float(v) for v in chosen]

    if keypair is None:
        t0 = time.perf_counter()
        pub, priv = paillier.generate_paillier_keypair(n_length=key_bits)
        keygen_ms = (time.perf_counter() - t0) * 1e3
    else:
        pub, priv = _check_keypair(keypair, key_bits)
        keygen_ms = float("nan")

    encrypted: list = []
    it = iter(chosen)
    enc_ms = median_ms(lambda: encrypted.append(pub.encrypt(next(it), precision=precision)), len(chosen))
    decrypted: list = []
    it_c = iter(encrypted)
    dec_ms = median_ms(lambda: decrypted.append(priv.decrypt(next(it_c))), len(encrypted))

    tol = max(1e-12 * scale, precision)
    err = np.abs(np.asarray(decrypted, dtype=float) - np.asarray(chosen))
    if not np.all(err <= tol):
        raise RuntimeError(f"Paillier round trip lost precision: error {float(err.max()):.3g} > tolerance {tol:.3g}")

    sizes = np.array([(c.ciphertext(be_secure=False).bit_length() + 7) // 8 + 4 for c in encrypted])
    nbytes = int(sizes.sum()) if not extrapolated else int(round(sizes.mean() * n))
    return {
        "ms_per_message": enc_ms * n,
        "bytes_per_message": nbytes,
        "keygen_ms": keygen_ms,
        "ms_per_value": enc_ms,
        "decrypt_ms_per_value": dec_ms,
        "bytes_per_value": float(sizes.mean()),
        "n_values": int(n),
        "extrapolated_from": len(chosen) if extrapolated else None,
        "key_bits": key_bits,
        "precision": precision,
        "gmpy2": bool(util.HAVE_GMP),
    }


# ---------------------------------------------------------------------------------------------
# 3. Authenticated encryption of the channel (eavesdropper model)
# ---------------------------------------------------------------------------------------------
AEAD_KEY_BYTES = 32
AEAD_NONCE_BYTES = 12
AEAD_TAG_BYTES = 16
AEAD_OVERHEAD_BYTES = AEAD_NONCE_BYTES + AEAD_TAG_BYTES   # 28


def _as_bytes(name: str, value, error=ParameterError) -> bytes:
    if not isinstance(value, (bytes, bytearray, memoryview)):
        raise error(f"{name} must be bytes, got {type(value).__name__}")
    return bytes(value)


def _check_key(key) -> bytes:
    key = _as_bytes("key", key)
    if len(key) != AEAD_KEY_BYTES:
        raise ParameterError(f"key must be {AEAD_KEY_BYTES} bytes, got {len(key)}")
    return key


def new_key() -> bytes:
    """A fresh random 32-byte ChaCha20-Poly1305 key (from :func:`os.urandom`)."""
    return os.urandom(AEAD_KEY_BYTES)


def seal(key: bytes, data: bytes, *, associated_data: bytes = b"") -> bytes:
    """Encrypt and authenticate ``data`` with ChaCha20-Poly1305.

    Parameters
    ----------
    key : bytes
        32 bytes, shared by the two vehicles (key agreement is out of scope).
    data : bytes
        Plaintext, e.g. :func:`roadcollab.wire.protocol.encode` of a message.
    associated_data : bytes
        Authenticated but not encrypted (e.g. a segment id); must match on opening.

    Returns
    -------
    bytes
        ``nonce (12 bytes, os.urandom) || ciphertext || tag (16 bytes)``:
        ``len(data) + 28`` bytes. A random 96-bit nonce per message is safe for far more
        messages than a vehicle sends under one key.
    """
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

    key = _check_key(key)
    data = _as_bytes("data", data)
    associated_data = _as_bytes("associated_data", associated_data)
    nonce = os.urandom(AEAD_NONCE_BYTES)
    return nonce + ChaCha20Poly1305(key).encrypt(nonce, data, associated_data)


def open_sealed(key: bytes, blob: bytes, *, associated_data: bytes = b"") -> bytes:
    """Verify and decrypt a blob made by :func:`seal`.

    Parameters
    ----------
    key : bytes
        The 32-byte key (a malformed key is a local error: :class:`ParameterError`).
    blob : bytes
        Untrusted input from the channel.
    associated_data : bytes
        Must equal the value used by :func:`seal`.

    Returns
    -------
    bytes
        The plaintext.

    Raises
    ------
    MessageError
        For anything that is not an authentic blob under this key and associated data:
        wrong key, any modified byte, truncation, non-bytes ``blob``. No other exception
        escapes for untrusted ``blob`` content.
    ParameterError
        If ``key`` is not 32 bytes or ``associated_data`` is not bytes (caller's own values).
    """
    from cryptography.exceptions import InvalidTag
    from cryptography.hazmat.primitives.ciphers.aead import ChaCha20Poly1305

    key = _check_key(key)
    associated_data = _as_bytes("associated_data", associated_data)
    blob = _as_bytes("blob", blob, MessageError)
    if len(blob) < AEAD_OVERHEAD_BYTES:
        raise MessageError(f"sealed blob truncated: {len(blob)} bytes, at least {AEAD_OVERHEAD_BYTES} expected")
    try:
        return ChaCha20Poly1305(key).decrypt(blob[:AEAD_NONCE_BYTES], blob[AEAD_NONCE_BYTES:], associated_data)
    except InvalidTag as err:
        raise MessageError("sealed blob failed authentication (wrong key, tampered or truncated)") from err
    except (OverflowError, ValueError) as err:
        raise MessageError(f"sealed blob refused: {err}") from err


def aead_cost(data, *, repeats: int = 20) -> dict:
    """Cost of sealing one message with ChaCha20-Poly1305 under a fresh key.

    Parameters
    ----------
    data : bytes or ExchangeMessage or InversionMessage
        The wire bytes (a message is encoded with :func:`roadcollab.wire.protocol.encode`).
    repeats : int
        Timed repetitions (>= 1).

    Returns
    -------
    dict
        ``ms_per_message`` (median seal time, ms), ``open_ms_per_message`` (median verify
        and decrypt time, ms), ``bytes_per_message`` (sealed length), ``overhead_bytes``
        (28: 12-byte nonce + 16-byte tag).
    """
    if isinstance(data, (ExchangeMessage, InversionMessage)):
        from ..wire.protocol import encode

        data = encode(data)
    data = _as_bytes("data", data)
    repeats = check_int("repeats", repeats, low=1)
    key = new_key()
    sealed = seal(key, data)
    if open_sealed(key, sealed) != data:  # pragma: no cover - would be a library bug
        raise RuntimeError("ChaCha20-Poly1305 round trip failed")
    return {
        "ms_per_message": median_ms(lambda: seal(key, data), repeats),
        "open_ms_per_message": median_ms(lambda: open_sealed(key, sealed), repeats),
        "bytes_per_message": len(sealed),
        "overhead_bytes": len(sealed) - len(data),
    }
