"""The security study behind ``roadcollab attack``: attacks, linkability, exactness and the
conventional baselines measured side by side on the same segments.

One run is one segment (a fresh road, fresh sensor noise, fresh obfuscators; see
:mod:`roadcollab.experiments.security_segment`); the fleet is the same in every run, so messages of
one vehicle on different runs are what a curious receiver could try to link. This module runs the
segments and turns them into the study's tables.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .._validation import check_int
from ..errors import ParameterError
from ..privacy import baselines
from ..privacy.attacks import PhysicalPrior, SUCCESS_TOLERANCE, intersect_pole_sets, pole_errors
from .config import ExperimentConfig
from .pipeline import pipeline_for
from .runner import map_runs
from .security_segment import EXACT_MECHANISMS, SegmentAttacks, attack_segment, dp_mse_key, target_poles
from .seeds import SeedPlan

__all__ = ["AttackStudyConfig", "AttackStudyResult", "run_attack_study"]

#: Linkability rows: the mechanism and the feature a curious receiver compares across segments.
_LINK_FEATURES = (("none", "poles of S"), ("paper", "multiplicity-attack poles"),
                  ("hardened", "model-error spectrum (true road known)"),
                  ("hardened_own_road", "model-error spectrum vs a fixed receiver's own inversion"))


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

    def __post_init__(self) -> None:
        check_int("n_runs", self.n_runs, low=2)
        if self.experiment.n_vehicles < 3:
            raise ParameterError(f"experiment.n_vehicles must be >= 3 for the study, got {self.experiment.n_vehicles}")

    def to_dict(self) -> dict:
        """The configuration as nested plain dicts (for ``config.json``)."""
        return dataclasses.asdict(self)


@dataclass(eq=False)
class AttackStudyResult:
    """Everything ``roadcollab attack`` writes.

    Parameters
    ----------
    config : AttackStudyConfig
        The study.
    seed : int
        Root seed.
    attack_rows : list of dict
        Per (mechanism, attack): median relative pole error, success rate and number of messages.
    exactness_rows : list of dict
        Per mechanism: largest relative change of any estimate vs. no privacy.
    linkability_rows : list of dict
        Per (mechanism, feature): AUC, top-1 accuracy and its chance level.
    baseline_rows : list of dict
        Per mechanism: MSE of vehicles 1..3 ((m/s)^2), ms and bytes per message, and a note.
    pole_examples : list of dict
        First segment, vehicles 1..3: true poles and the attacks' estimates (rad/s).
    """

    config: AttackStudyConfig
    seed: int
    attack_rows: list[dict]
    exactness_rows: list[dict]
    linkability_rows: list[dict]
    baseline_rows: list[dict]
    pole_examples: list[dict]


def _linkability(features: dict[tuple[int, int], np.ndarray]) -> dict:
    """AUC of 'same vehicle' vs 'different vehicle' distances across runs, and top-1 linking."""
    keys = [k for k, v in features.items() if np.all(np.isfinite(v))]
    if len(keys) < 4:
        return {"auc": float("nan"), "top1_accuracy": float("nan"), "chance": float("nan")}
    X = np.array([features[k] for k in keys])
    X = (X - X.mean(axis=0)) / np.maximum(X.std(axis=0), 1e-12)
    veh = np.array([k[0] for k in keys])
    run = np.array([k[1] for k in keys])
    D = np.linalg.norm(X[:, None, :] - X[None, :, :], axis=-1)
    other_run = run[:, None] != run[None, :]
    same = (veh[:, None] == veh[None, :]) & other_run
    diff = (veh[:, None] != veh[None, :]) & other_run
    ds, dd = D[same], D[diff]
    # Mann-Whitney AUC: P(distance of a same-vehicle pair < a different-vehicle pair).
    ranks = np.argsort(np.argsort(np.concatenate([ds, dd])))
    auc = 1.0 - (ranks[:ds.size].sum() - ds.size * (ds.size - 1) / 2) / (ds.size * dd.size)
    Dm = np.where(other_run, D, np.inf)
    nn = np.argmin(Dm, axis=1)
    top1 = float(np.mean(veh[nn] == veh))
    return {"auc": float(auc), "top1_accuracy": top1, "chance": 1.0 / len(set(veh.tolist()))}


def _study_pipeline(config: AttackStudyConfig, seed: int):
    """The study's (per-process cached) fleet pipeline."""
    return pipeline_for(config.experiment, seed)


