"""Configuration of a reproduction: fleet, road, sensors, estimators and scoring window (SI units)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .._validation import check_int, check_nonnegative, check_positive, check_real
from ..errors import ParameterError
from ..estimation.estimator import JDPNoise
from ..estimation.grid import SegmentGrid
from ..io.limits import FileLimits
from ..models.road import RoadSpec, jump_statistics, wiener_intensity
from ..models.vehicle import FleetSpec
from ..privacy.obfuscation import ObfuscationSpec

__all__ = ["ExperimentConfig"]


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything a reproduction depends on besides the seed (all SI units).

    Parameters
    ----------
    n_vehicles : int
        Fleet size (vehicles traverse the segment in index order).
    n_runs : int
        Monte Carlo runs.
    speed : float
        Vehicle speed, m/s.
    sample_rate : float
        Accelerometer sample rate, Hz.
    segment_length : float
        Scored segment length, m.
    margin : float
        Recorded lead-in and lead-out on each side of the segment, m. The vehicle starts at
        rest at the start of the lead-in; the margins keep start-up and window-edge effects
        of the offline filters out of the score.
    iso_class : str
        ISO 8608 roughness class of the synthetic road.
    anomaly_density : float
        Potholes and bumps per metre.
    sensor_noise_std : float
        Accelerometer noise standard deviation per sample, m/s^2.
    fleet : FleetSpec
        How true and estimated vehicle parameters are drawn.
    gamma : float
        Observer parameter of eq. 4; corner ``gamma (1 + gamma) / 2`` rad/s.
    band_low_hz : float
        Lower edge of the evaluation band, Hz.
    obfuscation : ObfuscationSpec
        Distribution of the obfuscating systems (Algorithm 2).
    oracle : bool
        Use each vehicle's true plant in ``T_j`` (analysis only).
    road_profile : str | None
        Path of a measured profile (``"packaged"`` for the shipped one); None: synthetic.
    redraw_fleet : bool
        Draw a new fleet for every run (statistics over fleets, e.g. how the fused estimate
        improves with fleet size on average); by default one fleet serves every run.
    profile_limits : FileLimits
        Largest ``road_profile`` file (MB) and most rows it may hold.
    """

    n_vehicles: int = 10
    n_runs: int = 100
    speed: float = 15.0
    sample_rate: float = 200.0
    segment_length: float = 300.0
    margin: float = 15.0
    iso_class: str = "C"
    anomaly_density: float = 0.02
    sensor_noise_std: float = 0.05
    fleet: FleetSpec = field(default_factory=FleetSpec)
    gamma: float = 512.0
    band_low_hz: float = 0.5
    obfuscation: ObfuscationSpec = field(default_factory=ObfuscationSpec)
    oracle: bool = False
    road_profile: str | None = None
    redraw_fleet: bool = False
    profile_limits: FileLimits = field(default_factory=FileLimits)

    def __post_init__(self) -> None:
        check_int("n_vehicles", self.n_vehicles, low=1, high=1000)
        check_int("n_runs", self.n_runs, low=1)
        check_positive("speed", self.speed)
        check_positive("sample_rate", self.sample_rate)
        check_positive("segment_length", self.segment_length)
        check_nonnegative("margin", self.margin)
        check_nonnegative("sensor_noise_std", self.sensor_noise_std)
        check_positive("gamma", self.gamma)
        check_real("band_low_hz", self.band_low_hz, low=0.0, low_open=True, high=self.sample_rate / 2)
        for name, typ in (("fleet", FleetSpec), ("obfuscation", ObfuscationSpec), ("profile_limits", FileLimits)):
            if not isinstance(getattr(self, name), typ):
                raise ParameterError(f"{name} must be a {typ.__name__}, got {type(getattr(self, name)).__name__}")
        self.road_spec()  # validates iso_class and the anomaly settings

    @property
    def window_length(self) -> float:
        """Recorded distance per vehicle, m."""
        return self.segment_length + 2 * self.margin

    @property
    def n_samples(self) -> int:
        """Samples in the recorded window."""
        return int(np.floor(self.window_length / self.speed * self.sample_rate + 1e-9))

    @property
    def scored(self) -> slice:
        """Sample indices of the scored segment inside the window."""
        k0 = int(round(self.margin / self.speed * self.sample_rate))
        k1 = k0 + int(round(self.segment_length / self.speed * self.sample_rate))
        return slice(k0, min(k1, self.n_samples))

    def road_spec(self) -> RoadSpec:
        """Synthetic road of the window length, anomalies kept out of the margins.

        Returns
        -------
        RoadSpec
            ``window_length + 1`` m long (one metre of slack for the sampling), ISO class
            ``iso_class``, anomaly margin ``max(margin, 1)`` m.
        """
        return RoadSpec(length=self.window_length + 1.0, iso_class=self.iso_class,
                        anomaly_density=self.anomaly_density, anomaly_margin=max(self.margin, 1.0))

    def noise_model(self) -> JDPNoise:
        """Road and sensor statistics the estimators are designed for (Lemma 1).

        The Wiener intensity is the ISO class's road-velocity intensity at ``speed``; the jump
        part comes from the pothole edges; the measurement intensity is ``std^2 * dt``. A
        floor of 1e-4 (m/s^2)^2 per sample keeps the design regular with noise-free sensors.

        Returns
        -------
        JDPNoise
            Wiener intensity (2, 2) in m^2/s, jump rate in 1/s, jump mean (2,) in m, jump
            covariance (2, 2) in m^2, measurement intensity (2, 2) in (m/s^2)^2 s.
        """
        spec = self.road_spec()
        jumps = jump_statistics(spec, self.speed)
        r = max(self.sensor_noise_std, 1e-2) ** 2 / self.sample_rate
        return JDPNoise(wiener_cov=wiener_intensity(spec, self.speed), jump_rate=jumps.rate,
                        jump_mean=jumps.mean, jump_cov=jumps.covariance, measurement_cov=r * np.eye(2))

    def grid(self) -> SegmentGrid:
        """Frequency grid of the recorded window.

        Returns
        -------
        SegmentGrid
            ``n_samples`` samples at ``sample_rate`` Hz, evaluation band from ``band_low_hz`` Hz.
        """
        return SegmentGrid(self.n_samples, self.sample_rate, band_low_hz=self.band_low_hz)

    def to_dict(self) -> dict:
        """JSON-ready configuration.

        Returns
        -------
        dict
            Every field by name, nested dataclasses as dicts.
        """
        return dataclasses.asdict(self)

