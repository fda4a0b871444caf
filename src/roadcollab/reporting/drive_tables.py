"""CSV tables of ``roadcollab estimate`` written straight from arrays (a 60-minute drive has 720,000 rows).

``final_estimate.csv`` has one schema whichever path ran (time grid or distance grid),
:data:`FINAL_COLUMNS`:

* ``position_m``: road distance, m;
* ``elevation_fused_left``, ``elevation_fused_right``: the fused elevation of every drive, m (mean
  removed, band-limited; wavelengths above ``speed / band_low_hz`` are not observed);
* ``coverage``: how many drives passed the point;
* ``elevation_collaborative_left``, ``elevation_collaborative_right``: the last drive's
  collaborative (Algorithm 1) elevation, m.

Cells where no estimate exists (a drive did not pass) are empty.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["FINAL_COLUMNS", "write_array_csv", "write_final_estimate"]

FINAL_COLUMNS = ("position_m", "elevation_fused_left", "elevation_fused_right", "coverage",
                 "elevation_collaborative_left", "elevation_collaborative_right")
_CHUNK = 20_000   # rows formatted per write


def _cell(v: float) -> str:
    """Full precision (``repr``), an empty cell for NaN."""
    return repr(v) if v == v else ""


def write_array_csv(path, columns, series) -> Path:
    """Write columns of floats as CSV at full precision (``repr``), NaN as an empty cell.

    The rows are assembled a chunk at a time, so no copy of the whole table is made.

    Parameters
    ----------
    path : str or Path
        Output file (overwritten).
    columns : sequence of str
        Header, one name per column.
    series : sequence of (n,) array_like
        The columns' values, one array per name.

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    series = [np.asarray(s, dtype=float) for s in series]
    n = series[0].shape[0] if series else 0
    with path.open("w", newline="") as fh:
        fh.write(",".join(columns) + "\r\n")
        for i in range(0, n, _CHUNK):
            rows = np.column_stack([s[i:i + _CHUNK] for s in series]).tolist()
            fh.write("".join(",".join(map(_cell, r)) + "\r\n" for r in rows))
    return path


def write_final_estimate(path, position, fused, collaborative, coverage) -> Path:
    """``final_estimate.csv`` in the schema :data:`FINAL_COLUMNS` (module docstring).

    Parameters
    ----------
    path : str or Path
    position : (n,) array_like
        m.
    fused, collaborative : (n, 2) array_like
        Elevations, m, NaN where none.
    coverage : (n,) array_like
        Drives that passed each point.

    Returns
    -------
    Path
    """
    cov = np.asarray(coverage, dtype=float)
    fused, collaborative = np.asarray(fused), np.asarray(collaborative)
    return write_array_csv(path, FINAL_COLUMNS, [position, fused[:, 0], fused[:, 1], np.where(cov > 0, cov, np.nan),
                                                 collaborative[:, 0], collaborative[:, 1]])
