"""Analysis of a sweep: paired ratios of run means and what each (noise, uncertainty) panel says.

The statistics are over the sweep's Monte Carlo runs; since every grid point uses the same
randomness per run (common random numbers), ratios between estimators or grid points are paired
and their standard errors come from the per-run residuals (:func:`ratio_of_means`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import check_matrix
from ...errors import ParameterError

__all__ = ["SweepFinding", "mean_stderr", "panel_findings", "ratio_of_means"]


def ratio_of_means(num, den) -> tuple[float, float]:
    """Ratio of two paired sample means and its delta-method standard error.

    With per-run pairs ``(a_r, b_r)``, ``r = 1..R``:

    .. math::

        \\hat G = \\bar a / \\bar b,\\qquad
        \\mathrm{SE}(\\hat G) = \\frac{1}{\\bar b}
        \\sqrt{\\frac{\\sum_r (a_r - \\hat G b_r)^2}{R (R - 1)}}

    (first-order linearisation of ``a / b`` around the means; the pairing enters through the
    covariance of ``a`` and ``b``, which the residuals ``a_r - G b_r`` carry).

    Parameters
    ----------
    num, den : (R,) array_like
        Paired per-run values (e.g. MSE in (m/s)^2); ``mean(den) != 0``.

    Returns
    -------
    ratio : float
        ``mean(num) / mean(den)``.
    se : float
        Its standard error; NaN for ``R = 1``.

    Raises
    ------
    ParameterError
        ``num`` and ``den`` are not 1-D of the same length, or ``mean(den) == 0``.

    Examples
    --------
    >>> ratio_of_means([2.0, 4.0], [1.0, 2.0])
    (2.0, 0.0)
    """
    a = check_matrix("num", num, (None,))
    b = check_matrix("den", den, (a.size,))
    if a.size == 0:
        raise ParameterError("num must hold at least one value, got none")
    mb = float(b.mean())
    if mb == 0.0:
        raise ParameterError("den must have a non-zero mean, got 0")
    g = float(a.mean()) / mb
    if a.size < 2:
        return g, float("nan")
    return g, float(np.sqrt(np.sum((a - g * b) ** 2) / (a.size * (a.size - 1))) / abs(mb))


def mean_stderr(x: np.ndarray) -> float:
    """Standard error of the mean of independent values.

    Parameters
    ----------
    x : (R,) ndarray
        Independent values (e.g. per-run MSE in (m/s)^2).

    Returns
    -------
    float
        ``std(x, ddof=1) / sqrt(R)``, in the unit of ``x``; NaN for a single value.
    """
    return float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")


@dataclass(frozen=True)
class SweepFinding:
    """What the sweep says for one (noise, uncertainty) pair, read off the numbers.

    Attributes
    ----------
    sensor_noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    parameter_uncertainty : float
        Relative standard deviation of the vehicles' parameter estimates.
    threshold : float
        "Within" means ``vehicle1_observer_mse <= threshold * algorithm1_mse``; "Algorithm 1
        wins" means the opposite (the single vehicle is more than ``threshold`` times worse).
    smallest_gamma_within : float or None
        Smallest swept gamma at which vehicle 1's observer is within ``threshold`` of
        Algorithm 1 (None: at no swept gamma).
    within_at_every_larger_gamma : bool
        The observer stays within ``threshold`` at every swept gamma above that one.
    gammas_algorithm1_wins : tuple of float
        Swept gammas at which Algorithm 1 wins.
    largest_gamma : float
        The strongest swept observer.
    algorithm1_over_observer_at_largest : float
        ``algorithm1_mse / vehicle1_observer_mse`` at ``largest_gamma`` (< 1: Algorithm 1 better).
    algorithm1_over_observer_at_largest_se : float
        Its delta-method standard error over the paired runs.
    algorithm1_over_own_inversion_at_largest : float
        Algorithm 1 against each vehicle's own offline inversion (the other single-vehicle
        estimator) on the same vehicles ``2..V`` at ``largest_gamma``: ratio of run means.
    algorithm1_over_own_inversion_at_largest_se : float
        Its delta-method standard error over the paired runs.
    algorithm1_over_own_observer_at_largest : float
        Algorithm 1 against each vehicle's own online observer on the same vehicles ``2..V`` at
        ``largest_gamma`` (a paired comparison, free of the vehicle-to-vehicle scatter that
        ``algorithm1_over_observer_at_largest`` carries).
    algorithm1_over_own_observer_at_largest_se : float
        Its delta-method standard error over the paired runs.
    unresolved_gammas : tuple of float
        Swept gammas at which the gain ``vehicle1_observer_mse / algorithm1_mse`` lies within
        two standard errors of ``threshold``: there the within/wins classification is not
        resolved by the runs.
    """

    sensor_noise_std: float
    parameter_uncertainty: float
    threshold: float
    smallest_gamma_within: float | None
    within_at_every_larger_gamma: bool
    gammas_algorithm1_wins: tuple[float, ...]
    largest_gamma: float
    algorithm1_over_observer_at_largest: float
    algorithm1_over_observer_at_largest_se: float
    algorithm1_over_own_inversion_at_largest: float
    algorithm1_over_own_inversion_at_largest_se: float
    algorithm1_over_own_observer_at_largest: float
    algorithm1_over_own_observer_at_largest_se: float
    unresolved_gammas: tuple[float, ...]

    @property
    def wins_only_for_weak_observers(self) -> bool:
        """Algorithm 1 wins at some swept gamma, but not at the largest one."""
        return bool(self.gammas_algorithm1_wins) and self.largest_gamma not in self.gammas_algorithm1_wins



def panel_findings(rows, mse: dict, n_gammas: int, threshold: float) -> list[SweepFinding]:
    """Per (noise, uncertainty) panel: where the single vehicle's observer catches up.

    Parameters
    ----------
    rows : sequence of roadcollab.experiments.sweep.result.SweepRow
        The sweep's table, in the order of :meth:`~roadcollab.experiments.sweep.config.SweepConfig.points`
        (each panel is ``n_gammas`` consecutive rows, gamma ascending).
    mse : dict of str to (n_points, n_runs, n_vehicles) ndarray
        Per-run, per-vehicle MSE of the swept estimators, (m/s)^2.
    n_gammas : int
        Swept gammas per panel.
    threshold : float
        Ratio (>= 1) below which vehicle 1's observer counts as "within" Algorithm 1.

    Returns
    -------
    list of SweepFinding
        One per panel, in sweep order.
    """
    out = []
    for k in range(0, len(rows), n_gammas):
        panel = rows[k:k + n_gammas]  # one (noise, uncertainty) pair, gamma ascending
        within = [r.vehicle1_observer_mse <= threshold * r.algorithm1_mse for r in panel]
        first = next((i for i, w in enumerate(within) if w), None)
        last = panel[-1]
        p_last = k + n_gammas - 1
        alg1_last = mse["algorithm1"][p_last, :, 1:].mean(axis=1)
        ratio, ratio_se = ratio_of_means(alg1_last, mse["observer_only"][p_last, :, 0])
        own, own_se = ratio_of_means(alg1_last, mse["own_inversion"][p_last, :, 1:].mean(axis=1))
        obs, obs_se = ratio_of_means(alg1_last, mse["observer_only"][p_last, :, 1:].mean(axis=1))
        out.append(SweepFinding(
            sensor_noise_std=last.sensor_noise_std, parameter_uncertainty=last.parameter_uncertainty,
            threshold=threshold, smallest_gamma_within=None if first is None else panel[first].gamma,
            within_at_every_larger_gamma=first is not None and all(within[first:]),
            gammas_algorithm1_wins=tuple(r.gamma for r, w in zip(panel, within) if not w),
            largest_gamma=last.gamma, algorithm1_over_observer_at_largest=ratio,
            algorithm1_over_observer_at_largest_se=ratio_se,
            algorithm1_over_own_inversion_at_largest=own, algorithm1_over_own_inversion_at_largest_se=own_se,
            algorithm1_over_own_observer_at_largest=obs, algorithm1_over_own_observer_at_largest_se=obs_se,
            unresolved_gammas=tuple(r.gamma for r in panel
                                    if abs(r.algorithm1_gain - threshold) <= 2 * r.algorithm1_gain_se)))
    return out
