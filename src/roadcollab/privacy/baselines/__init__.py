"""Conventional privacy baselines, measured side by side with the obfuscating dynamics.

Three mechanisms the paper argues against, each applied to what vehicles exchange:

1. **Differential privacy** (:mod:`.dp`; Le Ny and Pappas, "Differentially private
   filtering", IEEE TAC 59(2), 2014): the Gaussian mechanism on the hardened message ``z``.
   Calibration uses the *analytic* Gaussian mechanism of Balle and Wang (ICML 2018),
   which is valid for every ``epsilon > 0``.
2. **Paillier homomorphic encryption** (:mod:`.paillier`, :mod:`.paillier_packed`; :mod:`phe` keys,
   gmpy2 arithmetic): as deployed, 36 fixed-point values per 2048-bit ciphertext and ``r^n``
   precomputed offline; the earlier one-ciphertext-per-number path with ``packing=False``.
3. **Authenticated encryption of the channel** (:mod:`.aead`, ChaCha20-Poly1305 from
   :mod:`cryptography`): protects against an eavesdropper only; the receiving vehicle still
   sees everything.

Randomness: numpy noise comes from ``np.random.default_rng(rng)`` and never from global
state. Paillier encryption and AEAD nonces use the operating system's secure randomness
(``phe`` draws its obfuscators with :class:`random.SystemRandom`, nonces come from
:func:`os.urandom`); that is intended and cannot be seeded.
"""

from .aead import (AEAD_KEY_BYTES, AEAD_NONCE_BYTES, AEAD_OVERHEAD_BYTES, AEAD_TAG_BYTES, aead_cost, new_key,
                   open_sealed, seal)
from .dp import DPSpec, classic_gaussian_sigma, dp_message, dp_sigmas, gaussian_sigma, l2_sensitivity
from .paillier import PAILLIER_REL_PRECISION, paillier_cost
from .timing import median_ms

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
