"""The security study's tables from its segments: attacks, exactness, linkability, baselines, DP
composition and the privacy/accuracy frontier (typed rows of
:mod:`~roadcollab.experiments.security.rows`)."""

from __future__ import annotations

import numpy as np

from ...privacy.attacks import intersect_pole_sets, pole_errors
from ...privacy.baselines.dp_composition import composition_table
from ...privacy.baselines.dp import DPSpec
from .config import AttackStudyConfig
from .replica import ReplicaOutcome
from .rows import (AttackRow, BaselineRow, CompositionRow, ExactnessRow, FrontierPoint, LinkabilityRow,
                   attack_row)
from .segment import EXACT_MECHANISMS, SegmentAttacks, dp_mse_key, target_poles

__all__ = ["attack_rows", "exactness_rows", "linkability_rows", "baseline_rows", "composition_rows",
           "frontier_points"]

#: Linkability rows: the mechanism and the feature a curious receiver compares across segments.
_LINK_FEATURES = (("none", "poles of S"), ("paper", "multiplicity-attack poles"),
                  ("hardened", "model-error spectrum (true road known)"),
                  ("hardened_own_road", "model-error spectrum vs a fixed receiver's own inversion"))


def _road_and_segments(mechanism: str, attack: str) -> tuple[str, int]:
    """What the per-segment attacks assume: the road they are given and the messages they combine."""
    if attack == "prior_guess":
        return "-", 0
    if attack == "physical_fit_own_road":
        return "own", 1
    if mechanism == "hardened" or attack == "physical_fit":
        return "true", 2 if attack == "multiplicity" else 1
    return "-", 1


def attack_rows(config: AttackStudyConfig, pipe, runs: list[SegmentAttacks], replica: ReplicaOutcome
                ) -> list[AttackRow]:
    """``attack.csv``: the per-segment attacks, the hardened multiplicity attack over two segments,
    then the replica cells.

    Parameters
    ----------
    config : AttackStudyConfig
    pipe : FleetPipeline
        The study's fleet (the targets' poles).
    runs : list of SegmentAttacks
    replica : ReplicaOutcome

    Returns
    -------
    list of AttackRow
    """
    errs: dict[tuple[str, str], list[np.ndarray]] = {}
    for run in runs:
        for mech, attack, e in run.pole_errors:
            errs.setdefault((mech, attack), []).append(e)
    targets = target_poles(pipe)
    for r in range(1, len(runs)):   # hardened "multiplicity": ARX poles recurring over two segments
        for j in range(config.experiment.n_vehicles):
            est = intersect_pole_sets(runs[r - 1].arx_poles[j], runs[r].arx_poles[j], config.prior)
            errs.setdefault(("hardened", "multiplicity"), []).append(pole_errors(est, targets[j]))
    rows = [attack_row(m, a, *_road_and_segments(m, a), e) for (m, a), e in errs.items()]
    return rows + list(replica.rows)


def exactness_rows(runs: list[SegmentAttacks], replica: ReplicaOutcome) -> list[ExactnessRow]:
    """``exactness.csv``: the largest relative change of any estimate vs. no privacy, per mechanism;
    for secure aggregation, of the fused average vs. the plain average.

    Parameters
    ----------
    runs : list of SegmentAttacks
    replica : ReplicaOutcome

    Returns
    -------
    list of ExactnessRow
    """
    rows = [ExactnessRow(m, max(run.max_rel_diff[m] for run in runs)) for m in EXACT_MECHANISMS]
    return rows + [ExactnessRow("secure_aggregation", replica.secagg_exactness)]


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



def linkability_rows(runs: list[SegmentAttacks], n_vehicles: int) -> list[LinkabilityRow]:
    """``linkability.csv``: how well each feature links a vehicle's messages across segments.

    Parameters
    ----------
    runs : list of SegmentAttacks
    n_vehicles : int

    Returns
    -------
    list of LinkabilityRow
    """
    rows = []
    for mech, feature in _LINK_FEATURES:
        feats = {(j, r): run.features[(mech, j)] for r, run in enumerate(runs) for j in range(n_vehicles)}
        rows.append(LinkabilityRow(mech, feature, **_linkability(feats)))
    return rows


def _paillier_note(config: AttackStudyConfig, he: dict) -> str:
    if not he.get("packing"):
        return (f"Paillier {config.paillier_bits}-bit on z, one value per ciphertext, extrapolated from "
                f"{he.get('extrapolated_from', '')} values; keygen {he['keygen_ms']:.0f} ms")
    return (f"Paillier {config.paillier_bits}-bit on z (gmpy2 {he['gmpy2']}), {he['values_per_ciphertext']} values "
            f"per ciphertext in {he['slot_bits']}-bit slots (sums of {he['n_summands']}), r^n precomputed offline "
            f"({he['offline_ms_per_message']:.0f} ms per message, not counted); decryption "
            f"{he['decrypt_ms_per_message']:.0f} ms; keygen {he['keygen_ms']:.0f} ms")


