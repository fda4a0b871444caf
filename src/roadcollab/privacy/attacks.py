"""How much privacy the exchanges really give: attacks on what a receiver sees.

Threat model: the receiver (vehicle ``j+1``) is honest but curious and wants vehicle ``j``'s
dynamics, here the poles of ``S_j = -P_hat_j`` (its suspension model, which identifies the
car). Attacks:

``model_reduction`` (the paper's, Figs. 8-10)
    Knows the orders of ``T_j`` and ``S_j``; reduces ``S~_j`` to order 4 by discrete-time
    balanced truncation (SLICOT AB09AD with ``dico='D'``; python-control's ``balred`` treats
    every system as continuous, which keeps all discrete modes as "unstable") and reads off
    the poles.
``pole_intersection`` (Kerckhoffs: knows the mechanism)
    ``poles(T~) = poles(Psi1) + poles(T)`` and ``poles(S~) = poles(Psi1) + poles(S) +
    poles(Psi2)``; ``poles(T) > poles(P_hat)``. The common poles are ``Psi1``'s and the
    vehicle's; a physical prior on suspension modes (complex pairs, 0.5-3 Hz, damping
    0.05-0.7) picks two pairs.
``multiplicity`` (structural, stronger)
    The paper's ``Psi`` has one common denominator for its four entries, so each of its poles
    appears twice in any realisation of ``Psi`` (McMillan degree ``2n``), and so twice in
    ``S~``; the vehicle's four poles are the *simple* poles of ``S~``.

Against the hardened exchange nothing but the signal ``z_j = W P_hat_j^-1 y_j`` is sent. Each
attack then works from signals, granting the attacker the true road ``w`` (band-limited like
``z``): ``w - z = (P_j^-1 P_hat_j - I) z`` (noise aside), whose poles include those of
``P_hat_j``. ``model_reduction`` fits a high-order common-denominator ARX model of that map
and balanced-truncates it to order 4; ``pole_intersection`` fits an order-8 ARX model and
applies the physical prior; ``multiplicity`` intersects the ARX poles of two segments of the
same vehicle. An attack *succeeds* on a message when every pole of ``S_j`` is recovered
within 1 % relative error after optimal (Hungarian) matching.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike
import scipy.optimize

from ..errors import ParameterError
from ..wire.message import ExchangeMessage
from ..lti.arx import arx_poles, arx_state_space
from ..lti.realisation import StateSpaceData, continuous_poles

__all__ = ["PhysicalPrior", "pole_errors", "select_by_prior", "attack_model_reduction",
           "attack_pole_intersection", "attack_multiplicity", "attack_signals_reduction",
           "attack_signals_prior", "attack_signals_intersection", "intersect_pole_sets",
           "SUCCESS_TOLERANCE",
           "ATTACKS"]

#: Relative pole error below which a pole counts as recovered.
SUCCESS_TOLERANCE = 0.01
ATTACKS = ("model_reduction", "pole_intersection", "multiplicity")


@dataclass(frozen=True)
class PhysicalPrior:
    """What an attacker knows of suspension modes: complex pairs in a frequency and damping box.

    Parameters
    ----------
    frequency_range : (float, float)
        Natural frequency, Hz.
    damping_range : (float, float)
        Damping ratio.
    center_frequency, center_damping : float
        Most plausible mode (ranking among candidates), Hz and ratio.
    """

    frequency_range: tuple[float, float] = (0.5, 3.0)
    damping_range: tuple[float, float] = (0.05, 0.7)
    center_frequency: float = 1.4
    center_damping: float = 0.3

    def admits(self, p: complex) -> bool:
        wn = abs(p)
        if p.imag <= 0 or wn == 0:
            return False
        f, zeta = wn / (2 * np.pi), -p.real / wn
        return (self.frequency_range[0] <= f <= self.frequency_range[1]
                and self.damping_range[0] <= zeta <= self.damping_range[1])

    def distance(self, p: complex) -> float:
        wn = abs(p)
        f, zeta = wn / (2 * np.pi), -p.real / wn
        return float(np.hypot(np.log(f / self.center_frequency), (zeta - self.center_damping) / 0.3))


def pole_errors(estimated: ArrayLike, true: ArrayLike) -> np.ndarray:
    """Relative error of each true pole after optimal matching (Hungarian).

    Parameters
    ----------
    estimated : (k,) complex array_like
        Estimated poles, rad/s (any number; unmatched true poles get error ``inf``).
    true : (n,) complex array_like
        True poles, rad/s.

    Returns
    -------
    (n,) ndarray
        ``|p_est - p_true| / |p_true|`` per true pole.
    """
    est = np.asarray(estimated, dtype=complex).reshape(-1)
    tru = np.asarray(true, dtype=complex).reshape(-1)
    err = np.full(tru.size, np.inf)
    if est.size == 0 or not np.all(np.isfinite(est)):
        return err
    cost = np.abs(est[None, :] - tru[:, None]) / np.abs(tru)[:, None]
    rows, cols = scipy.optimize.linear_sum_assignment(cost)
    err[rows] = cost[rows, cols]
    return err


def select_by_prior(candidates: ArrayLike, prior: PhysicalPrior = PhysicalPrior(), n_pairs: int = 2) -> np.ndarray:
    """The ``n_pairs`` complex pairs among ``candidates`` that the prior finds most plausible.

    Parameters
    ----------
    candidates : complex array_like
        Continuous-time poles, rad/s (any shape, flattened). Only poles with positive imaginary
        part that :meth:`PhysicalPrior.admits` are considered.
    prior : PhysicalPrior
        Ranks the admitted poles by their distance to its most plausible mode.
    n_pairs : int
        Largest number of pairs returned. A pole within 1e-6 relative of one already chosen is
        skipped (a double pole counts once).

    Returns
    -------
    (2 k,) complex ndarray
        The ``k <= n_pairs`` chosen upper-half-plane poles, most plausible first, then their
        conjugates, rad/s; empty if the prior admits none.
    """
    c = np.asarray(candidates, dtype=complex).reshape(-1)
    upper = [p for p in c if prior.admits(p)]
    upper.sort(key=prior.distance)
    chosen: list[complex] = []
    for p in upper:  # skip near-duplicates (a double pole counts once)
        if all(abs(p - q) > 1e-6 * abs(p) for q in chosen):
            chosen.append(p)
        if len(chosen) == n_pairs:
            break
    out = np.array(chosen, dtype=complex)
    return np.concatenate([out, out.conj()])


def balanced_truncation_poles(sys: StateSpaceData, order: int) -> np.ndarray:
    """Poles (rad/s) of the discrete balanced truncation of ``sys`` to ``order`` states.

    Returns an empty array when SLICOT fails or its Hankel singular values are not finite
    (the attack then fails on that message).
    """
    import slycot

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            nr, Ar, _, _, hsv = slycot.ab09ad("D", "B", "N", sys.order, sys.B.shape[1], sys.C.shape[0],
                                              sys.A.copy(), sys.B.copy(), sys.C.copy(), nr=order, tol=0.0)
    except (ValueError, ArithmeticError, slycot.exceptions.SlycotError):
        return np.zeros(0, complex)
    if not np.all(np.isfinite(hsv)) or nr < 1:
        return np.zeros(0, complex)
    return continuous_poles(np.linalg.eigvals(Ar[:nr, :nr]), sys.dt)


def attack_model_reduction(message: ExchangeMessage, order: int = 4) -> np.ndarray:
    """The paper's attack: balanced truncation of ``S~`` to the known order; its poles.

    Parameters
    ----------
    message : ExchangeMessage
        An obfuscated (or clear) message.
    order : int
        The known order of ``S_j``.

    Returns
    -------
    complex ndarray
        Continuous poles of the reduced model, rad/s (empty if the reduction fails).
    """
    return balanced_truncation_poles(message.S, order)


def _match_sets(a: np.ndarray, b: np.ndarray, rtol: float) -> np.ndarray:
    """Elements of ``a`` that have a partner in ``b`` within ``rtol`` relative."""
    if a.size == 0 or b.size == 0:
        return np.zeros(0, complex)
    d = np.abs(a[:, None] - b[None, :]) / np.maximum(np.abs(a)[:, None], 1e-300)
    out: np.ndarray = a[d.min(axis=1) < rtol]
    return out


def attack_pole_intersection(message: ExchangeMessage, prior: PhysicalPrior = PhysicalPrior(),
                             rtol: float = 1e-5) -> np.ndarray:
    """Poles common to ``T~`` and ``S~``, then the physical prior.

    Parameters
    ----------
    message : ExchangeMessage
        The received message (``mechanism`` ``"none"`` or ``"paper"``); the poles of its
        discrete ``T`` and ``S`` are mapped to the s-plane, ``log(z) / dt`` (rad/s).
    prior : PhysicalPrior
        The attacker's prior on suspension modes.
    rtol : float
        Relative distance below which a pole of ``S~`` counts as a pole of ``T~``.

    Returns
    -------
    (2 k,) complex ndarray
        Estimated poles of ``S_j``, rad/s: ``k <= 2`` conjugate pairs chosen by
        :func:`select_by_prior`; empty if none is found.
    """
    pt = message.T.continuous_poles()
    ps = message.S.continuous_poles()
    return select_by_prior(_match_sets(ps, pt, rtol), prior)


def attack_multiplicity(message: ExchangeMessage, prior: PhysicalPrior = PhysicalPrior(),
                        rtol: float = 1e-6) -> np.ndarray:
    """Simple (multiplicity-one) poles of ``S~`` that also appear in ``T~``, then the prior.

    Parameters
    ----------
    message : ExchangeMessage
        The received message (``mechanism`` ``"none"`` or ``"paper"``); the poles of its
        discrete ``T`` and ``S`` are mapped to the s-plane, ``log(z) / dt`` (rad/s).
    prior : PhysicalPrior
        The attacker's prior on suspension modes.
    rtol : float
        Relative distance below which two poles of ``S~`` count as one repeated pole. Simple
        poles match poles of ``T~`` within 1e-5 relative; if none matches, all simple poles go
        to the prior.

    Returns
    -------
    (2 k,) complex ndarray
        Estimated poles of ``S_j``, rad/s: ``k <= 2`` conjugate pairs chosen by
        :func:`select_by_prior`; empty if none is found.
    """
    ps = message.S.continuous_poles()
    d = np.abs(ps[:, None] - ps[None, :]) / np.maximum(np.abs(ps)[:, None], 1e-300)
    np.fill_diagonal(d, np.inf)
    simple = ps[d.min(axis=1) > rtol] if ps.size > 1 else ps
    common = _match_sets(simple, message.T.continuous_poles(), 1e-5)
    return select_by_prior(common if common.size else simple, prior)


# -- attacks on signals (hardened exchange) ----------------------------------------------------
def _signals(z: np.ndarray, w_band: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Input (z) and output (w - z) of the map the attacker identifies."""
    return z, w_band - z


