"""The physical-fit attack: fit a half-car model to what Theorem 1 hands the receiver.

With the optimal learning filters the receiver can compute the sender's inversion
``z = W P_hat^-1 y`` from any exact exchange (clear, obfuscated or hardened). Given a road
(the true one, or the receiver's own estimate of it), ``z ~ P_hat^-1 P w``: the attacker fits the
scale-free parameters of both ``P_hat`` and ``P`` by nonlinear least squares over the band and
reads the poles of the fitted ``P_hat``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.optimize

from ..errors import ParameterError
from ..lti.batch2x2 import inv2x2, matvec
from ..models.vehicle import HalfCarParameters, half_car_model

__all__ = ["attack_physical_fit"]


def _ratio_model(log_ratios: np.ndarray) -> Any:
    """Half-car model from scale-free parameters ``log [k/m, c/m, I/m, L1, L2]`` (m = 1)."""
    k, c, I, L1, L2 = np.exp(log_ratios)
    return half_car_model(HalfCarParameters(sprung_mass=1.0, roll_inertia=I, left_arm=L1, right_arm=L2,
                                            stiffness=k, damping=c))


def _log_ratios(params: Any) -> np.ndarray:
    return np.log([params.stiffness / params.sprung_mass, params.damping / params.sprung_mass,
                   params.roll_inertia / params.sprung_mass, params.left_arm, params.right_arm])


def attack_physical_fit(z: np.ndarray, w_band: np.ndarray, grid: Any, nominal: Any, *,
                        band_hz: tuple[float, float] = (0.5, 20.0),
                        max_bins: int = 300) -> np.ndarray:
    """Hardened ``physical_fit``: knows the half-car structure and the fleet's nominal
    parameters; fits ``Z = P(theta_hat)^-1 P(theta) W`` over both parameter sets by nonlinear
    least squares on the spectra and returns the poles of ``P(theta_hat)`` (rad/s).

    Only ratios to the mass are identifiable (scaling m, I, k and c together leaves ``P``
    unchanged), so the fit is over ``log [k/m, c/m, I/m, L1, L2]`` for each model.

    Parameters
    ----------
    z : (nfft, 2) ndarray
        The hardened message's ``z`` (or ``z`` recovered from an exact message), m/s.
    w_band : (nfft, 2) ndarray
        Road velocity band-limited like ``z``, m/s: the true one, or a stand-in such as the
        receiver's own inversion.
    grid : SegmentGrid
        The segment grid of ``z`` (signals of at most ``nfft`` samples).
    nominal : HalfCarParameters
        The fleet's nominal parameters: the starting point of both parameter sets.
    band_hz : (float, float)
        Active bins with frequency in this range (Hz, both ends included) are fitted.
    max_bins : int
        At most this many of those bins, evenly spread, are used.

    Returns
    -------
    (4,) complex ndarray
        Poles of the fitted ``P(theta_hat)``, rad/s, sorted by imaginary part; empty if the
        fit fails.
    """
    Z = grid.rfft(z)
    Wb = grid.rfft(w_band)
    f = grid.freqs
    sel = np.flatnonzero((f >= band_hz[0]) & (f <= band_hz[1]) & grid.active)
    if sel.size > max_bins:
        sel = sel[np.linspace(0, sel.size - 1, max_bins).astype(int)]
    s = 2j * np.pi * f[sel]
    Zs, Ws = Z[sel], Wb[sel]
    norm = np.sqrt(np.mean(np.abs(Zs) ** 2))
    x0 = np.concatenate([_log_ratios(nominal), _log_ratios(nominal)])

    def resid(x: np.ndarray) -> np.ndarray:
        Ph = _ratio_model(x[:5]).frequency_response(s)
        P = _ratio_model(x[5:]).frequency_response(s)
        r = (Zs - matvec(inv2x2(Ph) @ P, Ws)) / norm
        return np.concatenate([r.real.ravel(), r.imag.ravel()])

    try:
        sol = scipy.optimize.least_squares(resid, x0, x_scale=0.1, max_nfev=400)
    except (ValueError, np.linalg.LinAlgError, ParameterError):
        return np.zeros(0, complex)
    poles: np.ndarray = _ratio_model(sol.x[:5]).poles()
    return poles
