"""Compare every CSV under two output folders of tools/study_outputs.sh, byte for byte.

Timing columns are skipped (``ms_per_message``, ``note`` of ``baselines.csv``), and so is the
Paillier baseline's ``bytes_per_message``: ciphertext sizes depend on the OS-random key.
With ``--numeric``, a file that differs is also compared cell by cell: the largest relative
difference of its numeric cells (``|a - b| / max(|a|, |b|)``) and whether its text cells agree.
Usage: python tools/compare_csv.py BEFORE AFTER [--numeric]   (exit status 1 if anything differs)
"""
import csv
import filecmp
import math
import sys
from pathlib import Path

TIMING = ("ms_per_message", "note")


def _baseline_rows(path):
    """Rows of a baselines.csv without the timing columns and the Paillier ciphertext size."""
    with open(path, newline="") as fh:
        return [{k: v for k, v in r.items() if k not in TIMING and not (r["mechanism"] == "he" and k == "bytes_per_message")}
                for r in csv.DictReader(fh)]


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.reader(fh))


def numeric_diff(f, g):
    """Largest relative difference of the numeric cells, and the number of differing text cells."""
    ra, rb = _rows(f), _rows(g)
    if len(ra) != len(rb):
        return math.inf, abs(len(ra) - len(rb))
    worst, text = 0.0, 0
    for x, y in zip(ra, rb):
        for a, b in zip(x, y):
            try:
                fa, fb = float(a), float(b)
            except ValueError:
                text += a != b
                continue
            if fa != fb and not (math.isnan(fa) and math.isnan(fb)):
                worst = max(worst, abs(fa - fb) / max(abs(fa), abs(fb)))
    return worst, text


A, B = Path(sys.argv[1]), Path(sys.argv[2])
numeric = "--numeric" in sys.argv[3:]
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
        bad += 1
        if numeric and g.exists():
            worst, text = numeric_diff(f, g)
            print(f"DIFF {f.relative_to(A)}: largest relative difference {worst:.2e}, differing text cells {text}")
        else:
            print("DIFF", f.relative_to(A))
print(f"compared {n} csv files (baselines.csv without its timing columns); differing: {bad}")

sys.exit(1 if bad else 0)
