"""Configuration of the security study (``roadcollab attack``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..._validation import check_int
from ...errors import ParameterError
from ...privacy.attacks import PhysicalPrior
from ..config import ExperimentConfig

__all__ = ["AttackStudyConfig"]


@dataclass(frozen=True)
class AttackStudyConfig:
    """Configuration of the security study.

    Parameters
    ----------
    experiment : ExperimentConfig
        Fleet, road, sensors and obfuscation (``n_runs`` there is ignored).
    n_runs : int
        Segments (runs).
    prior : PhysicalPrior
        The attacker's prior on suspension modes.
    dp_epsilons : tuple of float
        Privacy levels of the Gaussian-mechanism baseline.
    dp_delta : float
        ``delta`` of the Gaussian mechanism.
    dp_rho : float
        Adjacency radius: measurement records within ``rho`` (m/s^2, l2 over the record).
    paillier_bits : int
        Paillier key size.
    paillier_sample : int
        Values encrypted to time Paillier (extrapolated to a whole message).
    physical_fit_runs : int
        Runs on which the (slow, about 0.2 s per message) physical-fit attacks are made.
    replica_runs : int
        Segments of the replica attacks (about 0.5 s per fit; linked fits use 3 segments).
    replica_targets : int
        Vehicles attacked by the replica attacks (the first of the fleet).
    poisoning_runs : int
        Runs of the poisoning measurements (one receiver, one fusion node).
    secagg_min_inputs : int, optional
        ``k`` of secure aggregation: fewest inputs the aggregator may unmask (and the Shamir
        threshold). Default ``min(5, n_vehicles)``.
    secagg_colluders : tuple of int, optional
        Numbers of vehicles colluding with the aggregator in the collusion attacks. Default
        ``(n_vehicles - k - 1,)`` (``k + 1`` honest inputs left), empty if that is below 1; the case
        ``n_vehicles - 1`` (one honest input left) is always measured besides.
    """

    experiment: ExperimentConfig = field(default_factory=ExperimentConfig)
    n_runs: int = 20
    prior: PhysicalPrior = field(default_factory=PhysicalPrior)
    dp_epsilons: tuple[float, ...] = (0.5, 1.0, 2.0, 5.0, 10.0)
    dp_delta: float = 1e-5
    dp_rho: float = 0.5
    paillier_bits: int = 2048
    paillier_sample: int = 16
    physical_fit_runs: int = 5
    replica_runs: int = 3
    replica_targets: int = 3
    poisoning_runs: int = 2
    secagg_min_inputs: int | None = None
    secagg_colluders: tuple[int, ...] | None = None

    def __post_init__(self) -> None:
        check_int("n_runs", self.n_runs, low=2)
        check_int("replica_runs", self.replica_runs, low=1)
        check_int("poisoning_runs", self.poisoning_runs, low=1)
        check_int("replica_targets", self.replica_targets, low=1, high=self.experiment.n_vehicles)
        n = self.experiment.n_vehicles
        if self.secagg_min_inputs is None:
            object.__setattr__(self, "secagg_min_inputs", min(5, n))
        k = check_int("secagg_min_inputs", self.secagg_min_inputs, low=2, high=n)
        colluders = ((n - k - 1,) if n - k - 1 >= 1 else ()) if self.secagg_colluders is None else \
            tuple(self.secagg_colluders)
        object.__setattr__(self, "secagg_colluders", colluders)
        for c in colluders:
            check_int("secagg_colluders[]", c, low=1, high=self.experiment.n_vehicles - 1)
        if self.experiment.n_vehicles < 3:
            raise ParameterError(f"experiment.n_vehicles must be >= 3 for the study, got {self.experiment.n_vehicles}")

    def to_dict(self) -> dict:
        """The configuration as nested plain dicts (for ``config.json``)."""
        return dataclasses.asdict(self)
