"""Cleaning a recorded drive before estimation: isolated logger spikes, then slow offsets.

Both steps act on the accelerations only and leave every other field of the
:class:`~roadcollab.io.drives.Drive` as read. ``roadcollab estimate`` applies :func:`clean_drive` to
every drive; the estimators (:mod:`roadcollab.experiments.drives.estimation`) take drives as given.

Spikes (glitches)
-----------------
A logger glitch is one sample off the curve its neighbours lie on. Per channel, with
``d[k] = x[k] - (x[k - 1] + x[k + 1]) / 2`` (the departure from the straight line through the two
neighbours) and the drive's own robust scale ``s = 1.4826 MAD(d)`` (the standard deviation of
``d`` for Gaussian data; the sensor noise dominates it at vehicle sample rates), sample ``k`` is a
spike when all three hold:

1. ``|d[k]| > SPIKE_THRESHOLD * s`` (12): for Gaussian noise the chance is 4e-33 per sample, so
   noise never triggers it;
2. its neighbours agree with each other and show a spike's footprint:
   ``|x[k + 1] - x[k - 1]| <= |d[k]| / 2`` and ``|d[k +- 1] + d[k] / 2| <= |d[k]| / 4``. A single
   sample off the line moves each neighbour's departure by exactly ``-d[k] / 2`` and leaves the
   neighbours where the signal is; a real short pulse or step (two or more samples off the line,
   e.g. the damper's feed-through of a pothole or bump edge, a staircase at a coarse profile) does
   not;
3. the samples around it are quiet, ``|d[j]| <= QUIET_THRESHOLD * s`` (6) for ``2 <= |j - k| <= 5``:
   a pothole or a bump moves the body over several samples (the tyre envelopes the road over
   0.25 m, about 3 samples at 15 m/s and 200 Hz), so its neighbourhood is not quiet. (With a
   threshold of 12 here, one 12 cm pothole on a 60-minute synthetic drive was taken for a spike: its
   neighbourhood reached 11.6.) A glitch on top of a road event is therefore left alone: the rule
   prefers a missed glitch to a repaired pothole.

A spike is repaired by the mean of its two neighbours (linear interpolation). The first and last
samples are never judged (one neighbour only). Rule 3 needs a road event to span more than one
sample: spikes are not searched when one sample spans more than :data:`MAX_SPIKE_STEP_M` (0.2 m) of
road (at 25 m/s and 100 Hz, 0.25 m, pothole edges were measured to look like single-sample spikes). More than :data:`MAX_SPIKE_FRACTION` of a channel's
samples (1 in 1000) flagged means the log is unreliable rather than glitchy: the drive is refused.

Offsets (gravity, a tilted mount, sensor bias)
----------------------------------------------
Accelerometers cannot see a constant road velocity (DC), so nothing below the estimators' band edge
``band_low_hz`` (0.5 Hz) is estimated (``/work/shared/NOTES.md``); a constant or slowly varying offset
carries no road information but, through the finite window, leaks into every frequency of the
zero-padded transforms. It is removed as the slow trend: a 2nd-order Butterworth low-pass at
``band_low_hz / 10`` (0.05 Hz) applied forward and backward (``scipy.signal.sosfiltfilt``, zero
phase). At the window edges the record is mirrored (even extension) over one period of the corner
(20 s, or the whole record if shorter), so the trend near an edge is a local mean and a constant is
removed exactly up to rounding; an odd extension would pin the trend to the edge sample's own value
(measured: 25 % more error against the truth in the first 2 s of simulated drives; even extension:
no change). The low-pass's power gain at the band edge is ``1 / (1 + 10^4) = 1e-4``, where the
band weight is 0.5, so the road content the estimators keep is practically unchanged (measured on
the in-memory pipeline's drives: RMS error against the truth changed by under 0.3 %).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..errors import FileFormatError
from .drives import Drive

__all__ = ["SPIKE_THRESHOLD", "QUIET_THRESHOLD", "MAX_SPIKE_FRACTION", "MAX_SPIKE_STEP_M", "TREND_FACTOR", "Cleaning", "find_spikes",
           "remove_trend", "clean_drive", "cleaning_note"]

SPIKE_THRESHOLD = 12.0     # robust standard deviations of d (module docstring, rule 1)
QUIET_THRESHOLD = 6.0      # ... that every sample around a spike stays within (rule 3)
MAX_SPIKE_FRACTION = 1e-3  # more spikes than this per channel: the drive is refused
MAX_SPIKE_STEP_M = 0.2     # m of road per sample above which spikes are not searched
TREND_FACTOR = 10.0        # the trend's corner is band_low_hz / TREND_FACTOR
_QUIET = 5                 # rule 3 looks at 2..5 samples either side
_MAD_TO_STD = 1.4826       # 1 / Phi^-1(3/4): MAD to standard deviation for Gaussian data


@dataclass(frozen=True)
class Cleaning:
    """What :func:`clean_drive` did to one drive.

    Attributes
    ----------
    spikes : tuple of (int, int)
        Repaired samples as ``(sample index, channel)`` (0-based; channel 0 left, 1 right).
    spike_values : tuple of float
        Their values before the repair, m/s^2.
    offset_mean : (float, float)
        Mean of the removed trend per channel, m/s^2 (e.g. 9.81 for a log including gravity).
    trend_corner_hz : float
        Corner of the trend low-pass, Hz.
    spikes_searched : bool
        False if one sample spans more than :data:`MAX_SPIKE_STEP_M` of road (or repair was off).
    """

    spikes: tuple
    spike_values: tuple
    offset_mean: tuple
    trend_corner_hz: float
    spikes_searched: bool = True

    @property
    def n_spikes(self) -> int:
        """Number of repaired samples."""
        return len(self.spikes)

    def describe(self, sample_rate: float) -> dict:
        """JSON-ready summary (sample times in s since the drive's first sample).

        Parameters
        ----------
        sample_rate : float
            The drive's sample rate, Hz.

        Returns
        -------
        dict
        """
        return {"spikes_repaired": self.n_spikes,
                "spikes": [{"sample": k, "time_s": k / sample_rate, "side": ("left", "right")[c], "value": v}
                           for (k, c), v in zip(self.spikes, self.spike_values)],
                "offset_mean_mps2": list(self.offset_mean), "trend_corner_hz": self.trend_corner_hz,
                "spikes_searched": self.spikes_searched}


def find_spikes(x, *, threshold: float = SPIKE_THRESHOLD) -> np.ndarray:
    """Indices of isolated single-sample spikes in one channel (module docstring, rules 1-3).

    Parameters
    ----------
    x : (N,) array_like
        One acceleration channel, m/s^2.
    threshold : float
        Rule 1's threshold in robust standard deviations of ``d``.

    Returns
    -------
    (M,) int ndarray
        Sorted sample indices, all in ``[1, N - 2]``.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    if n < 2 * _QUIET + 3:
        return np.zeros(0, dtype=int)
    d = np.zeros(n)
    d[1:-1] = x[1:-1] - 0.5 * (x[:-2] + x[2:])
    inner = d[1:-1]
    s = _MAD_TO_STD * float(np.median(np.abs(inner - np.median(inner))))
    if s == 0.0:    # an exactly piecewise-linear log (no noise at all): the scale of the departures
        s = float(np.mean(np.abs(inner)))
    if s == 0.0:
        return np.zeros(0, dtype=int)
    big = np.abs(d) > threshold * s
    moving = np.abs(d) > QUIET_THRESHOLD * s
    cand = np.flatnonzero(big[1:-1]) + 1
    out = []
    for k in cand:
        dk = d[k]
        if (abs(x[k + 1] - x[k - 1]) > abs(dk) / 2 or abs(d[k - 1] + dk / 2) > abs(dk) / 4
                or abs(d[k + 1] + dk / 2) > abs(dk) / 4):
            continue                                   # rule 2: not a single sample's footprint
        lo, hi = max(1, k - _QUIET), min(n - 1, k + _QUIET + 1)
        around = [j for j in range(lo, hi) if abs(j - k) >= 2]
        if np.any(moving[around]):
            continue                                   # rule 3: the neighbourhood is moving
        out.append(k)
    return np.asarray(out, dtype=int)


def remove_trend(accel, sample_rate: float, corner_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Split accelerations into the slow trend and the rest (module docstring, offsets).

    Parameters
    ----------
    accel : (N, C) array_like
        m/s^2.
    sample_rate : float
        Hz.
    corner_hz : float
        Corner of the zero-phase 2nd-order Butterworth low-pass, Hz (below ``sample_rate / 2``).

    Returns
    -------
    rest : (N, C) ndarray
        ``accel - trend``, m/s^2.
    trend : (N, C) ndarray
        m/s^2.
    """
    import scipy.signal  # heavy (about 1 s); imported when a drive is cleaned

    a = np.asarray(accel, dtype=float)
    sos = scipy.signal.butter(2, corner_hz, btype="low", fs=sample_rate, output="sos")
    pad = min(a.shape[0] - 1, int(np.ceil(sample_rate / corner_hz)))   # one period of the corner (docstring)
    trend = scipy.signal.sosfiltfilt(sos, a, axis=0, padtype="even", padlen=pad)
    return a - trend, trend


def clean_drive(drive: Drive, *, band_low_hz: float = 0.5, repair_spikes: bool = True,
                remove_offset: bool = True) -> tuple[Drive, Cleaning]:
    """Repair isolated spikes, then remove the slow offset of a drive's accelerations.

    Parameters
    ----------
    drive : Drive
    band_low_hz : float
        The estimators' band edge, Hz; the trend's corner is ``band_low_hz / TREND_FACTOR``.
    repair_spikes, remove_offset : bool
        Do either step (both by default).

    Returns
    -------
    Drive
        The same drive with cleaned ``accel`` (m/s^2).
    Cleaning
        What was done.

    Raises
    ------
    FileFormatError
        More than :data:`MAX_SPIKE_FRACTION` of a channel's samples are spikes (message starts with the CSV).
    """
    a = drive.accel.copy()
    spikes, values = [], []
    step_m = float(np.max(drive.speeds())) / drive.sample_rate
    searched = bool(repair_spikes and step_m <= MAX_SPIKE_STEP_M)
    if searched:
        limit = max(1, int(MAX_SPIKE_FRACTION * drive.n_samples))
        for c in range(a.shape[1]):
            ks = find_spikes(a[:, c])
            if ks.size > limit:
                side = ("accel_left", "accel_right")[c]
                raise FileFormatError(f"{drive.csv_path}: {ks.size} isolated spikes in {side} (more than "
                                      f"{limit}, 1 in {1 / MAX_SPIKE_FRACTION:g} samples): the log is unreliable, "
                                      f"not glitchy; first at time {float(drive.time[ks[0]])!r} s")
            values += [float(a[k, c]) for k in ks]
            spikes += [(int(k), c) for k in ks]
            a[ks, c] = 0.5 * (a[ks - 1, c] + a[ks + 1, c])
        order = sorted(range(len(spikes)), key=lambda i: spikes[i])
        spikes, values = [spikes[i] for i in order], [values[i] for i in order]
    corner = band_low_hz / TREND_FACTOR
    mean = (0.0,) * a.shape[1]
    if remove_offset:
        a, trend = remove_trend(a, drive.sample_rate, corner)
        mean = tuple(float(m) for m in trend.mean(axis=0))
    return replace(drive, accel=a), Cleaning(spikes=tuple(spikes), spike_values=tuple(values), offset_mean=mean,
                                             trend_corner_hz=float(corner), spikes_searched=searched)


def cleaning_note(drives: list[Drive], cleanings: list[Cleaning]) -> str:
    """One line for the terminal and the report: spikes repaired per drive and the offsets removed.

    Parameters
    ----------
    drives : list of Drive
    cleanings : list of Cleaning
        One per drive, same order.

    Returns
    -------
    str
    """
    total = sum(c.n_spikes for c in cleanings)
    parts = []
    for d, c in zip(drives, cleanings):
        if not c.spikes_searched:
            parts.append(f"{d.csv_path.name}: not searched ({float(np.max(d.speeds())) / d.sample_rate:.3g} m of "
                         f"road per sample, more than {MAX_SPIKE_STEP_M:g} m)")
        elif c.n_spikes:
            where = ", ".join(f"{('left', 'right')[ch]} at {k / d.sample_rate:.6g} s ({v:.4g} m/s^2)"
                              for (k, ch), v in list(zip(c.spikes, c.spike_values))[:3])
            parts.append(f"{d.csv_path.name}: {c.n_spikes} ({where}{', ...' if c.n_spikes > 3 else ''})")
    offsets = "; ".join(f"{d.csv_path.name} {c.offset_mean[0]:.3g}/{c.offset_mean[1]:.3g}" for d, c in
                        zip(drives, cleanings))
    return (f"{total} isolated spike{'s' if total != 1 else ''} repaired" + (f" ({'; '.join(parts)})" if parts else "")
            + f"; slow offset removed below {cleanings[0].trend_corner_hz:g} Hz (mean left/right m/s^2: {offsets}).")
