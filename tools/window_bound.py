"""The linear MMSE of the scored window against the per-bin oracle and its two variants (docs/findings.md).

    .venv/bin/python tools/window_bound.py --vehicles 3 --runs 30 [--segment-length 300 --margin 15]

Builds :class:`roadcollab.estimation.window_mmse.WindowedMMSE` for the fleet of root seed 0 (true plants, the
road's lag moment from 64 design draws), prints per vehicle ``j`` the bound, the closed-form expected MSE of
``oracle_per_bin``, of the same estimate zeroed outside the window and of the per-bin oracle re-applied to the
records extended by the plants' free response after the window (``--closed-form``), and over ``--runs`` runs of
the road model: the mean MSE of each and the paired z of (estimator - windowed LMMSE).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import roadcollab as rc  # noqa: E402
from roadcollab.collaboration.fusion import DESIGN_SEED  # noqa: E402
from roadcollab.estimation.window_mmse import WindowedMMSE, window_lag_moment  # noqa: E402
from roadcollab.experiments.pipeline import fleet_and_run_seeds, FleetPipeline, record_run  # noqa: E402
from roadcollab.experiments.seeds import as_seed_sequence, run_stream  # noqa: E402
from window_variants import per_bin_variants  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=3)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--segment-length", type=float, default=300.0)
    ap.add_argument("--margin", type=float, default=15.0)
    ap.add_argument("--sample-rate", type=float, default=200.0)
    ap.add_argument("--closed-form", action="store_true")
    a = ap.parse_args()
    cfg = rc.ExperimentConfig(n_vehicles=a.vehicles, n_runs=a.runs, segment_length=a.segment_length,
                              margin=a.margin, sample_rate=a.sample_rate)
    fleet, seeds = fleet_and_run_seeds(cfg, 0)
    pipe = FleetPipeline(cfg, fleet)
    g, sl, N, V = pipe.grid, cfg.scored, cfg.n_samples, cfg.n_vehicles
    t0 = time.perf_counter()
    r = window_lag_moment(lambda rng: pipe.road(rng).velocity[:N], N, rng=DESIGN_SEED)
    plants = [e.true_plant for e in pipe.estimators]
    wm = WindowedMMSE(g, sl, r, plants, [cfg.sensor_noise_std] * V)
    print(f"N={N} m={wm.m} 2N={2 * N}: built in {time.perf_counter() - t0:.0f} s", flush=True)
    var = [per_bin_variants(pipe.oracle_per_bin, g, sl, plants, j) for j in range(1, V + 1)]
    if a.closed_form:
        for j in range(1, V + 1):
            t1 = time.perf_counter()
            e = {k: wm.expected_error(f, j) for k, f in var[j - 1].items()}
            print(f"closed form j={j}: bound {wm.bounds[j - 1]:.4e}; " + ", ".join(
                f"{k} {v:.4e} (+{100 * (v / wm.bounds[j - 1] - 1):.2f} %)" for k, v in e.items())
                + f" [{time.perf_counter() - t1:.0f} s]", flush=True)
    names = ["windowed_mmse", *var[0]]
    mse = {k: np.zeros((a.runs, V)) for k in names}
    for ri, s in enumerate(seeds):
        ss = as_seed_sequence(s)
        road_ss, noise_ss = (run_stream(ss, name) for name in ("road", "noise"))
        road, ys, _ = record_run(pipe, road_ss, noise_ss, cfg.sensor_noise_std)
        truth = wm.target(road.velocity[:N])
        recs = [y[:, :, None] for y in ys]
        for j in range(1, V + 1):
            mse["windowed_mmse"][ri, j - 1] = np.mean((wm.estimate(ys[:j]) - truth) ** 2)
            for k, f in var[j - 1].items():
                mse[k][ri, j - 1] = np.mean((f(recs[:j])[:, :, 0] - truth) ** 2)
    print(f"{a.runs} runs; bound and mean MSE per vehicle, (m/s)^2; z of the paired excess over windowed_mmse")
    for j in range(V):
        ref = mse["windowed_mmse"][:, j]
        cells = [f"bound {wm.bounds[j]:.4e}", f"windowed_mmse {ref.mean():.4e}"]
        for k in names[1:]:
            d = mse[k][:, j] - ref
            z = d.mean() / (d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
            cells.append(f"{k} {mse[k][:, j].mean():.4e} (+{100 * d.mean() / ref.mean():.2f} %, z {z:.1f}, "
                         f"worse in {int(np.sum(d > 0))}/{len(d)})")
        print(f"vehicle {j + 1}: " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
