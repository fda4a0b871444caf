"""The replica attack: re-run the receiver's own pipeline and fit both half cars to it.

Any exact relay hands the receiver the sender's band-limited inversion

.. math:: z = W_{reg}\\,\\hat P(\\hat\\theta)^{-1} y,\\qquad y = P(\\theta)\\,w + n,

computed per bin on the zero-padded segment grid (:class:`~roadcollab.estimation.grid.SegmentGrid`).
The replica attacker knows that pipeline exactly (Kerckhoffs) and replays it: it simulates the
half car ``P(theta)`` from rest on a road (ZOH-exact, as :func:`~roadcollab.models.simulation.simulate_response`
does for the fleet), zero-pads the simulated record to ``nfft``, applies ``W_reg P_hat_d(theta_hat)^-1``
with the ZOH-discretised nominal plant on the active bins, and fits ``theta`` and ``theta_hat`` by
nonlinear least squares (:func:`scipy.optimize.least_squares`) on the full padded spectra, which by
Parseval is the time-domain least-squares fit of ``z`` over all ``nfft`` samples, here weighted per bin by
the fleet's nominal plant response to whiten the sensor noise (generalised least squares). It starts from
the fleet's nominal parameters (public). Only ratios to the mass are identifiable (scaling ``m``,
``I``, ``k`` and ``c`` together leaves ``P`` unchanged), so each model is parametrised by
``log [k/m, c/m, I/m, L1, L2]`` as in :mod:`roadcollab.privacy.physical_fit`.

Unlike the physical fit (``Z ~ P_hat^-1 P W`` per bin), the replica models the finite record
exactly: the start from rest and the truncation of ``y`` to ``N`` samples before padding, the
discretisation of both plants and the regularising weight. On a noiseless message with the true
road it recovers the poles of ``P_hat`` to round-off of the optimiser.

Variants: the road is either known (the true road velocity, ``(N, 2)``) or the fleet's fused
estimate of it (e.g. the average of other vehicles' ``z``, no true road needed); one message, or
several segments of the same vehicle linked (one ``theta`` and one ``theta_hat`` fitted jointly).
"""

from __future__ import annotations

from collections.abc import Sequence

from dataclasses import dataclass

import numpy as np
import scipy.optimize

from .._validation import check_int, check_signal
from ..errors import ParameterError
from ..estimation.grid import SegmentGrid
from ..lti.batch2x2 import inv2x2, matvec
from ..models.simulation import discretize_plant, simulate_response
from ..models.vehicle import HalfCarParameters
from .physical_fit import _log_ratios, _ratio_model

__all__ = ["ReplicaFit", "replica_fit", "attack_replica", "attack_replica_linked", "replica_z"]


@dataclass(frozen=True)
class ReplicaFit:
    """What the replica attacker fitted.

    Parameters
    ----------
    poles : (4,) complex ndarray
        Poles of the fitted ``P(theta_hat)`` (the sender's nominal model), rad/s, sorted by
        imaginary part; empty if the fit failed.
    nominal_ratios : (5,) ndarray
        Fitted ``[k/m, c/m, I/m, L1, L2]`` of ``P_hat`` (1/s^2, 1/s, m^2, m, m); NaN if the fit failed.
    true_ratios : (5,) ndarray
        The same for the true plant ``P(theta)``.
    cost : float
        Final normalised least-squares cost (``0.5 sum r^2`` of residuals relative to the RMS of ``z``).
    n_evaluations : int
        Residual evaluations used.
    """

    poles: np.ndarray
    nominal_ratios: np.ndarray
    true_ratios: np.ndarray
    cost: float
    n_evaluations: int

    @classmethod
    def failed(cls) -> ReplicaFit:
        """The result of a fit that could not be made."""
        nan = np.full(5, np.nan)
        return cls(np.zeros(0, complex), nan, nan.copy(), float("nan"), 0)