def _run_seeds(config: AttackStudyConfig, seed: int):
    """One seed per segment."""
    return SeedPlan(seed).runs(config.n_runs)


@dataclass(frozen=True)
class _AttackTask:
    """Picklable task: the attacks of runs ``indices`` (setup cached once per process)."""

    config: AttackStudyConfig
    seed: int
    key: bytes

    def __call__(self, indices) -> list[SegmentAttacks]:
        pipe = _study_pipeline(self.config, self.seed)
        seeds = _run_seeds(self.config, self.seed)
        return [attack_segment(pipe, self.config, r, seeds[r], self.key) for r in indices]


def _errors_by_attack(config: AttackStudyConfig, pipe, runs: list[SegmentAttacks]) -> dict:
    """Relative pole errors ((4,) per message) per (mechanism, attack), in the order first made."""
    errs: dict[tuple[str, str], list[np.ndarray]] = {}
    for run in runs:
        for mech, attack, e in run.pole_errors:
            errs.setdefault((mech, attack), []).append(e)
    # Hardened "multiplicity": ARX poles that recur over two consecutive segments of a vehicle.
    targets = target_poles(pipe)
    for r in range(1, len(runs)):
        for j in range(config.experiment.n_vehicles):
            est = intersect_pole_sets(runs[r - 1].arx_poles[j], runs[r].arx_poles[j], config.prior)
            errs.setdefault(("hardened", "multiplicity"), []).append(pole_errors(est, targets[j]))
    return errs


def _attack_rows(errs: dict) -> list[dict]:
    """``attack.csv``: per (mechanism, attack) the median over messages of the median pole error, the
    success rate (every pole within :data:`SUCCESS_TOLERANCE`) and the number of messages."""
    rows = []
    for (mech, attack), lst in errs.items():
        E = np.array(lst)
        per_msg = np.median(E, axis=1)
        rows.append({"mechanism": mech, "attack": attack,
                     "median_rel_pole_error": float(np.median(per_msg)),
                     "success_rate": float(np.mean(np.all(E < SUCCESS_TOLERANCE, axis=1))),
                     "n_messages": int(E.shape[0])})
    return rows


def _exactness_rows(runs: list[SegmentAttacks]) -> list[dict]:
    """``exactness.csv``: the largest relative change of any estimate vs. no privacy, per mechanism."""
    return [{"mechanism": m, "max_rel_diff": max(run.max_rel_diff[m] for run in runs)} for m in EXACT_MECHANISMS]


def _linkability_rows(runs: list[SegmentAttacks], n_vehicles: int) -> list[dict]:
    """``linkability.csv``: how well each feature links a vehicle's messages across segments."""
    rows = []
    for mech, feature in _LINK_FEATURES:
        feats = {(j, r): run.features[(mech, j)] for r, run in enumerate(runs) for j in range(n_vehicles)}
        rows.append({"mechanism": mech, "feature": feature, **_linkability(feats)})
    return rows


def _baseline_row(name: str, mse: np.ndarray, ms: float, nbytes: int, note: str = "") -> dict:
    """One ``baselines.csv`` row: MSE of vehicles 1..3 ((m/s)^2) and the cost of one message."""
    return {"mechanism": name, "mse_vehicle1": mse[0], "mse_vehicle2": mse[1], "mse_vehicle3": mse[2],
            "ms_per_message": ms, "bytes_per_message": nbytes, "note": note}


