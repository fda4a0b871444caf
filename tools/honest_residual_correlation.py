"""Correlation and spread of honest vehicles' residuals against the robust fused centre.

Quoted in docs/security-receivers.md. Run: ``.venv/bin/python tools/honest_residual_correlation.py``
(4 runs of the anomaly study's default 10-vehicle fleet, seed 0).
"""
import numpy as np

from roadcollab.collaboration.robust_fusion import RobustFusion
from roadcollab.experiments.anomalies.config import AnomalyStudyConfig
from roadcollab.experiments.security.fusion_poisoning import _honest_run
from roadcollab.experiments.pipeline import FleetPipeline, fleet_and_run_seeds
from roadcollab.experiments.seeds import SeedPlan

cfg = AnomalyStudyConfig()
exp = cfg.experiment
pipe = FleetPipeline(exp, fleet_and_run_seeds(exp, 0)[0])
for s in SeedPlan(0).runs(4):
    run = _honest_run(pipe, s, cfg.road_spec(), None)
    r = run.z - RobustFusion().combine(run.z)
    out = []
    for k in range(2):
        R = r[:, :, k]
        G = R @ R.T / R.shape[1]
        d = np.sqrt(np.diag(G))
        off = np.abs((G / np.outer(d, d))[~np.eye(len(d), dtype=bool)])
        out.append(f"track {k}: max|rho| {off.max():.2f}, median|rho| {np.median(off):.2f}, "
                   f"pairs above 0.5 {np.mean(off > 0.5):.2f}, rms max/min {d.max() / d.min():.1f}")
    print(" | ".join(out))
