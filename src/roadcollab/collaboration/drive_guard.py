"""The receiver guard of a vehicle that has only its recorded drive (issue 20, section 4).

:class:`~roadcollab.collaboration.guard.ReceiverGuard` states an honest sender's expected discrepancy
``v_b`` from the receiver's posterior plants (parameter uncertainty) and the road's second moment ``S``.
A simulation has both (the fleet distribution and the configuration's road model); a recorded drive has
its vehicle's estimated parameters and nothing else. The priors here are what such a vehicle can state:

* **Parameter uncertainty** (:func:`drive_fleet_prior`): the parameters file holds the estimate
  ``theta_hat``; its stated relative accuracy ``u`` (default 0.10, the fleet model's
  ``FleetSpec.estimate_uncertainty``, the accuracy the calibration is designed to) with a flat prior over
  everything that accuracy admits, i.e. ``FleetSpec(nominal=theta_hat, spread=3 u, estimate_uncertainty=u)``:
  the posterior of :func:`~roadcollab.collaboration.fusion.posterior_draws` is then the likelihood
  ``phi((theta_hat / theta - 1) / u) / theta`` on ``|theta_hat / theta - 1| <= 3 u``, with no fleet centre.
* **Road second moment** (:func:`iso_road_moment`): the public road class the estimator is designed for
  (Lemma 1 design of every recorded drive: ISO 8608 class C with the default pothole statistics, at the
  drive's speed). The road velocity of that model is white in time: a Wiener intensity ``Q`` (m^2/s) and
  jumps at rate ``lambda`` (1/s) of mean ``mu`` and covariance ``Sigma`` (m), so the sampled road
  velocity has covariance ``fs (Q + lambda (Sigma + mu mu^T))`` per sample and, on the unnormalised DFT of
  ``N`` samples, ``S_k = N fs (Q + lambda (Sigma + mu mu^T))`` on every bin.
* ``road="own"`` (:func:`own_road_moment`): instead, the band means of the receiver's own unweighted
  inversion ``P_hat^-1 y`` over its record (diagonal: the tracks taken as independent, as the ISO model
  does). It adapts to a road rougher or smoother than the class and includes the inversion noise, so it
  overstates ``S`` where the noise dominates; measured against the class prior in
  ``docs/security-receivers.md``.

The receiver's own record is not under an attacker's control, so neither prior can be steered by a message.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .._validation import check_real
from ..errors import ParameterError
from ..estimation.estimator import JDPNoise
from ..lti.batch2x2 import inv2x2, matvec
from ..models.vehicle import FleetSpec, HalfCarParameters
from .algorithm1 import CollaborativeEstimator
from .guard import ReceiverGuard, third_octave_bands

__all__ = ["DEFAULT_UNCERTAINTY", "GUARD_ROADS", "GUARD_ROAD_DEFAULT", "drive_fleet_prior", "iso_road_moment", "own_road_moment", "drive_guard"]

#: Road priors of a recorded drive's guard: the design's ISO class, or the receiver's own inversions.
GUARD_ROADS = ("class", "own")
#: The default road prior (stated a priori: the class every recorded drive's estimator is designed for).
GUARD_ROAD_DEFAULT = "class"

#: Stated relative accuracy of a recorded vehicle's parameter estimate (``FleetSpec.estimate_uncertainty``).
DEFAULT_UNCERTAINTY = 0.10


def drive_fleet_prior(params: HalfCarParameters, uncertainty: float = DEFAULT_UNCERTAINTY) -> FleetSpec:
    """The parameter prior of a vehicle that knows only its own estimate and its stated accuracy.

    Parameters
    ----------
    params : HalfCarParameters
        The estimate ``theta_hat`` (the drive's parameters file).
    uncertainty : float
        Relative standard deviation ``u`` of the estimate, 0 to 0.3.

    Returns
    -------
    FleetSpec
        ``nominal = theta_hat``, ``spread = 3 u`` (a flat prior over what the accuracy admits),
        ``estimate_uncertainty = u``.
    """
    u = check_real("uncertainty", uncertainty, low=0.0, high=0.3)
    if not isinstance(params, HalfCarParameters):
        raise ParameterError(f"params must be HalfCarParameters, got {type(params).__name__}")
    return FleetSpec(nominal=params, spread=3.0 * u, estimate_uncertainty=u)


def iso_road_moment(estimator: CollaborativeEstimator, noise: JDPNoise) -> np.ndarray:
    """``S = E[W W^H]`` per active bin of the road model the estimator is designed for (white in time).

    Parameters
    ----------
    estimator : CollaborativeEstimator
        The receiver (its grid: ``N`` samples at ``fs``).
    noise : JDPNoise
        The design's road statistics: ``wiener_cov`` (2, 2) m^2/s, ``jump_rate`` 1/s, ``jump_mean`` (2,) m,
        ``jump_cov`` (2, 2) m^2 (``ExperimentConfig(...).noise_model()``).

    Returns
    -------
    (K_active, 2, 2) complex ndarray
        ``N fs (Q + lambda (Sigma + mu mu^T))`` on every active bin, (m/s)^2 per bin of the unnormalised DFT.
    """
    g = estimator.grid
    mu = np.asarray(noise.jump_mean, float)
    per_sample = g.sample_rate * (np.asarray(noise.wiener_cov, float)
                                  + noise.jump_rate * (np.asarray(noise.jump_cov, float) + np.outer(mu, mu)))
    K = int(g.active.sum())
    return np.broadcast_to(g.n_samples * per_sample.astype(complex), (K, 2, 2)).copy()


def own_road_moment(estimator: CollaborativeEstimator, spectra: Sequence[np.ndarray], *, min_bins: int = 16
                    ) -> np.ndarray:
    """``S`` from the receiver's own inversions: per guard band, the mean of ``|P_hat^-1 y|^2`` per track.

    Parameters
    ----------
    estimator : CollaborativeEstimator
        The receiver.
    spectra : sequence of (K, 2) complex ndarray
        Its record spectra (one per window of the drive), on its grid.
    min_bins : int
        Fewest bins per band (as the guard's).

    Returns
    -------
    (K_active, 2, 2) complex ndarray
        Diagonal, constant within each band, (m/s)^2 per bin.
    """
    g = estimator.grid
    act = g.active
    if not spectra:
        raise ParameterError("own_road_moment needs at least one record spectrum")
    Pinv = inv2x2(estimator.P_f[act])
    power = np.mean([np.abs(matvec(Pinv, Y[act])) ** 2 for Y in spectra], axis=0)      # (K_active, 2)
    freqs = g.freqs[act]
    S = np.zeros((int(act.sum()), 2, 2), complex)
    for b in third_octave_bands(freqs, min_bins=min_bins):
        S[b, 0, 0], S[b, 1, 1] = power[b, 0].mean(), power[b, 1].mean()
    return S


def drive_guard(estimator: CollaborativeEstimator, noise: JDPNoise, noise_std: float, *, road: str = GUARD_ROAD_DEFAULT,
                spectra: Sequence[np.ndarray] = (), **options) -> ReceiverGuard:
    """The receiver guard of a recorded-drive vehicle, attached to its estimator.

    Parameters
    ----------
    estimator : CollaborativeEstimator
        Built with ``fleet=`` set (:func:`drive_fleet_prior` of its parameters).
    noise : JDPNoise
        The design's road statistics (:func:`iso_road_moment`).
    noise_std : float
        The drive's accelerometer noise, m/s^2.
    road : {"class", "own"}
        The road prior: the design's ISO class (:func:`iso_road_moment`) or the own inversions
        (:func:`own_road_moment`, needs ``spectra``).
    spectra : sequence of (K, 2) complex ndarray
        The record spectra of the drive's windows (``road="own"``).
    **options
        Keyword options of :class:`~roadcollab.collaboration.guard.ReceiverGuard`.

    Returns
    -------
    ReceiverGuard
        Attached (:meth:`~roadcollab.collaboration.guard.ReceiverGuard.attach`).
    """
    if road == "class":
        S = iso_road_moment(estimator, noise)
    elif road == "own":
        S = own_road_moment(estimator, spectra)
    else:
        raise ParameterError(f"road must be 'class' or 'own', got {road!r}")
    return ReceiverGuard(estimator, S, noise_std, **options).attach()