def _baseline_rows(config: AttackStudyConfig, runs: list[SegmentAttacks], he: dict) -> list[dict]:
    """``baselines.csv``: accuracy and cost per message of every mechanism on the same segments
    (``he``: :func:`roadcollab.privacy.baselines.paillier_cost` of a hardened message)."""
    timing = {m: float(np.median([t for run in runs for t in run.timing_ms[m]])) for m in runs[0].timing_ms}
    nbytes = {m: int(np.median([b for run in runs for b in run.nbytes[m]])) for m in runs[0].nbytes}
    mse = {k: np.mean([run.mse[k] for run in runs], axis=0) for k in runs[0].mse}
    sigmas = runs[0].dp_sigmas
    rows = [_baseline_row(m, mse[m], timing[m], nbytes[m], note) for m, note in (
        ("none", "Algorithm 1 in the clear"), ("paper", "Algorithm 2 (obfuscation + encode)"), ("hardened", "z only"))]
    for e in config.dp_epsilons:
        rows.append(_baseline_row(
            f"dp(eps={e:g})", mse[dp_mse_key(e)], timing["dp"], nbytes["dp"],
            f"Gaussian mechanism on z, delta={config.dp_delta:g}, rho={config.dp_rho:g}, sigma={sigmas[e]:.3g}"))
    rows.append(_baseline_row(
        "he", mse["hardened"], he["ms_per_message"], int(he["bytes_per_message"]),
        f"Paillier {config.paillier_bits}-bit on z, extrapolated from {he.get('extrapolated_from', '')} values; "
        f"keygen {he['keygen_ms']:.0f} ms"))
    rows.append(_baseline_row("aead", mse["hardened"], timing["aead"], nbytes["aead"],
                              "ChaCha20-Poly1305 on the encoded hardened message"))
    return rows


def run_attack_study(config: AttackStudyConfig, seed: int, *, progress: Callable[[int], None] | None = None,
                     workers: int | None = None, scheduler: str | None = None) -> AttackStudyResult:
    """Run the security study (see the module docstring), serially or on Dask.

    Results do not depend on ``workers``/``scheduler`` except the timing columns.

    Parameters
    ----------
    config : AttackStudyConfig
    seed : int
        Root seed (>= 0) of the fleet and of every run.
    progress : callable, optional
        Called with the number of finished runs.
    workers : int, optional
        Run on a local Dask cluster with this many worker processes.
    scheduler : str, optional
        Address of an existing Dask scheduler (e.g. ``tcp://host:8786``); not with ``workers``.

    Returns
    -------
    AttackStudyResult
        Attack, exactness, linkability and baseline rows, and the pole examples of the first run.

    Raises
    ------
    ParameterError
        If ``config`` is not an AttackStudyConfig, ``seed`` is negative, or both ``workers``
        and ``scheduler`` are given.
    """
    if not isinstance(config, AttackStudyConfig):
        raise ParameterError(f"config must be an AttackStudyConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    pipe = _study_pipeline(config, seed)
    runs = map_runs(_AttackTask(config, seed, baselines.new_key()), config.n_runs, workers=workers,
                    scheduler=scheduler, progress=progress)
    attack_rows = _attack_rows(_errors_by_attack(config, pipe, runs))
    exactness_rows = _exactness_rows(runs)
    link_rows = _linkability_rows(runs, config.experiment.n_vehicles)
    # Paillier: one ciphertext per fixed-point number of a hardened message's z.
    he = baselines.paillier_cost(runs[0].last_z.ravel(), key_bits=config.paillier_bits,
                                 sample=config.paillier_sample, rng=np.random.default_rng(seed))
    return AttackStudyResult(config=config, seed=seed, attack_rows=attack_rows, exactness_rows=exactness_rows,
                             linkability_rows=link_rows, baseline_rows=_baseline_rows(config, runs, he),
                             pole_examples=list(runs[0].pole_examples))
