#!/usr/bin/env bash
# Run every study command small, with fixed seeds, into OUT (for behaviour-preserving refactors:
# run it before and after, then compare with tools/compare_csv.py).
# Usage: tools/study_outputs.sh OUT   (from the repository root, after `make .venv/.installed`)
set -euo pipefail
OUT=$1; B=.venv/bin/roadcollab; PY=.venv/bin/python
rm -rf "$OUT"; mkdir -p "$OUT/drives"
$PY - "$OUT/drives" <<'PYEOF'
import sys
from pathlib import Path
import numpy as np
import roadcollab as rc
from roadcollab.io.drives import write_drive_csv
from roadcollab.io.drive_params import write_drive_params
from roadcollab.models.simulation import add_sensor_noise
d = Path(sys.argv[1])
cfg = rc.ExperimentConfig(n_vehicles=4, n_runs=1)
pipe = rc.FleetPipeline(cfg, rc.sample_fleet(4, cfg.fleet, rng=11))
road_ss, noise_ss = np.random.SeedSequence(3).spawn(2)
road = pipe.road(np.random.default_rng(road_ss))
noise = np.random.default_rng(noise_ss)
for j, est in enumerate(pipe.estimators):
    y = add_sensor_noise(rc.simulate_response(est.true_plant, road.velocity), cfg.sensor_noise_std, rng=noise)
    write_drive_csv(d / f"drive{j + 1}.csv", road.time, y)
    write_drive_params(d / f"drive{j + 1}.toml", speed=cfg.speed, params=est.vehicle.estimated_params,
                       sensor_noise_std=cfg.sensor_noise_std, start_m=float(road.start))
PYEOF
$B estimate $(for j in 1 2 3 4; do echo --drive "$OUT/drives/drive$j.csv"; done) --out "$OUT/estimate" > /dev/null
$B reproduce --runs 6 --measured-runs 3 --out "$OUT/reproduce" > /dev/null 2>&1
$B reproduce --runs 3 --redraw-fleet --measured-runs 0 --vehicles 4 --out "$OUT/redraw" > /dev/null 2>&1
$B attack --runs 3 --out "$OUT/attack" > /dev/null 2>&1
$B anomalies --runs 3 --out "$OUT/anomalies" > /dev/null 2>&1
$B sweep --runs 2 --vehicles 3 --gammas 8,512 --noise 0.05 --uncertainty 0.1 --out "$OUT/sweep" > /dev/null 2>&1
$B calibrate-anomalies --seeds 1000 --runs-per-seed 2 --vehicles 3 --snr-thresholds 4.25 5 --min-depths-mm 12.5 \
    --out "$OUT/calibrate" > /dev/null 2>&1
$B iri --out "$OUT/iri" > /dev/null 2>&1
$B simulate-drives --gps --vehicles 2 --seed 5 --out "$OUT/city" > /dev/null 2>&1
$B map $(for f in "$OUT"/city/drive*.csv; do echo --drive "$f"; done) --network "$OUT/city/network.geojson" \
    --bootstrap 0 --seed 0 --store "$OUT/city/roads.sqlite" --out "$OUT/map" > /dev/null 2>&1
echo "outputs in $OUT"
