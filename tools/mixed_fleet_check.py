"""Issue 10's check: four simulated drives at 12, 15, 18 and 13-17 m/s over the packaged measured profile.

Usage: ``PYTHONPATH=src python tools/mixed_fleet_check.py [--seeds 0-4]``. Prints the NMSE of the fused
elevation (0.5-15 m wavelengths) per seed against the single vehicles' mean, the same fleet at one
speed (15 m/s), the fused posterior-mean inversions (known fleet prior), and the start-offset errors
with +-3 m GPS errors.
"""

import argparse

import numpy as np

from roadcollab.experiments.drives.mixed_fleet import MIXED_SPEEDS, mixed_fleet_check


def main() -> None:
    """Run the check for every seed and print one line per seed."""
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--seeds", default="0-4", help="one seed N or a range first-last (default 0-4)")
    args = p.parse_args()
    try:
        parts = [int(v) for v in args.seeds.split("-")]
    except ValueError:
        p.error(f"--seeds: expected N or FIRST-LAST, got {args.seeds!r}")
    if len(parts) not in (1, 2):
        p.error(f"--seeds: expected N or FIRST-LAST, got {args.seeds!r}")
    lo, hi = parts[0], parts[-1]
    errors = (2.5, -3.0, 1.2, 3.0)
    print("seed  fused  single_mean  ratio  same_speed_fused  fused_posterior  max|offset error| (m)  done")
    for seed in range(lo, hi + 1):
        r = mixed_fleet_check(MIXED_SPEEDS, seed=seed, posterior=True)
        same = mixed_fleet_check((15.0,) * 4, seed=seed)
        a = mixed_fleet_check(MIXED_SPEEDS, seed=seed, start_errors=errors, align=True)
        done = r.fused <= 0.02 and r.fused <= 0.5 * r.single_mean
        print(f"{seed:4d}  {r.fused:.4f}  {r.single_mean:.4f}  {r.fused / r.single_mean:.3f}  {same.fused:.4f}  "
              f"{r.fused_posterior:.4f}  {np.max(np.abs(a.offset_errors)):.3f}  {'yes' if done else 'NO'}")


if __name__ == "__main__":
    main()
