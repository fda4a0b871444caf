"""Estimated against true IRI on the measured road of ``roadcollab reproduce`` (``iri_measured.csv``).

Per run, the Golden Car IRI (:func:`~roadcollab.models.iri.iri_segments`) per segment of the scored
stretch is computed for

- the *raw* true profile: the elevation the vehicles drove over (the measured track, detrended and
  tyre-enveloped, as sampled at the fleet's speed), i.e. the true road velocity integrated;
- the *band-limited* true profile: the band-limited true road velocity integrated. The estimates
  cannot see wavelengths above ``speed / band_low_hz`` (30 m at 15 m/s and 0.5 Hz), while the IRI
  responds to about 1.2-30 m, so this is the fair reference for an estimator;
- every estimator's elevation: its band-limited road-velocity estimate integrated the same way.

Integration (as :func:`~roadcollab.experiments.drives.estimation.integrate_elevation` and the
detector): the road velocity is constant over a sample, so the elevation increment per sample is
``w[k] / fs`` and ``N`` samples give ``N + 1`` elevations spaced ``speed / fs``. The IRI uses
slopes only, so the unknown integration constant does not matter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._validation import check_positive
from ...models.iri import iri_segments
from ..drives.estimation import integrate_elevation
from .rows import IriRow

__all__ = ["IRI_SEGMENT_LENGTH", "RunIri", "run_iri", "elevation_with_end", "iri_rows", "IriRatio", "iri_ratios"]

_TRACK_NAMES = ("left", "right")

#: Segment length of the IRI comparison, m: six segments of the 300 m scored stretch.
IRI_SEGMENT_LENGTH = 50.0


@dataclass(frozen=True, eq=False)
class RunIri:
    """IRI per segment of one run: truth and every estimator, both tracks.

    Attributes
    ----------
    vehicle : int
        1-based vehicle whose estimates are scored (the fleet estimates use vehicles ``1..vehicle``).
    start, end : (s,) ndarray
        Segment bounds, road distance, m.
    truth_raw, truth_band : (s, 2) ndarray
        IRI of the raw and of the band-limited true profile, m/km, columns ``[left, right]``.
    estimates : dict of str to (s, 2) ndarray
        IRI of each estimator's elevation, m/km.
    """

    vehicle: int
    start: np.ndarray
    end: np.ndarray
    truth_raw: np.ndarray
    truth_band: np.ndarray
    estimates: dict


def elevation_with_end(w, sample_rate: float) -> np.ndarray:
    """Elevation at the start of every sample *and* at the end of the last one, m.

    Parameters
    ----------
    w : (N, C) array_like
        Road velocity, m/s, constant over each sample.
    sample_rate : float
        Hz.

    Returns
    -------
    (N + 1, C) ndarray
        ``h[k] = sum_{i<k} w[i] / fs`` up to one constant (:func:`integrate_elevation` of ``w``
        with its last sample repeated), so ``N`` samples cover ``N / fs`` seconds of road.

    Examples
    --------
    >>> h = elevation_with_end(np.ones((4, 1)), 2.0)
    >>> np.diff(h[:, 0]).tolist()
    [0.5, 0.5, 0.5, 0.5]
    """
    w = np.asarray(w, dtype=float)
    return integrate_elevation(np.concatenate([w, w[-1:]], axis=0), sample_rate)


def _segments(distance: np.ndarray, velocity: np.ndarray, sample_rate: float, segment_length: float):
    """IRI per segment (both tracks) of the elevation integrated from ``velocity``."""
    seg = iri_segments(distance, elevation_with_end(velocity, sample_rate), segment_length)
    return seg, np.column_stack([seg.left, seg.right])


def run_iri(distance, truth_raw, truth_band, estimates: dict, *, sample_rate: float, vehicle: int,
            segment_length: float = IRI_SEGMENT_LENGTH) -> RunIri:
    """IRI per segment of the true profile (raw and band-limited) and of every estimate.

    Parameters
    ----------
    distance : (N + 1,) array_like
        Road distance of the scored stretch's elevation samples (its samples and the end of the
        last one), m, uniform.
    truth_raw : (N, 2) array_like
        True road velocity over the scored stretch, m/s.
    truth_band : (N, 2) array_like
        The same band-limited (the scoring band), m/s.
    estimates : dict of str to (N, 2) array_like
        Band-limited road-velocity estimates, m/s.
    sample_rate : float
        Hz.
    vehicle : int
        1-based vehicle of ``estimates`` (recorded in the result).
    segment_length : float
        m; only whole segments of the scored stretch are reported.

    Returns
    -------
    RunIri

    Raises
    ------
    ParameterError
        Stretch shorter than one segment or than the Golden Car's 11 m initialisation.
    """
    segment_length = check_positive("segment_length", segment_length)
    distance = np.asarray(distance, dtype=float)
    seg, raw = _segments(distance, truth_raw, sample_rate, segment_length)
    band = _segments(distance, truth_band, sample_rate, segment_length)[1]
    est = {name: _segments(distance, w, sample_rate, segment_length)[1] for name, w in estimates.items()}
    return RunIri(vehicle=int(vehicle), start=seg.start, end=seg.end, truth_raw=raw, truth_band=band, estimates=est)


def iri_rows(runs: list) -> list[IriRow]:
    """Rows of ``iri_measured.csv``: per run (those with an IRI), track and segment.

    Parameters
    ----------
    runs : list of RunIri or None
        In run order; ``None`` for runs without an IRI comparison (skipped).

    Returns
    -------
    list of IriRow
        Run-major, then track (left, right), then segment.
    """
    rows = []
    for i, r in enumerate(runs):
        if r is None:
            continue
        for c, track in enumerate(_TRACK_NAMES):
            for s in range(r.start.size):
                rows.append(IriRow(i, r.vehicle, track, float(r.start[s]), float(r.end[s]), float(r.truth_raw[s, c]),
                                   float(r.truth_band[s, c]),
                                   **{f"{name}_iri": float(v[s, c]) for name, v in r.estimates.items()}))
    return rows


@dataclass(frozen=True)
class IriRatio:
    """Estimated over true IRI of one estimator, averaged over runs and segments.

    Attributes
    ----------
    estimator : str
    track : str
        ``"left"`` (measured), ``"right"`` or ``"both"``.
    ratio_raw, ratio_raw_std : float
        Mean and standard deviation of ``estimated / true`` per segment, raw true profile.
    ratio_band, ratio_band_std : float
        The same against the band-limited true profile.
    segments : int
        Segments averaged (runs x segments, x 2 for ``"both"``).
    """

    estimator: str
    track: str
    ratio_raw: float
    ratio_raw_std: float
    ratio_band: float
    ratio_band_std: float
    segments: int


def iri_ratios(rows: list[IriRow], estimators) -> list[IriRatio]:
    """Mean ratio estimated / true IRI per estimator and track (left, right, both).

    Parameters
    ----------
    rows : list of IriRow
        :func:`iri_rows`.
    estimators : sequence of str
        Estimator names (``IriRow`` has ``<name>_iri``), in the order wanted.

    Returns
    -------
    list of IriRatio
        Estimator-major; empty without rows.

    Examples
    --------
    >>> iri_ratios([], ["fused"])
    []
    """
    out: list[IriRatio] = []
    if not rows:
        return out
    for name in estimators:
        for track in (*_TRACK_NAMES, "both"):
            sel = [r for r in rows if track in ("both", r.track)]
            est = np.array([getattr(r, f"{name}_iri") for r in sel])
            raw = est / np.array([r.true_iri_raw for r in sel])
            band = est / np.array([r.true_iri_band_limited for r in sel])
            out.append(IriRatio(name, track, float(raw.mean()), float(raw.std()), float(band.mean()),
                                float(band.std()), len(sel)))
    return out
