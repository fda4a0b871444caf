"""Outputs of ``roadcollab attack``: attack, exactness, linkability and baseline tables, Figs. 8-11,
``config.json`` and ``report.md``."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import plotting
from .records import markdown_table, output_dir, run_header, write_config, write_csv

__all__ = ["ATTACK_COLUMNS", "BASELINE_COLUMNS", "security_markdown", "write_attack"]

#: Columns of ``attack.csv``.
ATTACK_COLUMNS = ["mechanism", "attack", "median_rel_pole_error", "success_rate", "n_messages"]
#: Columns of ``baselines.csv``: MSE in (m/s)^2 of vehicles 1..3, cost per message.
BASELINE_COLUMNS = ["mechanism", "mse_vehicle1", "mse_vehicle2", "mse_vehicle3", "ms_per_message",
                    "bytes_per_message", "note"]
_EXACTNESS_COLUMNS = ["mechanism", "max_rel_diff"]
_LINKABILITY_COLUMNS = ["mechanism", "feature", "auc", "top1_accuracy", "chance"]
_POLE_COLUMNS = ["vehicle", "kind", "real", "imag"]
#: Pole sets of each Figs. 8-10 example, in CSV order: the truth and the three attacks on the paper's message.
_POLE_KINDS = ("true", "model_reduction", "pole_intersection", "multiplicity")


def _pole_figure(example: dict) -> str:
    """File name of the pole figure of one example (Figs. 8-10 for vehicles 1-3)."""
    return f"fig{7 + example['vehicle']}_poles_vehicle{example['vehicle']}.png"


def _attack_lines(result) -> list[str]:
    """Threat model, the attack table and the pole figures."""
    cfg = result.config
    lines = [
        "## Security",
        "",
        f"{cfg.n_runs} segments x {cfg.experiment.n_vehicles} vehicles; seed {result.seed}. The target is the "
        "four poles of S_j = -P_hat_j (the vehicle's suspension model). An attack succeeds on a message when "
        "every pole is recovered within 1 % relative error after Hungarian matching. Against the hardened "
        "exchange (z only) each attack works from signals and is *given the true road*. `no_message / "
        "prior_guess` is what the attacker knows without any message (the fleet's nominal poles).",
        "",
        "### Attacks (`attack.csv`)",
        "",
        markdown_table(result.attack_rows, ATTACK_COLUMNS),
        "",
        "![attack success](fig11_attack_success.png)",
        "",
        "### Figs. 8-10: poles of S_1..S_3 and the attackers' estimates (paper's mechanism, run 1)",
        "",
    ]
    for ex in result.pole_examples:
        lines += [f"![Vehicle {ex['vehicle']}]({_pole_figure(ex)})", ""]
    return lines


def _exactness_linkability_baseline_lines(result) -> list[str]:
    """The exactness, linkability and baseline tables."""
    return [
        "### Exactness (`exactness.csv`): largest relative change of any estimate vs. no privacy",
        "",
        markdown_table(result.exactness_rows, _EXACTNESS_COLUMNS),
        "",
        "### Linkability (`linkability.csv`): can messages of one vehicle be linked across segments?",
        "",
        "AUC = probability that two messages of the same vehicle (different segments) are closer in the "
        "feature than two messages of different vehicles (0.5 = no information); top-1 = how often the "
        "nearest message from another segment is the same vehicle's.",
        "",
        markdown_table(result.linkability_rows, _LINKABILITY_COLUMNS),
        "",
        "### Baselines on the same segments (`baselines.csv`)",
        "",
        markdown_table(result.baseline_rows, BASELINE_COLUMNS),
        "",
    ]


def security_markdown(result) -> str:
    """The security section of a report (attacks, exactness, linkability, baselines).

    Parameters
    ----------
    result : roadcollab.experiments.security_study.AttackStudyResult
        The security study.

    Returns
    -------
    str
        Markdown, ending with a newline.
    """
    return "\n".join(_attack_lines(result) + _exactness_linkability_baseline_lines(result))


def _write_pole_figures(pole_examples: list[dict], out: Path) -> None:
    """Figs. 8-10 and ``fig8_10_poles.csv`` (poles in rad/s, one row per pole)."""
    pole_rows = []
    for ex in pole_examples:
        plotting.plot_poles(ex, out / _pole_figure(ex))
        for key in _POLE_KINDS:
            for p in np.asarray(ex[key]):
                pole_rows.append({"vehicle": ex["vehicle"], "kind": key, "real": float(p.real), "imag": float(p.imag)})
    write_csv(out / "fig8_10_poles.csv", pole_rows, _POLE_COLUMNS)


def write_attack(result, out, *, command: str, elapsed: float) -> None:
    """Write every output of ``roadcollab attack`` to ``out``.

    Files: ``attack.csv``, ``exactness.csv``, ``linkability.csv``, ``baselines.csv``,
    ``fig11_attack_success.png``, ``fig8..10_poles_vehicle{1..3}.png`` with ``fig8_10_poles.csv``,
    ``config.json`` and ``report.md``.

    Parameters
    ----------
    result : roadcollab.experiments.security_study.AttackStudyResult
        The security study.
    out : str or Path
        Output folder (created if missing; files overwritten).
    command : str
        The command line, recorded in ``config.json`` and the report.
    elapsed : float
        Wall-clock time of the study, s.
    """
    out = output_dir(out)
    write_csv(out / "attack.csv", result.attack_rows, ATTACK_COLUMNS)
    write_csv(out / "exactness.csv", result.exactness_rows, _EXACTNESS_COLUMNS)
    write_csv(out / "linkability.csv", result.linkability_rows, _LINKABILITY_COLUMNS)
    write_csv(out / "baselines.csv", result.baseline_rows, BASELINE_COLUMNS)
    plotting.plot_attack_success(result.attack_rows, out / "fig11_attack_success.png")
    _write_pole_figures(result.pole_examples, out)
    write_config(out / "config.json", command=command, seed=result.seed, config=result.config.to_dict(),
                 extra={"elapsed_s": elapsed})
    text = run_header("# roadcollab attack: how much privacy the exchanges give", command, elapsed)
    (out / "report.md").write_text("\n".join(text + [security_markdown(result)]))
