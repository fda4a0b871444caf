"""Outputs of ``roadcollab export``: the files ``roadcollab estimate`` writes, from the service's store.

``final_estimate.csv`` and ``road_estimates.csv`` have the columns of
:mod:`roadcollab.reporting.fleet_report` (vehicle ``k`` = the ``k``-th vehicle id, ``vk`` for the
``k``-th drive of ``roadcollab fleet``);
``iri.csv`` and ``anomalies.csv`` come from the service's fused elevation by the same functions as
``estimate``; ``config.json`` and ``report.md`` describe the store.
"""

from __future__ import annotations

import numpy as np

from pathlib import Path


from ..errors import ParameterError
from ..experiments.drives.estimation import AnomalyRow
from ..experiments.drives.fleet_estimation import FLEET_ESTIMATORS, find_fleet_anomalies, fused_iri
from ..network.results import NetworkResults
from .drive_tables import write_array_csv, write_final_estimate
from .fleet_report import write_iri_csv
from .records import markdown_table, write_config, write_rows

__all__ = ["NETWORK_FILES", "write_network_results"]

NETWORK_FILES = ["road_estimates.csv", "final_estimate.csv", "iri.csv", "anomalies.csv", "config.json", "report.md"]
_SIDES = ("left", "right")


def write_network_results(r: NetworkResults, out, *, command: str, segment_length: float, plan: dict) -> dict:
    """Write every output of ``roadcollab export`` (module docstring); returns the summary.

    Parameters
    ----------
    r : NetworkResults
    out : Path
        Output folder (from ``staged_output``).
    command : str
    segment_length : float
        IRI segment length, m.
    plan : dict
        The fleet plan, for ``config.json``.

    Returns
    -------
    dict
        ``n_vehicles``, ``length_m``, ``notes``, ``files``.
    """
    out = Path(out)
    V = len(r.vehicles)
    # The same writers and schema as ``estimate`` (reporting.fleet_report), so the files compare byte for byte.
    named = [(f"elevation_{name}_v{j + 1}_{side}", r.elevation[name][j][:, c])
             for j in range(V) for name in FLEET_ESTIMATORS for c, side in enumerate(_SIDES)]
    write_array_csv(out / "road_estimates.csv", ["position_m"] + [n for n, _ in named],
                    [r.position] + [series for _, series in named])
    write_final_estimate(out / "final_estimate.csv", r.position, r.fused, r.elevation["collaborative"][-1],
                         r.coverage)
    view = r.fleet_view()
    notes = []
    if V and not np.isfinite(r.elevation["inversion"]).any():
        notes.append("The fleet fuses by secure aggregation: the service holds only each round's sum, so the "
                     "fused elevation and its coverage are known, and every vehicle's own estimate "
                     "(road_estimates.csv, the last vehicle's collaborative columns of final_estimate.csv) is "
                     "blank.")
    iri, iri_note = fused_iri(view, segment_length)
    if iri_note:
        notes.append(iri_note)
    write_iri_csv(out / "iri.csv", iri)
    try:
        anomalies = find_fleet_anomalies(view)
    except ParameterError as err:
        anomalies = []
        notes.append(f"Anomaly detection was not run: {err}.")
    write_rows(out / "anomalies.csv", anomalies, AnomalyRow)
    ok = r.coverage > 0
    length = float(r.position[ok][-1] - r.position[ok][0])
    write_config(out / "config.json", command=command, seed=None,
                 config={"grid": "distance", "plan": plan, "vehicles": [{"id": v, **h} for v, h in r.vehicles]},
                 extra={"notes": notes})
    rows = [{"vehicle": f"v{j + 1}", "id": v, "csv": h.get("csv", ""), "speed_mps": float(h["speed_mps"]),
             "segments": len(h.get("segments", []))} for j, (v, h) in enumerate(r.vehicles)]
    lines = ["# roadcollab export: the road from the roadside service's store", "", f"Command: `{command}`  ",
             f"{V} vehicle(s) over {length:.1f} m of road.", ""]
    lines += ["**Notes.**", ""] + [f"- {n}" for n in notes] + [""] if notes else []
    lines += ["## Vehicles", "", markdown_table(rows, list(rows[0])), "",
              "## Anomalies in the fused elevation (`anomalies.csv`)", "",
              markdown_table(anomalies, ["position_m", "side", "kind", "depth_m", "confidence"])
              if anomalies else "None.", ""]
    (out / "report.md").write_text("\n".join(lines))
    return {"n_vehicles": V, "length_m": length, "notes": notes, "files": list(NETWORK_FILES)}
