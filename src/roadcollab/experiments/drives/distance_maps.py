"""Kernels that map a vehicle's signals between its own time base and road distance.

The road is the invariant: its elevation ``h(p)`` along the distance ``p``. A vehicle at speed
``v(t)`` sees the road velocity ``w(t) = dh/dt = v(t) h'(p(t))`` with ``p(t) = p0 + int v dt``.
A vehicle's dynamics are time-invariant in *its own* time, so every inversion runs in time; what
crosses between vehicles and what is fused is the elevation on distance:

.. code-block:: text

    y_j(t) --[invert in time]--> w_j(t) --[integrate]--> h_j(t_k) --[spline at p_j(t_k)]--> h_j(x) on x = x0 + i dx
    h(x) --[spline at p_j(t_k)]--> h(p_j(t_k)) --[difference]--> w_j(t) in vehicle j's time base

Band limits are applied on distance, in wavenumber (cycles/m), with the same Butterworth-shaped
weight as in time (:class:`~roadcollab.estimation.grid.SegmentGrid` with the spacing's inverse as
its "sample rate").
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import make_interp_spline

from ..._validation import check_positive
from ...errors import ParameterError
from ...estimation.grid import SegmentGrid

__all__ = ["distance_grid", "elevation_to_distance", "elevation_at", "band_limit_stretch", "covered",
           "estimate_offset"]


def distance_grid(starts, ends, spacing: float) -> np.ndarray:
    """A uniform distance grid on multiples of ``spacing`` covering every ``[start, end]``.

    Parameters
    ----------
    starts, ends : sequence of float
        First and last road position of every drive, m.
    spacing : float
        Grid step, m.

    Returns
    -------
    (n,) ndarray
        ``spacing * (i0 + arange(n))``, m.
    """
    dx = check_positive("spacing", spacing)
    i0 = int(np.ceil(min(starts) / dx - 1e-9))
    i1 = int(np.floor(max(ends) / dx + 1e-9))
    if i1 - i0 < 16:
        raise ParameterError(f"the drives cover {max(ends) - min(starts):.3g} m: fewer than 16 grid steps of "
                             f"{dx:g} m")
    return dx * np.arange(i0, i1 + 1)


def elevation_to_distance(positions, elevation, grid) -> np.ndarray:
    """A vehicle's elevation at its sample positions, evaluated on a distance grid.

    Cubic interpolating spline through ``(positions[k], elevation[k])`` (positions need not be
    uniform: the speed may vary); NaN outside ``[positions[0], positions[-1]]``.

    Parameters
    ----------
    positions : (N,) array_like
        Strictly increasing road positions of the samples, m.
    elevation : (N, C) array_like
        m.
    grid : (n,) array_like
        Distance grid, m.

    Returns
    -------
    (n, C) ndarray
        m, NaN where the vehicle did not pass.
    """
    p = np.asarray(positions, dtype=float)
    h = np.asarray(elevation, dtype=float)
    x = np.asarray(grid, dtype=float)
    out = np.full((x.shape[0], h.shape[1]), np.nan)
    inside = (x >= p[0]) & (x <= p[-1])
    out[inside] = make_interp_spline(p, h, k=3, axis=0)(x[inside])
    return out


def elevation_at(grid, elevation, positions) -> np.ndarray:
    """Elevation on a distance grid evaluated at a vehicle's sample positions (0 where not covered).

    Parameters
    ----------
    grid : (n,) array_like
        Uniform distance grid, m.
    elevation : (n, C) array_like
        m, NaN where not covered (one contiguous covered stretch).
    positions : (N,) array_like
        Road positions of the vehicle's samples, m.

    Returns
    -------
    (N, C) ndarray
        m; 0 outside the covered stretch.
    """
    x = np.asarray(grid, dtype=float)
    h = np.asarray(elevation, dtype=float)
    p = np.asarray(positions, dtype=float)
    ok = covered(h)
    out = np.zeros((p.shape[0], h.shape[1]))
    if ok.sum() < 4:
        return out
    xs = x[ok]
    inside = (p >= xs[0]) & (p <= xs[-1])
    out[inside] = make_interp_spline(xs, h[ok], k=3, axis=0)(p[inside])
    return out


def covered(elevation) -> np.ndarray:
    """Grid points where an elevation is finite.

    Parameters
    ----------
    elevation : (n, C) array_like
        m, NaN where not covered.

    Returns
    -------
    (n,) bool ndarray
    """
    return np.all(np.isfinite(np.asarray(elevation, dtype=float)), axis=1)


def band_limit_stretch(elevation, spacing: float, low_per_m: float, high_per_m: float | None = None) -> np.ndarray:
    """Zero-phase band weight in wavenumber applied to the covered stretch of an elevation.

    The stretch's mean is removed, then ``W(n) = 1 / (1 + (n_low / n)^8)`` (and the high edge if
    given) is applied on a zero-padded grid; NaN stays NaN.

    Parameters
    ----------
    elevation : (n, C) array_like
        m on a uniform grid, NaN outside one contiguous covered stretch.
    spacing : float
        Grid step, m.
    low_per_m : float
        Low band edge, cycles/m (the longest wavelength kept is about ``1 / low_per_m``).
    high_per_m : float, optional
        High band edge, cycles/m.

    Returns
    -------
    (n, C) ndarray
        m.
    """
    h = np.asarray(elevation, dtype=float)
    ok = covered(h)
    out = np.full_like(h, np.nan)
    if ok.sum() < 16:
        return out
    seg = h[ok] - h[ok].mean(axis=0)
    g = SegmentGrid(seg.shape[0], 1.0 / spacing, band_low_hz=low_per_m, band_high_hz=high_per_m)
    out[ok] = g.band_limited(g.rfft(seg), seg.shape[0])
    return out


def estimate_offset(reference, other, spacing: float, max_offset: float) -> tuple[float, float]:
    """The shift of ``other`` against ``reference`` that best aligns them (cross-correlation).

    Finds the lag ``L`` (within ``+-max_offset``) maximising the normalised correlation
    ``sum h_r(x) h_o(x + L) / sqrt(sum h_r^2 sum h_o^2)`` over the overlap, refined by a parabola
    through the peak. ``other`` is then ``L`` too far along the road: its positions need the
    correction ``-L``.

    Parameters
    ----------
    reference, other : (n, C) array_like
        Band-limited elevations (or slopes) on one uniform grid, NaN where not covered.
    spacing : float
        Grid step, m.
    max_offset : float
        Largest shift searched, m.

    Returns
    -------
    lag : float
        ``L``, m.
    peak : float
        The normalised correlation at the peak (1 = identical shapes).
    """
    a = np.nan_to_num(np.asarray(reference, dtype=float))
    b = np.nan_to_num(np.asarray(other, dtype=float))
    m = int(np.ceil(max_offset / spacing))
    lags = np.arange(-m, m + 1)
    n = a.shape[0]
    corr = np.zeros(lags.size)
    for i, L in enumerate(lags):
        ra = a[max(0, -L):n - max(0, L)]
        rb = b[max(0, L):n - max(0, -L)] if L >= 0 else b[0:n + L]
        both = (ra != 0).any(axis=1) & (rb != 0).any(axis=1)
        den = np.sqrt(np.sum(ra[both] ** 2) * np.sum(rb[both] ** 2))
        corr[i] = np.sum(ra[both] * rb[both]) / den if den > 0 else 0.0
    k = int(np.argmax(corr))
    frac = 0.0
    if 0 < k < lags.size - 1:
        c0, c1, c2 = corr[k - 1], corr[k], corr[k + 1]
        denom = c0 - 2 * c1 + c2
        frac = 0.5 * (c0 - c2) / denom if denom < 0 else 0.0
    return float((lags[k] + frac) * spacing), float(corr[k])
