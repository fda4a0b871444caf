"""Outputs of ``roadcollab attack``: attack, exactness, linkability, poisoning, baseline and DP-composition
tables, Figs. 8-11, the privacy/accuracy frontier, ``config.json`` and ``report.md``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..experiments.security.fusion_poisoning import PoisoningSummary
from ..experiments.security.rows import (AttackRow, BaselineRow, CompositionRow, ExactnessRow, FrontierPoint,
                                         LinkabilityRow, PoleRow, pole_rows)
from . import plotting, plotting_security
from .records import markdown_table, output_dir, row_columns, run_header, write_config, write_rows

__all__ = ["security_markdown", "write_attack"]

_ATTACK_SHOWN = ["mechanism", "attack", "road", "segments", "median_rel_pole_error", "success_rate", "n_messages",
                 "epsilon_total"]
_POISON_SHOWN = ["strategy", "target", "ratio", "max_ratio_to_observer", "fake_anomalies_reported",
                 "real_anomalies_lost", "refused", "runs"]


def _pole_figure(example: dict) -> str:
    """File name of the pole figure of one example (Figs. 8-10 for vehicles 1-3)."""
    return f"fig{7 + example['vehicle']}_poles_vehicle{example['vehicle']}.png"


def _attack_lines(result) -> list[str]:
    """Threat model, the attack table and the pole figures."""
    cfg = result.config
    lines = [
        "## Security", "",
        f"{cfg.n_runs} segments x {cfg.experiment.n_vehicles} vehicles; seed {result.seed}. The target is the "
        "four poles of S_j = -P_hat_j (the vehicle's suspension model). An attack succeeds on a message when "
        "every pole is recovered within 1 % relative error after Hungarian matching. `road` is what the attacker "
        "is given: the true road, the fleet's fused map (`fused`), its own inversion (`own`) or nothing (`-`); "
        "`segments` is how many messages of one vehicle one estimate combines. `no_message / prior_guess` is "
        "what the attacker knows without any message (the fleet's nominal poles).", "",
        f"The replica attacker (first {cfg.replica_runs} segments, vehicles 1..{cfg.replica_targets}) re-runs the "
        "receiver's pipeline and fits the sender's model to what it receives. Every exact relay (`none`, `paper`, "
        "`paper_vehicle`, `hardened`) hands the receiver the same z (see `exactness.csv`), so one set of replica "
        "fits scores all four. `epsilon_total` is the composed DP level of the messages one estimate uses.", "",
        "### Attacks (`attack.csv`)", "",
        markdown_table(list(result.attack_rows), _ATTACK_SHOWN), "",
        "![attack success](fig11_attack_success.png)", "",
        "### Privacy against accuracy (`frontier.csv`)", "",
        "Each mechanism's strongest attack against the receivers' road-velocity MSE.", "",
        markdown_table(list(result.frontier), row_columns(FrontierPoint)), "",
        "![privacy/accuracy frontier](fig12_privacy_frontier.png)", "",
        "### Figs. 8-10: poles of S_1..S_3 and the attackers' estimates (paper's mechanism, run 1)", "",
    ]
    for ex in result.pole_examples:
        lines += [f"![Vehicle {ex['vehicle']}]({_pole_figure(ex)})", ""]
    return lines


def _tables_lines(result) -> list[str]:
    """Exactness, linkability, poisoning, DP composition and baseline tables."""
    clip = (" An honest input reached the clipping bound: secure aggregation is not exact here."
            if result.secagg_clipped else "")
    return [
        "### Exactness (`exactness.csv`): largest relative change of any estimate vs. no privacy", "",
        "For `secure_aggregation`: the securely aggregated average vs. the plain average of the same inputs, "
        "with and without two vehicles dropping out after the key round." + clip, "",
        markdown_table(list(result.exactness_rows), row_columns(ExactnessRow)), "",
        "### Linkability (`linkability.csv`): can messages of one vehicle be linked across segments?", "",
        "AUC = probability that two messages of the same vehicle (different segments) are closer in the "
        "feature than two messages of different vehicles (0.5 = no information); top-1 = how often the "
        "nearest message from another segment is the same vehicle's.", "",
        markdown_table(list(result.linkability_rows), row_columns(LinkabilityRow)), "",
        "### Poisoning (`poisoning.csv`)", "",
        "`receiver_*`: hostile but well-formed messages to vehicle 2, which runs the receiver guard; `ratio` is "
        "its MSE over its MSE with the honest message, `max_ratio_to_observer` over its own observer-only MSE "
        "(target <= 2). `fused_mean`: one malicious vehicle of the fleet against the plain (count-weighted) "
        "average; `fused_robust`: against the robust fusion node (common-scale biweight) with anomaly reports "
        "corroborated by f + 1 of n vehicles (f = floor((n - 1) / 2)); `collusion_c{c}_*`: c vehicles that "
        "pool their inputs and send one message (docs/security-receivers.md). `receiver_*` rows "
        "`coherent_*`, `fake_pothole_09`, `slow_drift`: lies built with the receiver guard's own statistics. "
        "Anomalies: reported ones matching neither truth nor an honest report, and true ones reported "
        "honestly but lost.", "",
        markdown_table(list(result.poisoning_rows), _POISON_SHOWN), "",
        "### DP composition (`dp_composition.csv`)", "",
        "A vehicle's parameters are the same in every message: its exposure composes over segments.", "",
        markdown_table(list(result.composition_rows), row_columns(CompositionRow)), "",
        "### Baselines on the same segments (`baselines.csv`)", "",
        markdown_table(list(result.baseline_rows), row_columns(BaselineRow)), "",
    ]


def security_markdown(result) -> str:
    """The security section of a report.

    Parameters
    ----------
    result : roadcollab.experiments.security.study.AttackStudyResult
        The security study.

    Returns
    -------
    str
        Markdown, ending with a newline.
    """
    return "\n".join(_attack_lines(result) + _tables_lines(result))


def _write_pole_figures(pole_examples, out: Path) -> None:
    """Figs. 8-10 and ``fig8_10_poles.csv`` (poles in rad/s, one row per pole)."""
    for ex in pole_examples:
        plotting.plot_poles(ex, out / _pole_figure(ex))
    write_rows(out / "fig8_10_poles.csv", pole_rows(pole_examples), PoleRow)


def write_attack(result, out, *, command: str, elapsed: float) -> None:
    """Write every output of ``roadcollab attack`` to ``out``.

    Files: ``attack.csv``, ``exactness.csv``, ``linkability.csv``, ``baselines.csv``, ``poisoning.csv``,
    ``dp_composition.csv``, ``frontier.csv``, ``fig11_attack_success.png``, ``fig12_privacy_frontier.png``,
    ``fig8..10_poles_vehicle{1..3}.png`` with ``fig8_10_poles.csv``, ``config.json`` and ``report.md``.

    Parameters
    ----------
    result : roadcollab.experiments.security.study.AttackStudyResult
        The security study.
    out : str or Path
        Output folder (created if missing; files overwritten).
    command : str
        The command line, recorded in ``config.json`` and the report.
    elapsed : float
        Wall-clock time of the study, s.
    """
    out = output_dir(out)
    write_rows(out / "attack.csv", result.attack_rows, AttackRow)
    write_rows(out / "exactness.csv", result.exactness_rows, ExactnessRow)
    write_rows(out / "linkability.csv", result.linkability_rows, LinkabilityRow)
    write_rows(out / "baselines.csv", result.baseline_rows, BaselineRow)
    write_rows(out / "poisoning.csv", result.poisoning_rows, PoisoningSummary)
    write_rows(out / "dp_composition.csv", result.composition_rows, CompositionRow)
    write_rows(out / "frontier.csv", result.frontier, FrontierPoint)
    plotting.plot_attack_success([dataclasses.asdict(r) for r in result.attack_rows], out / "fig11_attack_success.png")
    plotting_security.plot_privacy_frontier(result.frontier, out / "fig12_privacy_frontier.png")
    _write_pole_figures(result.pole_examples, out)
    cfg = result.config.to_dict()
    write_config(out / "config.json", command=command, seed=result.seed, config=cfg,
                 extra={"elapsed_s": elapsed, "secagg_clipped": result.secagg_clipped})
    text = run_header("# roadcollab attack: how much privacy the exchanges give", command, elapsed)
    (out / "report.md").write_text("\n".join(text + [security_markdown(result)]))

