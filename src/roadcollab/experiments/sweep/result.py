"""Result of a sweep: per-run, per-vehicle MSE of every grid point and its ``sweep.csv`` table."""

from __future__ import annotations

from dataclasses import dataclass

from ..._validation import check_int, check_matrix, check_real
from ...errors import ParameterError
from .config import SWEPT_ESTIMATORS, SweepConfig
from .findings import SweepFinding, mean_stderr, panel_findings, ratio_of_means

__all__ = ["SweepRow", "SweepResult"]


@dataclass(frozen=True)
class SweepRow:
    """One grid point of ``sweep.csv``: MSE in (m/s)^2, averaged over the runs.

    Attributes
    ----------
    gamma : float
        Observer parameter of eq. 4.
    sensor_noise_std : float
        Accelerometer noise standard deviation, m/s^2.
    parameter_uncertainty : float
        Relative standard deviation of the vehicles' parameter estimates.
    vehicle1_observer_mse : float
        Vehicle 1's own online observer (the single vehicle, nobody ahead of it).
    algorithm1_mse : float
        Algorithm 1, averaged over vehicles ``2..V``.
    own_inversion_mse : float
        Each vehicle's offline inversion of its own record, averaged over all vehicles.
    fused_mse : float
        Fleet average of the inversions ``z`` at vehicle ``V``.
    oracle_per_bin_mse : float
        Linear MMSE from all ``V`` records with the true models (the bound).
    observer_only_mse : float
        Own observer, averaged over all vehicles.
    centralized_mse : float
        Linear MMSE from all ``V`` records with the nominal models.
    algorithm1_gain : float
        ``vehicle1_observer_mse / algorithm1_mse`` (> 1: Algorithm 1 is better).
    algorithm1_gain_se : float
        Delta-method standard error of the gain over the paired runs (:func:`ratio_of_means`).
    algorithm1_mse_se : float
        Standard error of ``algorithm1_mse`` over runs (per-run means over vehicles 2..V).
    vehicle1_observer_mse_se : float
        Standard error of ``vehicle1_observer_mse`` over runs.
    own_posterior_inversion_mse : float
        Each vehicle's inversion of its posterior-mean plant, averaged over all vehicles.
    fused_posterior_mse : float
        Fleet average of the posterior inversions at vehicle ``V``.
    n_runs : int
        Runs averaged ``R``.
    n_vehicles : int
        Fleet size ``V``.
    """

    gamma: float
    sensor_noise_std: float
    parameter_uncertainty: float
    vehicle1_observer_mse: float
    algorithm1_mse: float
    own_inversion_mse: float
    fused_mse: float
    oracle_per_bin_mse: float
    observer_only_mse: float
    centralized_mse: float
    algorithm1_gain: float
    algorithm1_gain_se: float
    algorithm1_mse_se: float
    vehicle1_observer_mse_se: float
    own_posterior_inversion_mse: float
    fused_posterior_mse: float
    n_runs: int
    n_vehicles: int


@dataclass(frozen=True, eq=False)
class SweepResult:
    """Per-run, per-vehicle MSE of every grid point of a sweep.

    Parameters
    ----------
    config : SweepConfig
    seed : int
        Root seed.
    mse : dict of str to (n_points, n_runs, n_vehicles) ndarray
        MSE of every estimator of :data:`SWEPT_ESTIMATORS`, (m/s)^2; points in the order of
        :meth:`SweepConfig.points`. ``fused``, ``centralized`` and ``oracle_per_bin`` at vehicle
        index ``j`` use the records of vehicles ``1..j+1``.

    Raises
    ------
    ParameterError
        An estimator is missing or an array has the wrong shape.
    """

    config: SweepConfig
    seed: int
    mse: dict

    def __post_init__(self) -> None:
        if not isinstance(self.config, SweepConfig):
            raise ParameterError(f"config must be a SweepConfig, got {type(self.config).__name__}")
        check_int("seed", self.seed, low=0)
        if not isinstance(self.mse, dict) or set(self.mse) != set(SWEPT_ESTIMATORS):
            got = sorted(self.mse) if isinstance(self.mse, dict) else type(self.mse).__name__
            raise ParameterError(f"mse must map exactly {list(SWEPT_ESTIMATORS)} to arrays, got {got}")
        shape = (len(self.config.points()), self.config.n_runs, self.config.n_vehicles)
        object.__setattr__(self, "mse", {k: check_matrix(f"mse[{k!r}]", self.mse[k], shape)
                                         for k in SWEPT_ESTIMATORS})

    def table(self) -> list[SweepRow]:
        """One :class:`SweepRow` per grid point, in the order of :meth:`SweepConfig.points`.

        Per run ``r``: ``a_r`` = vehicle 1's observer MSE, ``b_r`` = Algorithm 1's MSE averaged
        over vehicles ``2..V``; the row holds the run means, their standard errors (runs are
        independent) and the gain ``mean(a) / mean(b)`` with its paired standard error.
        """
        m = self.mse
        V, R = self.config.n_vehicles, self.config.n_runs
        rows = []
        for p, (g, s, u) in enumerate(self.config.points()):
            a = m["observer_only"][p, :, 0]
            b = m["algorithm1"][p, :, 1:].mean(axis=1)
            gain, gain_se = ratio_of_means(a, b)
            rows.append(SweepRow(
                gamma=g, sensor_noise_std=s, parameter_uncertainty=u,
                vehicle1_observer_mse=float(a.mean()), algorithm1_mse=float(b.mean()),
                own_inversion_mse=float(m["own_inversion"][p].mean()),
                fused_mse=float(m["fused"][p, :, V - 1].mean()),
                oracle_per_bin_mse=float(m["oracle_per_bin"][p, :, V - 1].mean()),
                observer_only_mse=float(m["observer_only"][p].mean()),
                centralized_mse=float(m["centralized"][p, :, V - 1].mean()),
                algorithm1_gain=gain, algorithm1_gain_se=gain_se, algorithm1_mse_se=mean_stderr(b),
                vehicle1_observer_mse_se=mean_stderr(a),
                own_posterior_inversion_mse=float(m["own_posterior_inversion"][p].mean()),
                fused_posterior_mse=float(m["fused_posterior"][p, :, V - 1].mean()), n_runs=R, n_vehicles=V))
        return rows

    def to_rows(self) -> list[SweepRow]:
        """Rows of ``sweep.csv``, one per grid point (:meth:`table`).

        Returns
        -------
        list of SweepRow
        """
        return self.table()

    def findings(self, *, threshold: float = 1.25) -> list[SweepFinding]:
        """Per (noise, uncertainty) pair: where the single vehicle's observer catches up.

        Parameters
        ----------
        threshold : float
            Ratio (> 1) below which vehicle 1's observer counts as "within" Algorithm 1.

        Returns
        -------
        list of SweepFinding
            One per (noise, uncertainty) pair, in sweep order.
        """
        threshold = check_real("threshold", threshold, low=1.0)
        return panel_findings(self.table(), self.mse, len(self.config.gammas), threshold)
