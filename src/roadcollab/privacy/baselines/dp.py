"""Differential-privacy baseline: the Gaussian mechanism on the hardened message ``z``.

After Le Ny and Pappas, "Differentially private filtering", IEEE TAC 59(2), 2014.
Calibration uses the *analytic* Gaussian mechanism of Balle and Wang (ICML 2018), which is
valid for every ``epsilon > 0``.

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

Randomness: the noise comes from ``np.random.default_rng(rng)`` and never from global state.
"""

from __future__ import annotations

from typing import Any, Callable

import math
from dataclasses import dataclass

import numpy as np
import scipy.special

from ..._validation import check_matrix, check_nonnegative, check_positive, check_real
from ...errors import ParameterError
from ...lti.batch2x2 import sigma_max_2x2
from ...wire.message import InversionMessage

__all__ = ["DPSpec", "l2_sensitivity", "gaussian_sigma", "classic_gaussian_sigma", "dp_sigmas", "dp_message"]


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


def _check_delta(delta: float) -> float:
    """``delta`` of (epsilon, delta)-DP, checked to lie in the open interval (0, 1)."""
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


def l2_sensitivity(estimator: Any, rho: float) -> float:
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
    return float(la + math.log(-math.expm1(min(eps + lb - la, -1e-300))))


def _b_plus(v: float, eps: float) -> float:
    """``Phi(sqrt(eps v)) - e^eps Phi(-sqrt(eps (v + 2)))`` (terms of order 1, no cancellation issue)."""
    from scipy.stats import norm  # heavy: imported when a DP budget is computed

    return float(norm.cdf(math.sqrt(eps * v)) - math.exp(eps + scipy.special.log_ndtr(-math.sqrt(eps * (v + 2.0)))))


def _bracket_up(f: Callable[[float], float], start: float = 1.0) -> float:
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
    import scipy.optimize  # 0.07 s to import, for a root: here, not with every command (docs/speed.md)

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


def dp_sigmas(estimator: Any, spec: DPSpec = DPSpec()) -> dict[float, float]:
    """Analytic-Gaussian noise level for every ``epsilon`` of ``spec`` on one vehicle's message.

    Parameters
    ----------
    estimator : CollaborativeEstimator or compatible
        As for :func:`l2_sensitivity` (``P_f`` (K, 2, 2) and ``grid``).
    spec : DPSpec
        Privacy levels, ``delta`` and the adjacency radius ``rho`` (m/s^2).

    Returns
    -------
    dict
        ``{epsilon: sigma}``, sigma in m/s (units of ``z``).
    """
    if not isinstance(spec, DPSpec):
        raise ParameterError(f"spec must be a DPSpec, got {type(spec).__name__}")
    sens = l2_sensitivity(estimator, spec.rho)
    return {e: gaussian_sigma(e, spec.delta, sens) for e in spec.epsilons}


def dp_message(message: InversionMessage, sigma: float, *, rng: Any = None) -> InversionMessage:
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

