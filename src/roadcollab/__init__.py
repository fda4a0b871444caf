"""roadcollab: privacy-preserving collaborative road estimation by networked vehicles.

After Gao, Li and Wang, "Privacy-Preserved Collaborative Estimation for Networked Vehicles
with Application to Road Anomaly Detection". See the README for the architecture.
"""

from importlib import metadata as _metadata

from .wire import protocol
from .detection.detector import Detection, DetectorSpec, detect_anomalies
from .detection.scoring import MatchResult, match_detections
from .collaboration.algorithm1 import CollaborativeEstimator, VehicleEstimate, learning_filters
from .errors import FileFormatError, MessageError, ParameterError
from .estimation.estimator import JDPNoise, RoadInputEstimator, build_road_input_estimator, jdp_estimator_gain
from .experiments.config import ExperimentConfig
from .experiments.pipeline import FleetPipeline
from .experiments.reproduction import ReproductionResult, run_reproduction
from .collaboration.fusion import LinearMMSE
from .wire.message import ExchangeMessage, InversionMessage
from .lti.realisation import StateSpaceData
from .privacy.obfuscation import ObfuscationSpec, obfuscate
from .collaboration.relay import Exchange, Relay, simulate_measurements
from .io.profiles import measured_road
from .models.road import RoadSpec, generate_road
from .models.simulation import discretize_plant, simulate_response
from .estimation.grid import SegmentGrid
from .models.vehicle import FleetSpec, HalfCarParameters, Vehicle, half_car_model, sample_fleet

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
