"""The security study behind ``roadcollab attack``: attacks, linkability, exactness and the
conventional baselines measured side by side on the same segments.

One run is one segment (a fresh road, fresh sensor noise, fresh obfuscators); the fleet is
the same in every run, so messages of one vehicle on different runs are what a curious
receiver could try to link.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..wire import protocol
from .._validation import check_int
from ..errors import ParameterError
from ..experiments.config import ExperimentConfig
from ..collaboration.relay import Exchange, Relay
from ..privacy.attacks import (PhysicalPrior, SUCCESS_TOLERANCE, attack_model_reduction, attack_multiplicity, attack_pole_intersection, attack_signals_prior, attack_signals_reduction, intersect_pole_sets, pole_errors)
from ..privacy.physical_fit import attack_physical_fit
from ..lti.arx import arx_poles
from ..lti.batch2x2 import receiver_z
from ..models.simulation import add_sensor_noise, simulate_response

__all__ = ["AttackStudyConfig", "AttackStudyResult", "run_attack_study"]


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
        import dataclasses

        return dataclasses.asdict(self)


@dataclass(eq=False)
class AttackStudyResult:
    """Everything ``roadcollab attack`` writes."""

    config: AttackStudyConfig
    seed: int
    attack_rows: list[dict]
    exactness_rows: list[dict]
    linkability_rows: list[dict]
    baseline_rows: list[dict]
    pole_examples: list[dict]


def _feature_poles(poles: np.ndarray) -> np.ndarray:
    """(f1, zeta1, f2, zeta2) of the two upper-half-plane poles sorted by frequency."""
    up = sorted([p for p in poles if p.imag > 0], key=abs)[:2]
    if len(up) < 2:
        return np.full(4, np.nan)
    return np.array([v for p in up for v in (np.log(abs(p) / (2 * np.pi)), -p.real / abs(p))])


def _spectral_feature(z: np.ndarray, w_band: np.ndarray, grid, n_bands: int = 12) -> np.ndarray:
    """Log band-averaged |W - Z|^2 / |Z|^2 per track: the vehicle's model-error signature."""
    Z, W = grid.rfft(z), grid.rfft(w_band)
    edges = np.geomspace(0.6, 50.0, n_bands + 1)
    out = []
    for c in range(2):
        for lo, hi in zip(edges[:-1], edges[1:]):
            sel = (grid.freqs >= lo) & (grid.freqs < hi)
            num = np.sum(np.abs(W[sel, c] - Z[sel, c]) ** 2)
            den = np.sum(np.abs(Z[sel, c]) ** 2)
            out.append(np.log(max(num, 1e-300) / max(den, 1e-300)))
    return np.array(out)


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
    from ..experiments.pipeline import pipeline_for

    return pipeline_for(config.experiment, seed)


def _run_seeds(config: AttackStudyConfig, seed: int):
    # Same split as the reproduction: child 0 draws the fleet, child 1 the runs.
    return np.random.SeedSequence(seed).spawn(2)[1].spawn(config.n_runs)


@dataclass(frozen=True)
class _AttackTask:
    """Picklable task: the attacks of runs ``indices`` (setup cached once per process)."""

    config: AttackStudyConfig
    seed: int
    key: bytes

    def __call__(self, indices) -> list[dict]:
        pipe = _study_pipeline(self.config, self.seed)
        seeds = _run_seeds(self.config, self.seed)
        return [_attack_run(pipe, self.config, r, seeds[r], self.key) for r in indices]


def _encoded(message) -> tuple:
    """``(message, its encoding)``: what is timed per message."""
    return message, protocol.encode(message)


