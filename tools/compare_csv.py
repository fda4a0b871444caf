"""Compare every CSV under two output folders of tools/study_outputs.sh, byte for byte.

Timing columns are skipped (``ms_per_message``, ``note`` of ``baselines.csv``), and so is the
Paillier baseline's ``bytes_per_message``: ciphertext sizes depend on the OS-random key.
Usage: python tools/compare_csv.py BEFORE AFTER   (exit status 1 if anything differs)
"""
import csv, sys, filecmp
from pathlib import Path
A, B = Path(sys.argv[1]), Path(sys.argv[2]); bad = 0; n = 0
for f in sorted(A.rglob("*.csv")):
    g = B / f.relative_to(A); n += 1
    if f.name == "baselines.csv":
        ra = [{k: v for k, v in r.items() if k not in ("ms_per_message", "note") and not (r["mechanism"] == "he" and k == "bytes_per_message")} for r in csv.DictReader(open(f))]
        rb = [{k: v for k, v in r.items() if k not in ("ms_per_message", "note") and not (r["mechanism"] == "he" and k == "bytes_per_message")} for r in csv.DictReader(open(g))]
        same = ra == rb
    else:
        same = g.exists() and filecmp.cmp(f, g, shallow=False)
    if not same: print("DIFF", f.relative_to(A)); bad += 1
print(f"compared {n} csv files (baselines.csv without its timing columns); differing: {bad}")

sys.exit(1 if bad else 0)