def replica_z(road_w: np.ndarray, grid: SegmentGrid, true_log_ratios: np.ndarray,
              nominal_log_ratios: np.ndarray) -> np.ndarray:
    """The receiver's ``z`` spectrum re-run for given parameters: ``W_reg P_hat_d^-1 rfft(P_d w)``.

    .. math:: Z_k = W_{reg,k}\\,\\hat P_d(e^{j\\omega_k})^{-1}\\,\\mathrm{DFT}_{nfft}\\{P_d\\,w\\}_k

    with ``P_d w`` simulated from rest over the ``N`` samples of ``road_w`` (ZOH-exact), zero
    outside the active bins.

    Parameters
    ----------
    road_w : (N, 2) ndarray
        Road velocity under the left and right wheel, m/s, ``N <= grid.nfft``.
    grid : SegmentGrid
        The segment grid of the message.
    true_log_ratios : (5,) array_like
        ``log [k/m, c/m, I/m, L1, L2]`` of the plant that drives the simulated record.
    nominal_log_ratios : (5,) array_like
        The same for the nominal plant that is inverted.

    Returns
    -------
    (n_bins, 2) complex ndarray
        Spectrum of ``z`` on the grid's rfft bins, m/s.
    """
    act = grid.active
    y = simulate_response(discretize_plant(_ratio_model(np.asarray(true_log_ratios, float)), grid.dt), road_w)
    Ph = discretize_plant(_ratio_model(np.asarray(nominal_log_ratios, float)), grid.dt).frequency_response(
        grid.omega_dt[act])
    Z = np.zeros((grid.n_bins, 2), complex)
    Z[act] = grid.reg_weight[act][:, None] * matvec(inv2x2(Ph), grid.rfft(y)[act])
    return Z


def _bin_weights(grid: SegmentGrid) -> np.ndarray:
    """Parseval weights of the active rfft bins: 1 for DC and Nyquist, sqrt(2) for the others."""
    f = grid.freqs[grid.active]
    wts = np.full(f.size, np.sqrt(2.0))
    wts[(f == 0) | (f == grid.sample_rate / 2)] = 1.0
    return wts


def _check_segments(segments: Sequence[tuple[np.ndarray, np.ndarray]], grid: SegmentGrid) -> list[tuple[np.ndarray, np.ndarray]]:
    """Validate ``[(z, road_w), ...]``: z (<= nfft, 2) and road (<= nfft, 2), both finite."""
    if not isinstance(grid, SegmentGrid):
        raise ParameterError(f"grid must be a SegmentGrid, got {type(grid).__name__}")
    try:
        segs = list(segments)
    except TypeError as err:
        raise ParameterError(f"segments must be a sequence of (z, road_w) pairs, got {type(segments).__name__}") \
            from err
    if not segs:
        raise ParameterError("segments must not be empty, got 0 segments")
    out = []
    for i, seg in enumerate(segs):
        if len(seg) != 2:
            raise ParameterError(f"segments[{i}] must be a (z, road_w) pair, got {len(seg)} items")
        z = check_signal(f"segments[{i}].z", seg[0], 2)
        w = check_signal(f"segments[{i}].road_w", seg[1], 2)
        for name, x in (("z", z), ("road_w", w)):
            if x.shape[0] > grid.nfft:
                raise ParameterError(f"segments[{i}].{name} must have at most {grid.nfft} samples, got {x.shape[0]}")
        out.append((z, w))
    return out