def _attack_run(pipe, config: AttackStudyConfig, r: int, rs: np.random.SeedSequence, key: bytes) -> dict:
    """Everything one segment contributes to the study."""
    from ..privacy import baselines

    cfg, grid = config.experiment, pipe.grid
    V = cfg.n_vehicles
    targets = [e.S_ss.continuous_poles() for e in pipe.estimators]
    eps_list = tuple(config.dp_epsilons)
    sens = baselines.l2_sensitivity(pipe.estimators[0], config.dp_rho)
    sigmas = {e: baselines.gaussian_sigma(e, config.dp_delta, sens) for e in eps_list}
    out = {"errs": [], "feats": {}, "exact": {"none": 0.0, "paper": 0.0, "hardened": 0.0},
           "mse": {}, "timing": {m: [] for m in ("none", "paper", "hardened", "dp", "aead")},
           "nbytes": {m: [] for m in ("none", "paper", "hardened", "dp", "aead")},
           "arx": {}, "examples": [], "sigmas": sigmas, "last_z": None}

    def add(mech, attack, est, j):
        out["errs"].append((mech, attack, pole_errors(est, targets[j])))

    road_ss, noise_ss, priv_ss, dp_ss, own_ss = rs.spawn(5)
    road = pipe.road(np.random.default_rng(road_ss))
    noise_rng, priv_rng, dp_rng, own_rng = (np.random.default_rng(s) for s in (noise_ss, priv_ss, dp_ss, own_ss))
    w = road.velocity
    W_true = grid.rfft(w)
    w_band = grid.irfft(grid.reg_weight[:, None] * W_true)      # nfft samples, band-limited like z
    n, sl = grid.n_samples, cfg.scored
    truth = grid.irfft(grid.weight[:, None] * W_true, n)[sl]

    def seg_mse(X):
        return float(np.mean((grid.irfft(grid.weight[:, None] * X, n)[sl] - truth) ** 2))

    def timed(name, fn):
        t0 = time.perf_counter()
        msg, data = fn()
        out["timing"][name].append((time.perf_counter() - t0) * 1e3)
        out["nbytes"][name].append(len(data))
        return msg

    ests = pipe.estimators
    relays = {"none": Relay(ests, "none"), "paper": Relay(ests, Exchange("paper", cfg.obfuscation), rng=priv_rng),
              "hardened": Relay(ests, "hardened")}
    dp_relays = {e: Relay(ests, Exchange("dp", dp_sigma=sigmas[e]), rng=dp_rng) for e in eps_list}
    mse = {m: np.zeros(3) for m in ["none", "paper", "hardened"] + [f"dp_eps_{e:g}" for e in eps_list]}
    plain_in = paper_in = hard_in = None
    own_proxy = None
    dp_in = {e: None for e in eps_list}
    for j, est in enumerate(pipe.estimators):
        y = add_sensor_noise(simulate_response(est.true_plant, w), cfg.sensor_noise_std, rng=noise_rng)
        res = est.estimate(y, plain_in)
        scale = max(float(np.max(np.abs(res.estimate))), 1e-300)
        plain = timed("none", lambda: _encoded(relays["none"].send(j, res).message))
        rp = est.estimate(y, paper_in)
        paper = timed("paper", lambda: _encoded(relays["paper"].send(j, rp).message))
        if j == 0:
            own_proxy = grid.irfft(est.invert(grid.rfft(y)))
        rh = est.estimate(y, hard_in)
        hard = timed("hardened", lambda: _encoded(relays["hardened"].send(j, rh).message))
        timed("aead", lambda: (None, baselines.seal(key, protocol.encode(relays["hardened"].send(j, rh).message))))
        out["exact"]["paper"] = max(out["exact"]["paper"], float(np.max(np.abs(rp.estimate - res.estimate))) / scale)
        out["exact"]["hardened"] = max(out["exact"]["hardened"],
                                       float(np.max(np.abs(rh.estimate - res.estimate))) / scale)
        if j < 3:
            mse["none"][j], mse["paper"][j], mse["hardened"][j] = seg_mse(res.W_hat), seg_mse(rp.W_hat), \
                seg_mse(rh.W_hat)
        # Differential privacy: the hardened chain with Gaussian noise on every z sent.
        for e in eps_list:
            rd = est.estimate(y, dp_in[e])
            if e == eps_list[0]:
                dp_in[e] = timed("dp", lambda: _encoded(dp_relays[e].send(j, rd).message))
            else:
                dp_in[e] = dp_relays[e].send(j, rd).message
            if j < 3:
                mse[f"dp_eps_{e:g}"][j] = seg_mse(rd.W_hat)
            # The strongest signal attack on the noisy z: the privacy/accuracy trade-off.
            if r < config.physical_fit_runs:
                add(f"dp(eps={e:g})", "physical_fit",
                    attack_physical_fit(dp_in[e].z, w_band, grid, cfg.fleet.nominal), j)
        # Attacks on vehicle j's outgoing messages.
        for mech, msg in (("none", plain), ("paper", paper)):
            est_poles = {"model_reduction": attack_model_reduction(msg),
                         "pole_intersection": attack_pole_intersection(msg, config.prior),
                         "multiplicity": attack_multiplicity(msg, config.prior)}
            for attack, poles in est_poles.items():
                add(mech, attack, poles, j)
        # est_poles now holds the attacks on the paper's message (the last in the loop).
        mu = est_poles["multiplicity"]
        if r == 0 and j < 3:
            out["examples"].append({"vehicle": j + 1, "true": targets[j], **est_poles})
        add("hardened", "model_reduction", attack_signals_reduction(hard.z, w_band, grid.dt), j)
        add("hardened", "pole_intersection", attack_signals_prior(hard.z, w_band, grid.dt, config.prior), j)
        out["arx"][j] = arx_poles(hard.z, w_band - hard.z, grid.dt, 8, 2)
        if r < config.physical_fit_runs:
            add("hardened", "physical_fit", attack_physical_fit(hard.z, w_band, grid, cfg.fleet.nominal), j)
            # Without the true road: the next vehicle's own inversion stands in for it.
            if j + 1 < V:
                nxt = pipe.estimators[j + 1]
                y_next = add_sensor_noise(simulate_response(nxt.true_plant, w), cfg.sensor_noise_std, rng=own_rng)
                own = grid.irfft(nxt.invert(grid.rfft(y_next)))
                add("hardened", "physical_fit_own_road", attack_physical_fit(hard.z, own, grid, cfg.fleet.nominal), j)
            # Any exact mechanism hands the receiver z (Theorem 1): recover it from the
            # obfuscated message and attack it the same way.
            z_paper = grid.irfft(_recover_z(paper, grid))
            add("paper", "physical_fit", attack_physical_fit(z_paper, w_band, grid, cfg.fleet.nominal), j)
        # Reference: what the attacker knows with no message at all (the fleet's nominal).
        add("no_message", "prior_guess", _nominal_poles(cfg.fleet.nominal), j)
        out["feats"][("none", j)] = _feature_poles(plain.S.continuous_poles())
        out["feats"][("paper", j)] = _feature_poles(mu)
        out["feats"][("hardened", j)] = _spectral_feature(hard.z, w_band, grid)
        # A receiver without the true road compares with its own inversion (vehicle 1's
        # inversion stands in for a fixed receiver's here).
        out["feats"][("hardened_own_road", j)] = _spectral_feature(hard.z, own_proxy, grid)
        plain_in, paper_in, hard_in = plain, paper, hard
        if r == 0 and j == V - 1:
            out["last_z"] = hard.z
    out["mse"] = mse
    return out


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
    from ..privacy import baselines
    from ..experiments.runner import map_runs

    if not isinstance(config, AttackStudyConfig):
        raise ParameterError(f"config must be an AttackStudyConfig, got {type(config).__name__}")
    seed = check_int("seed", seed, low=0)
    cfg = config.experiment
    pipe = _study_pipeline(config, seed)
    V = cfg.n_vehicles
    targets = [e.S_ss.continuous_poles() for e in pipe.estimators]
    runs = map_runs(_AttackTask(config, seed, baselines.new_key()), config.n_runs, workers=workers,
                    scheduler=scheduler, progress=progress)
    errs: dict[tuple[str, str], list[np.ndarray]] = {}
    for run in runs:
        for mech, attack, e in run["errs"]:
            errs.setdefault((mech, attack), []).append(e)
    # Hardened "multiplicity": ARX poles that recur over two consecutive segments of a vehicle.
    for r in range(1, len(runs)):
        for j in range(V):
            est = intersect_pole_sets(runs[r - 1]["arx"][j], runs[r]["arx"][j], config.prior)
            errs.setdefault(("hardened", "multiplicity"), []).append(pole_errors(est, targets[j]))
    attack_rows = []
    for (mech, attack), lst in errs.items():
        E = np.array(lst)
        per_msg = np.median(E, axis=1)
        attack_rows.append({"mechanism": mech, "attack": attack,
                            "median_rel_pole_error": float(np.median(per_msg)),
                            "success_rate": float(np.mean(np.all(E < SUCCESS_TOLERANCE, axis=1))),
                            "n_messages": int(E.shape[0])})
    exact = {m: max(run["exact"][m] for run in runs) for m in ("none", "paper", "hardened")}
    exactness_rows = [{"mechanism": m, "max_rel_diff": v} for m, v in exact.items()]
    link_rows = []
    for mech, feature in (("none", "poles of S"), ("paper", "multiplicity-attack poles"),
                          ("hardened", "model-error spectrum (true road known)"),
                          ("hardened_own_road", "model-error spectrum vs a fixed receiver's own inversion")):
        feats = {(j, r): run["feats"][(mech, j)] for r, run in enumerate(runs) for j in range(V)}
        link_rows.append({"mechanism": mech, "feature": feature, **_linkability(feats)})
    # Paillier: one ciphertext per fixed-point number of a hardened message's z.
    he = baselines.paillier_cost(runs[0]["last_z"].ravel(), key_bits=config.paillier_bits,
                                 sample=config.paillier_sample, rng=np.random.default_rng(seed))
    timing = {m: float(np.median([t for run in runs for t in run["timing"][m]])) for m in runs[0]["timing"]}
    nbytes = {m: int(np.median([b for run in runs for b in run["nbytes"][m]])) for m in runs[0]["nbytes"]}
    mse = {k: np.mean([run["mse"][k] for run in runs], axis=0) for k in runs[0]["mse"]}
    sigmas = runs[0]["sigmas"]
    base_rows = []

    def brow(name, key_mse, ms, b, note=""):
        m = mse[key_mse]
        base_rows.append({"mechanism": name, "mse_vehicle1": m[0], "mse_vehicle2": m[1], "mse_vehicle3": m[2],
                          "ms_per_message": ms, "bytes_per_message": b, "note": note})

    brow("none", "none", timing["none"], nbytes["none"], "Algorithm 1 in the clear")
    brow("paper", "paper", timing["paper"], nbytes["paper"], "Algorithm 2 (obfuscation + encode)")
    brow("hardened", "hardened", timing["hardened"], nbytes["hardened"], "z only")
    for e in config.dp_epsilons:
        brow(f"dp(eps={e:g})", f"dp_eps_{e:g}", timing["dp"], nbytes["dp"],
             f"Gaussian mechanism on z, delta={config.dp_delta:g}, rho={config.dp_rho:g}, sigma={sigmas[e]:.3g}")
    brow("he", "hardened", he["ms_per_message"], int(he["bytes_per_message"]),
         f"Paillier {config.paillier_bits}-bit on z, extrapolated from {he.get('extrapolated_from', '')} values; "
         f"keygen {he['keygen_ms']:.0f} ms")
    brow("aead", "hardened", timing["aead"], nbytes["aead"], "ChaCha20-Poly1305 on the encoded hardened message")
    return AttackStudyResult(config=config, seed=seed, attack_rows=attack_rows, exactness_rows=exactness_rows,
                             linkability_rows=link_rows, baseline_rows=base_rows, pole_examples=runs[0]["examples"])


def _recover_z(message, grid) -> np.ndarray:
    """What a receiver computes from an (obfuscated) exchange message: W T^-1 (e - S w^f)."""
    act = grid.active
    om = grid.omega_dt[act]
    T, S = message.T.frequency_response(om), message.S.frequency_response(om)
    Z = np.zeros((grid.n_bins, 2), complex)
    E, Wf = grid.rfft(message.e)[act], grid.rfft(message.wf)[act]
    Z[act] = receiver_z(T, S, E, Wf, grid.reg_weight[act])
    return Z


def _nominal_poles(nominal) -> np.ndarray:
    from ..models.vehicle import half_car_model

    return half_car_model(nominal).poles()