def attack_signals_reduction(z: np.ndarray, w_band: np.ndarray, dt: float, order: int = 12,
                             decimate: int = 2) -> np.ndarray:
    """Hardened ``model_reduction``: high-order ARX fit of ``z -> w - z``, then balanced
    truncation to 4 states.

    Parameters
    ----------
    z : (nfft, 2) ndarray
        The hardened message's ``z`` (band-limited model inversion on the padded grid), m/s.
    w_band : (nfft, 2) ndarray
        True road velocity band-limited like ``z`` (granted to the attacker), m/s.
    dt : float
        Sample period, s (``grid.dt``).
    order : int
        ARX order (as :func:`arx_poles`).
    decimate : int
        Decimation before the fit (as :func:`arx_poles`).

    Returns
    -------
    complex ndarray
        At most 4 poles of the truncated model, rad/s (empty if the truncation fails). If the
        fitted model is unstable, its poles chosen by the default :class:`PhysicalPrior` instead.
    """
    u, y = _signals(z, w_band)
    sys = arx_state_space(u, y, dt, order, decimate)
    if np.max(np.abs(np.linalg.eigvals(sys.A))) >= 1:
        return select_by_prior(continuous_poles(np.linalg.eigvals(sys.A), sys.dt))
    return balanced_truncation_poles(sys, 4)


