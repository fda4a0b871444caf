"""roadcollab: privacy-preserving collaborative road estimation by networked vehicles.

After Gao, Li and Wang, "Privacy-Preserved Collaborative Estimation for Networked Vehicles
with Application to Road Anomaly Detection". See the README for the architecture.
"""

import importlib as _importlib
from importlib import metadata as _metadata

from .errors import FileFormatError, MessageError, ParameterError

#: Where each re-exported name lives (``name -> module``); imported on first use (PEP 562), so
#: ``import roadcollab`` and ``roadcollab --help`` do not load SciPy's signal and statistics modules,
#: matplotlib or Dask. ``protocol`` is the module :mod:`roadcollab.wire.protocol` itself.
_LAZY = {
    "protocol": "wire.protocol",
    "Detection": "detection.detector",
    "DetectorSpec": "detection.detector",
    "detect_anomalies": "detection.detector",
    "MatchResult": "detection.scoring",
    "match_detections": "detection.scoring",
    "CollaborativeEstimator": "collaboration.algorithm1",
    "VehicleEstimate": "collaboration.algorithm1",
    "learning_filters": "collaboration.algorithm1",
    "JDPNoise": "estimation.estimator",
    "RoadInputEstimator": "estimation.estimator",
    "build_road_input_estimator": "estimation.estimator",
    "jdp_estimator_gain": "estimation.estimator",
    "ExperimentConfig": "experiments.config",
    "FleetPipeline": "experiments.pipeline",
    "ReproductionResult": "experiments.reproduction.study",
    "run_reproduction": "experiments.reproduction.study",
    "LinearMMSE": "collaboration.fusion",
    "ExchangeMessage": "wire.message",
    "InversionMessage": "wire.message",
    "StateSpaceData": "lti.realisation",
    "ObfuscationSpec": "privacy.obfuscation",
    "obfuscate": "privacy.obfuscation",
    "Exchange": "collaboration.relay",
    "Relay": "collaboration.relay",
    "simulate_measurements": "collaboration.relay",
    "measured_road": "io.profiles",
    "RoadSpec": "models.road",
    "generate_road": "models.road",
    "discretize_plant": "models.simulation",
    "simulate_response": "models.simulation",
    "SegmentGrid": "estimation.grid",
    "FleetSpec": "models.vehicle",
    "HalfCarParameters": "models.vehicle",
    "Vehicle": "models.vehicle",
    "half_car_model": "models.vehicle",
    "sample_fleet": "models.vehicle",
}

try:
    __version__ = _metadata.version("roadcollab")
except _metadata.PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

__all__ = [
    "Detection", "DetectorSpec", "detect_anomalies", "MatchResult", "match_detections",
    "CollaborativeEstimator", "VehicleEstimate", "learning_filters",
    "FileFormatError", "MessageError", "ParameterError",
    "JDPNoise", "RoadInputEstimator", "build_road_input_estimator", "jdp_estimator_gain",
    "ExperimentConfig", "FleetPipeline", "ReproductionResult", "run_reproduction", "LinearMMSE",
    "Exchange", "Relay", "simulate_measurements",
    "ExchangeMessage", "InversionMessage", "StateSpaceData",
    "ObfuscationSpec", "obfuscate",
    "RoadSpec", "generate_road", "measured_road",
    "discretize_plant", "simulate_response",
    "SegmentGrid",
    "FleetSpec", "HalfCarParameters", "Vehicle", "half_car_model", "sample_fleet",
    "protocol", "__version__",
]


def __getattr__(name: str):
    """Import a re-exported name on first use (PEP 562).

    Parameters
    ----------
    name : str
        One of ``__all__``.

    Returns
    -------
    object
        The class, function or module ``name``.

    Raises
    ------
    AttributeError
        ``name`` is not re-exported by :mod:`roadcollab`.
    """
    where = _LAZY.get(name)
    if where is None:
        raise AttributeError(f"module 'roadcollab' has no attribute {name!r}")
    if name == "protocol":
        value = _importlib.import_module(f"{__name__}.{where}")
    else:
        value = getattr(_importlib.import_module(f"{__name__}.{where}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