# Long: one row per mechanism, each with its own note; a table in code form.
def baseline_rows(config: AttackStudyConfig, runs: list[SegmentAttacks], he: dict, replica: ReplicaOutcome
                  ) -> list[BaselineRow]:
    """``baselines.csv``: accuracy and cost per message of every mechanism on the same segments.

    Parameters
    ----------
    config : AttackStudyConfig
    runs : list of SegmentAttacks
    he : dict
        :func:`roadcollab.privacy.baselines.paillier_cost` of a hardened message.
    replica : ReplicaOutcome
        For secure aggregation's accuracy and cost.

    Returns
    -------
    list of BaselineRow
    """
    timing = {m: float(np.median([t for run in runs for t in run.timing_ms[m]])) for m in runs[0].timing_ms}
    nbytes = {m: int(np.median([b for run in runs for b in run.nbytes[m]])) for m in runs[0].nbytes}
    mse = {k: np.mean([run.mse[k] for run in runs], axis=0) for k in runs[0].mse}
    sigmas = runs[0].dp_sigmas

    def row(name, m, ms, nb, note=""):
        return BaselineRow(name, float(m[0]), float(m[1]), float(m[2]), float(ms), int(nb), note)

    rows = [row(m, mse[m], timing[m], nbytes[m], note) for m, note in (
        ("none", "Algorithm 1 in the clear"), ("paper", "Algorithm 2 (obfuscation + encode)"), ("hardened", "z only"))]
    for e in config.dp_epsilons:
        rows.append(row(f"dp(eps={e:g})", mse[dp_mse_key(e)], timing["dp"], nbytes["dp"],
                        f"Gaussian mechanism on z, delta={config.dp_delta:g}, rho={config.dp_rho:g}, "
                        f"sigma={sigmas[e]:.3g}"))
    rows.append(row("he", mse["hardened"], he["ms_per_message"], he["bytes_per_message"], _paillier_note(config, he)))
    rows.append(row("aead", mse["hardened"], timing["aead"], nbytes["aead"],
                    "ChaCha20-Poly1305 on the encoded hardened message"))
    c, spec = replica.secagg_cost, replica.spec
    agg = replica.mse["secure_aggregation"]
    rows.append(row("secure_aggregation", (agg,) * 3, c["ms_per_message"], c["bytes_per_message"],
                    f"every vehicle receives the average of all {config.experiment.n_vehicles} inversions; active "
                    f"protocol, k={spec.min_inputs}, t={spec.threshold}, c={spec.max_colluders}, {c['rounds']} rounds, "
                    f"Ed25519-signed adverts, share commitments and consistency round, X25519 + ChaCha20 masks in "
                    f"Z_2^64, resolution {spec.resolution:.2g} m/s, clip {spec.clip:g} m/s; aggregator "
                    f"{c['aggregator_ms']:.1f} ms; semi-honest protocol {c['semi_honest']['ms_per_message']:.1f} ms, "
                    f"{c['semi_honest']['bytes_per_message']} bytes"))
    return rows


def composition_rows(config: AttackStudyConfig, segments=(1, 3, 10, 100)) -> list[CompositionRow]:
    """``dp_composition.csv``: each per-message DP level composed over a vehicle's segments.

    Parameters
    ----------
    config : AttackStudyConfig
        Per-message levels ``dp_epsilons`` and ``dp_delta``.
    segments : sequence of int
        Messages composed.

    Returns
    -------
    list of CompositionRow
    """
    spec = DPSpec(epsilons=tuple(config.dp_epsilons), delta=config.dp_delta, rho=config.dp_rho)
    return [CompositionRow(r["epsilon_per_message"], r["delta"], r["noise_multiplier"], r["segments"],
                           r["epsilon_total"]) for r in composition_table(spec, segments)]


def frontier_points(attacks: list[AttackRow], baselines: list[BaselineRow], replica: ReplicaOutcome,
                    n_vehicles: int) -> list[FrontierPoint]:
    """Each mechanism's strongest attack (highest success, then lowest error) against its MSE.

    Parameters
    ----------
    attacks : list of AttackRow
    baselines : list of BaselineRow
    replica : ReplicaOutcome
        MSE of the fused relay and of secure aggregation.
    n_vehicles : int
        Fleet size (secure aggregation's ``n - 1`` colluders case is outside its guarantee and left out).

    Returns
    -------
    list of FrontierPoint
        Mechanisms with both an accuracy and an attack row; MSE of vehicles 2-3 (the receivers).
    """
    mse = {b.mechanism: 0.5 * (b.mse_vehicle2 + b.mse_vehicle3) for b in baselines}
    mse.update(replica.mse)
    mse["paper_vehicle"] = mse.get("paper", np.nan)
    out = []
    for mech in dict.fromkeys(a.mechanism for a in attacks):
        if mech not in mse:
            continue
        # Secure aggregation's guarantee assumes k honest inputs: the n - 1 colluders row is outside it.
        inside = [a for a in attacks if a.mechanism == mech and not (
            mech == "secure_aggregation" and a.attack == f"replica_collusion_c{n_vehicles - 1}")]
        best = min(inside, key=lambda a: (-a.success_rate, a.median_rel_pole_error))
        out.append(FrontierPoint(mech, best.attack, best.road, best.segments, best.success_rate,
                                 best.median_rel_pole_error, float(mse[mech])))
    return out
