"""roadcollab: privacy-preserving collaborative road estimation by networked vehicles.

After Gao, Li and Wang, "Privacy-Preserved Collaborative Estimation for Networked Vehicles
with Application to Road Anomaly Detection". See the README for the architecture.
"""

from importlib import metadata as _metadata

from . import protocol
from .anomaly import Detection, DetectorSpec, detect_anomalies, match_detections
from .collaborative import CollaborativeEstimator, VehicleEstimate, learning_filters
from .errors import MessageError, ParameterError
from .estimator import JDPNoise, RoadInputEstimator, build_road_input_estimator, jdp_estimator_gain
from .experiment import ExperimentConfig, FleetPipeline, ReproductionResult, run_reproduction
from .fusion import LinearMMSE
from .message import ExchangeMessage, InversionMessage, StateSpaceData
from .privacy import ObfuscationSpec, obfuscate
from .relay import Exchange, Relay, simulate_measurements
from .road import RoadSpec, generate_road, measured_road
from .simulation import discretize_plant, simulate_response
from .spectral import SegmentGrid
from .vehicle import FleetSpec, HalfCarParameters, Vehicle, half_car_model, sample_fleet

try:
    __version__ = _metadata.version("roadcollab")
except _metadata.PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

__all__ = [
    "Detection", "DetectorSpec", "detect_anomalies", "match_detections",
    "CollaborativeEstimator", "VehicleEstimate", "learning_filters",
    "MessageError", "ParameterError",
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