def attack_signals_prior(z: np.ndarray, w_band: np.ndarray, dt: float, prior: PhysicalPrior = PhysicalPrior(),
                         order: int = 8, decimate: int = 2) -> np.ndarray:
    """Hardened ``pole_intersection``: ARX poles of ``z -> w - z`` selected by the prior.

    Parameters
    ----------
    z : (nfft, 2) ndarray
        The hardened message's ``z`` (band-limited model inversion on the padded grid), m/s.
    w_band : (nfft, 2) ndarray
        True road velocity band-limited like ``z`` (granted to the attacker), m/s.
    dt : float
        Sample period, s (``grid.dt``).
    prior : PhysicalPrior
        The attacker's prior on suspension modes.
    order : int
        ARX order (as :func:`arx_poles`).
    decimate : int
        Decimation before the fit (as :func:`arx_poles`).

    Returns
    -------
    (2 k,) complex ndarray
        Estimated poles of ``S_j``, rad/s: ``k <= 2`` conjugate pairs chosen by
        :func:`select_by_prior`; empty if none is found.
    """
    u, y = _signals(z, w_band)
    return select_by_prior(arx_poles(u, y, dt, order, decimate), prior)


def intersect_pole_sets(p1: np.ndarray, p2: np.ndarray, prior: PhysicalPrior = PhysicalPrior(),
                        rtol: float = 0.05) -> np.ndarray:
    """Poles of ``p1`` that recur in ``p2`` within ``rtol`` (averaged), then the prior.

    Parameters
    ----------
    p1 : complex array_like
        Poles of one segment, rad/s.
    p2 : complex ndarray
        Poles of another segment of the same vehicle, rad/s.
    prior : PhysicalPrior
        The attacker's prior on suspension modes.
    rtol : float
        A pole ``p`` of ``p1`` recurs if its nearest pole ``q`` of ``p2`` has
        ``|q - p| < rtol |p|``; the pair is replaced by its mean.

    Returns
    -------
    (2 k,) complex ndarray
        Estimated poles of ``S_j``, rad/s: ``k <= 2`` conjugate pairs chosen by
        :func:`select_by_prior`; empty if none is found.
    """
    common = []
    for p in np.asarray(p1, dtype=complex):
        if p2.size:
            q = p2[np.argmin(np.abs(p2 - p))]
            if abs(q - p) < rtol * abs(p):
                common.append(0.5 * (p + q))
    return select_by_prior(np.array(common, dtype=complex), prior)