def replica_fit(segments: Sequence[tuple[np.ndarray, np.ndarray]], grid: SegmentGrid, nominal: HalfCarParameters, *, max_nfev: int = 200,
                x_scale: float = 0.1, whiten: bool = True) -> ReplicaFit:
    """Fit one ``theta`` and one ``theta_hat`` to one or more segments of one vehicle.

    Parameters
    ----------
    segments : sequence of (z, road_w)
        Per segment: the message's ``z`` ((nfft, 2) m/s, or fewer samples, zero-padded) and the road
        velocity the attacker assumes, ``(N, 2)`` m/s (the true road, or the fleet's fused estimate
        cut to the recorded ``N`` samples).
    grid : SegmentGrid
        The segment grid of every message.
    nominal : HalfCarParameters
        The fleet's nominal parameters: the starting point of both parameter sets.
    max_nfev : int
        Budget of :func:`scipy.optimize.least_squares` (>= 1): residual evaluations not counting
        the 10 extra ones of each finite-difference Jacobian (scipy's ``trf`` convention), so a
        fit costs up to about ``11 * max_nfev`` evaluations.
    x_scale : float
        Characteristic step of the log-parameters (> 0).
    whiten : bool
        Weight the residual ``z - z(theta, theta_hat)`` per bin by the fleet's nominal plant
        response ``P(theta_0)`` (fixed, so no bias): ``W_reg P_hat^-1`` colours the sensor noise
        and ``P(theta_0)`` approximately undoes it (generalised least squares). False fits ``z``
        itself (plain time-domain least squares).

    Returns
    -------
    ReplicaFit
        Poles of the fitted ``P(theta_hat)`` and the fitted ratios; :meth:`ReplicaFit.failed`
        (empty poles) if the optimiser cannot evaluate the model.

    Raises
    ------
    ParameterError
        If ``segments`` is empty or a signal has the wrong shape, ``grid`` is not a SegmentGrid,
        ``nominal`` is not a HalfCarParameters or ``max_nfev < 1``.
    """
    segs = _check_segments(segments, grid)
    if not isinstance(nominal, HalfCarParameters):
        raise ParameterError(f"nominal must be a HalfCarParameters, got {type(nominal).__name__}")
    max_nfev = check_int("max_nfev", max_nfev, low=1)
    act = grid.active
    wts = _bin_weights(grid)[:, None]
    Zs = [grid.rfft(z)[act] for z, _ in segs]
    norm = np.sqrt(np.mean([np.mean(np.abs(Z) ** 2) for Z in Zs])) or 1.0
    x0 = np.concatenate([_log_ratios(nominal), _log_ratios(nominal)])
    om = grid.omega_dt[act]
    P0 = discretize_plant(_ratio_model(x0[:5]), grid.dt).frequency_response(om)
    ynorm = np.sqrt(np.mean([np.mean(np.abs(matvec(P0, Z)) ** 2) for Z in Zs])) or 1.0

    def resid(x: np.ndarray) -> np.ndarray:
        parts = []
        for Z, (_, w) in zip(Zs, segs):
            if whiten:
                r = wts * matvec(P0, Z - replica_z(w, grid, x[5:], x[:5])[act]) / ynorm
            else:
                r = wts * (Z - replica_z(w, grid, x[5:], x[:5])[act]) / norm
            parts += [r.real.ravel(), r.imag.ravel()]
        out = np.concatenate(parts)
        return out if np.all(np.isfinite(out)) else np.full(out.size, 1e6)

    try:
        sol = scipy.optimize.least_squares(resid, x0, x_scale=x_scale, max_nfev=max_nfev)
        poles = _ratio_model(sol.x[:5]).poles()
    except (ValueError, np.linalg.LinAlgError, ParameterError):
        return ReplicaFit.failed()
    if not np.all(np.isfinite(poles)):
        return ReplicaFit.failed()
    return ReplicaFit(poles=poles, nominal_ratios=np.exp(sol.x[:5]), true_ratios=np.exp(sol.x[5:]),
                      cost=float(sol.cost), n_evaluations=int(sol.nfev))


def attack_replica(z: np.ndarray, road_w: np.ndarray, grid: SegmentGrid, nominal: HalfCarParameters, *,
                   max_nfev: int = 200) -> np.ndarray:
    """The replica attack on one message: poles of the fitted ``P(theta_hat)``.

    Parameters
    ----------
    z : (nfft, 2) ndarray
        The hardened (or DP) message's ``z``, or ``z`` recovered from an exact message, m/s.
    road_w : (N, 2) ndarray
        Road velocity the attacker assumes, m/s: the true one, or the fleet's fused estimate.
    grid : SegmentGrid
        The segment grid of ``z``.
    nominal : HalfCarParameters
        The fleet's nominal parameters (public), the starting point.
    max_nfev : int
        Budget of residual evaluations.

    Returns
    -------
    (4,) complex ndarray
        Poles of ``P(theta_hat)``, rad/s; empty if the fit failed (scored as a miss by
        :func:`~roadcollab.privacy.attacks.pole_errors`).

    Examples
    --------
    >>> poles = attack_replica(message.z, road.velocity, pipe.grid, cfg.fleet.nominal)  # doctest: +SKIP
    """
    return replica_fit([(z, road_w)], grid, nominal, max_nfev=max_nfev).poles


def attack_replica_linked(segments: Sequence[tuple[np.ndarray, np.ndarray]], grid: SegmentGrid, nominal: HalfCarParameters, *,
                          max_nfev: int = 300) -> np.ndarray:
    """The replica attack on linked segments of one vehicle: one ``theta_hat`` for all of them.

    Parameters
    ----------
    segments : sequence of (z, road_w)
        Per segment, the message's ``z`` ((nfft, 2) m/s) and the assumed road velocity ((N, 2) m/s).
    grid : SegmentGrid
        The segment grid (the same for every segment).
    nominal : HalfCarParameters
        The fleet's nominal parameters (public), the starting point.
    max_nfev : int
        Budget of residual evaluations.

    Returns
    -------
    (4,) complex ndarray
        Poles of ``P(theta_hat)``, rad/s; empty if the fit failed.
    """
    return replica_fit(segments, grid, nominal, max_nfev=max_nfev).poles
