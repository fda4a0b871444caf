"""Compare every CSV under two output folders of tools/study_outputs.sh, byte for byte.

Timing columns are skipped (``ms_per_message``, ``note`` of ``baselines.csv``), and so is the
Paillier baseline's ``bytes_per_message``: ciphertext sizes depend on the OS-random key.
Usage: python tools/compare_csv.py BEFORE AFTER   (exit status 1 if anything differs)
"""
import csv
import filecmp
import sys
from pathlib import Path

TIMING = ("ms_per_message", "note")


def _baseline_rows(path):
    """Rows of a baselines.csv without the timing columns and the Paillier ciphertext size."""
    with open(path, newline="") as fh:
        return [{k: v for k, v in r.items() if k not in TIMING and not (r["mechanism"] == "he" and k == "bytes_per_message")}
                for r in csv.DictReader(fh)]


A, B = Path(sys.argv[1]), Path(sys.argv[2])
bad = 0
n = 0
for f in sorted(A.rglob("*.csv")):
    g = B / f.relative_to(A)
    n += 1
    if f.name == "baselines.csv":
        same = g.exists() and _baseline_rows(f) == _baseline_rows(g)
    else:
        same = g.exists() and filecmp.cmp(f, g, shallow=False)
    if not same:
        print("DIFF", f.relative_to(A))
        bad += 1
print(f"compared {n} csv files (baselines.csv without its timing columns); differing: {bad}")