def attack_signals_intersection(segments: list[tuple[np.ndarray, np.ndarray]], dt: float,
                                prior: PhysicalPrior = PhysicalPrior(), order: int = 8,
                                decimate: int = 2, rtol: float = 0.05) -> np.ndarray:
    """Hardened ``multiplicity``: ARX poles of ``z -> w - z`` that recur (within ``rtol``) in two
    segments of the same vehicle, then the prior.

    Parameters
    ----------
    segments : list of (z, w_band) tuples
        At least two segments of the same vehicle (only the first two are used); ``z`` and
        ``w_band`` are (nfft, 2) ndarrays in m/s, as in :func:`attack_signals_prior`.
    dt : float
        Sample period, s (``grid.dt``).
    prior : PhysicalPrior
        The attacker's prior on suspension modes.
    order : int
        ARX order of each fit (as :func:`arx_poles`).
    decimate : int
        Decimation before each fit (as :func:`arx_poles`).
    rtol : float
        Relative tolerance of :func:`intersect_pole_sets`.

    Returns
    -------
    (2 k,) complex ndarray
        Estimated poles of ``S_j``, rad/s: ``k <= 2`` conjugate pairs chosen by
        :func:`select_by_prior`; empty if none is found.

    Raises
    ------
    ParameterError
        If fewer than 2 segments are given.
    """
    if len(segments) < 2:
        raise ParameterError(f"segments must hold at least 2 (z, w) pairs, got {len(segments)}")
    (u1, y1), (u2, y2) = _signals(*segments[0]), _signals(*segments[1])
    p1 = arx_poles(u1, y1, dt, order, decimate)
    p2 = arx_poles(u2, y2, dt, order, decimate)
    return intersect_pole_sets(p1, p2, prior, rtol)
