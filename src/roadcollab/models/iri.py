"""The International Roughness Index (IRI): the Golden Car quarter-car run over a longitudinal profile.

The IRI of a wheel track is the accumulated suspension stroke of a reference quarter-car (the
"Golden Car") driven over the profile at 80 km/h, divided by the distance travelled (Sayers,
Gillespie and Queiroz 1986; ASTM E1926). Computation follows Sayers (1995): the profile is
smoothed by a 250 mm moving average, its slope drives the quarter-car through the exact
state transition of one sample step, and the IRI is the mean of the rectified slope
``|Z1' - Z3'|`` in m/m, reported in m/km (= mm/m).

References
----------
.. [1] M. W. Sayers, T. D. Gillespie and C. A. V. Queiroz, "The International Road Roughness
   Experiment", World Bank Technical Paper 45, and "Guidelines for Conducting and Calibrating
   Road Roughness Measurements", World Bank Technical Paper 46, 1986.
.. [2] M. W. Sayers, "On the calculation of International Roughness Index from longitudinal road
   profile", Transportation Research Record 1501, pp. 1-12, 1995.
.. [3] ASTM E1926, "Standard Practice for Computing International Roughness Index of Roads from
   Longitudinal Profile Measurements".
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validation import check_matrix, check_nonnegative, check_positive
from ..errors import ParameterError
from ..lti.discretisation import zoh_discretize
from ..lti.modal import modal_states

__all__ = ["GoldenCar", "GOLDEN_CAR", "golden_car_response", "rectified_slope", "iri", "IRIRow", "IRISegments",
           "iri_segments"]


@dataclass(frozen=True)
class GoldenCar:
    """The IRI reference quarter-car, its simulated speed and the standard's profile processing.

    Stiffness and damping are per unit sprung mass, as in the standard ([1]_, [3]_).

    Parameters
    ----------
    tyre_stiffness : float
        ``k1 = kt / ms``, 1/s^2 (653).
    suspension_stiffness : float
        ``k2 = ks / ms``, 1/s^2 (63.3).
    suspension_damping : float
        ``c = cs / ms``, 1/s (6.0).
    mass_ratio : float
        ``mu = mu / ms``, unsprung over sprung mass (0.15).
    speed : float
        Simulated speed, m/s (80 km/h).
    smoothing_length : float
        Base length ``B`` of the moving average of the profile, m (0.25); 0 uses the slope of
        each sample step only.
    initial_length : float
        Length ``L0`` of profile whose mean slope initialises the car, m (11 m, E1926:
        ``Z1' = Z3' = (Y(L0) - Y(0)) / L0``, ``Z2' = Z4' = 0``).

    References
    ----------
    .. [1] Sayers, Gillespie and Queiroz, World Bank Technical Paper 46, 1986.
    .. [3] ASTM E1926.
    """

    tyre_stiffness: float = 653.0
    suspension_stiffness: float = 63.3
    suspension_damping: float = 6.0
    mass_ratio: float = 0.15
    speed: float = 80.0 / 3.6
    smoothing_length: float = 0.25
    initial_length: float = 11.0

    def __post_init__(self):
        for name in ("tyre_stiffness", "suspension_stiffness", "suspension_damping", "mass_ratio", "speed",
                     "initial_length"):
            object.__setattr__(self, name, check_positive(name, getattr(self, name)))
        object.__setattr__(self, "smoothing_length", check_nonnegative("smoothing_length", self.smoothing_length))

    def state_space(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous model driven by the profile slope, states in slope units (m/m).

        With ``z = [zs, zs', zu, zu']`` (sprung and unsprung heights and their time
        derivatives) and profile ``y``, the quarter-car is ``zs'' = -k2 (zs - zu) - c (zs' - zu')``,
        ``mu zu'' = k2 (zs - zu) + c (zs' - zu') - k1 (zu - y)``. Its time derivative divided by
        the speed ``v`` has the state ``Z' = z' / v`` and the input ``y' / v`` = profile slope:

        .. math:: \\dot Z' = A Z' + B \\, \\mathrm{d}y/\\mathrm{d}x

        Returns
        -------
        A : (4, 4) ndarray
            1/s.
        B : (4, 1) ndarray
            1/s.
        """
        k1, k2, c, mu = self.tyre_stiffness, self.suspension_stiffness, self.suspension_damping, self.mass_ratio
        A = np.array([[0.0, 1.0, 0.0, 0.0],
                      [-k2, -c, k2, c],
                      [0.0, 0.0, 0.0, 1.0],
                      [k2 / mu, c / mu, -(k1 + k2) / mu, -c / mu]])
        B = np.array([[0.0], [0.0], [0.0], [k1 / mu]])
        return A, B


#: The standard's Golden Car at 80 km/h with the 250 mm moving average.
GOLDEN_CAR = GoldenCar()


def golden_car_response(wavenumber, *, car: GoldenCar = GOLDEN_CAR, smoothing: bool = True) -> np.ndarray:
    """Closed-form frequency response from profile slope to rectified slope (suspension rate / speed).

    Eliminating ``zs`` and ``zu`` from the quarter-car of :meth:`GoldenCar.state_space` gives,
    with ``s = j 2 pi kappa v``,

    .. math:: H(s) = \\frac{-k_1 s^2}{\\mu s^4 + (1 + \\mu) c s^3 + (k_1 + (1 + \\mu) k_2) s^2
              + k_1 c s + k_1 k_2} \\cdot \\operatorname{sinc}(B \\kappa)

    where the last factor is the moving average of base ``B`` (``sinc(x) = sin(pi x) / (pi x)``).
    ``H(0) = 0``: a constant slope gives no suspension motion.

    Parameters
    ----------
    wavenumber : array_like
        Spatial frequency ``kappa = 1 / wavelength``, cycles/m, any shape.
    car : GoldenCar
        Car, speed and moving-average base.
    smoothing : bool
        Include the moving average's ``sinc``.

    Returns
    -------
    numpy.ndarray
        Complex, same shape as ``wavenumber``, dimensionless (m/m per m/m).

    Examples
    --------
    >>> round(float(abs(golden_car_response(1 / 2.5))), 3)   # near the wheel-hop peak
    1.61
    """
    kappa = check_matrix("wavenumber", wavenumber)
    k1, k2, c, mu = car.tyre_stiffness, car.suspension_stiffness, car.suspension_damping, car.mass_ratio
    s = 2j * math.pi * kappa * car.speed
    h = -k1 * s**2 / (mu * s**4 + (1 + mu) * c * s**3 + (k1 + (1 + mu) * k2) * s**2 + k1 * c * s + k1 * k2)
    if smoothing:
        h = h * np.sinc(car.smoothing_length * kappa)
    return h


def _profile_check(elevation, spacing, car: GoldenCar) -> tuple[np.ndarray, float]:
    """The (n,) or (n, tracks) elevation and the spacing, with the profile long enough for the IRI."""
    spacing = check_positive("spacing", spacing)
    z = check_matrix("elevation", elevation)
    if z.ndim not in (1, 2) or z.shape[0] < 2:
        raise ParameterError(f"elevation must have shape (n,) or (n, tracks) with n >= 2, got {z.shape}")
    base = max(car.smoothing_length, spacing)
    minimum = max(car.initial_length, base + spacing)
    length = (z.shape[0] - 1) * spacing
    if length < minimum - 1e-9 * spacing:
        raise ParameterError(f"elevation: profile length {length:g} m ({z.shape[0]} samples at {spacing:g} m) is "
                             f"shorter than the minimum {minimum:g} m (initialisation over {car.initial_length:g} m, "
                             f"moving average {car.smoothing_length:g} m)")
    return z, spacing


def _modal_run(Phi: np.ndarray, gamma: np.ndarray, state0: np.ndarray, drive: np.ndarray) -> np.ndarray:
    """``Z1' - Z3'`` after each step of ``Z'[i+1] = Phi Z'[i] + gamma s[i]`` from ``Z'[0] = state0``, (m,).

    In the eigenbasis of ``Phi`` (four distinct eigenvalues, well conditioned for the Golden Car
    at any step) each mode is a first-order recursion (:func:`~roadcollab.lti.modal.modal_states`).
    The per-sample Python loop it replaces took 5-6 ms per track of 6000 steps (4.5 s of the default
    reproduction's 40 s, measured); this takes about 0.2 ms and agrees with it to round-off
    (tests/test_iri.py).
    """
    lam, V = np.linalg.eig(Phi)
    g = np.linalg.solve(V, gamma.astype(complex))
    q0 = np.linalg.solve(V, state0.astype(complex))
    q = modal_states(lam, drive[:, None] * g[None, :], q0)[1:]
    return (q @ (V[0] - V[2])).real            # Z1' - Z3' in modal coordinates


def rectified_slope(elevation, spacing, *, car: GoldenCar = GOLDEN_CAR) -> tuple[np.ndarray, np.ndarray]:
    """Signed suspension rate over speed ``Z1' - Z3'`` (m/m) of the Golden Car along one profile.

    The smoothed slope of step ``i`` is ``(y(x_i + b) - y(x_i)) / b`` with ``b = max(B, dx)``
    and ``y`` linearly interpolated: the 250 mm moving average of the slope at ``x_i + b / 2``,
    which is E1926's ``(Y[i+k] - Y[i]) / (k dx)`` whenever ``B / dx`` is an integer ``k`` or
    ``dx >= B``. It is held over one step ``dt = dx / v`` of the exact transition
    ``Z'[i+1] = e^{A dt} Z'[i] + A^{-1} (e^{A dt} - I) B s[i]`` ([2]_).

    Parameters
    ----------
    elevation : array_like
        Shape (n,), profile heights on a uniform grid, m.
    spacing : float
        Grid step ``dx``, m.
    car : GoldenCar
        Car, speed, moving average and initialisation.

    Returns
    -------
    positions : (m,) ndarray
        Road position of each output relative to the first sample, m: ``x_i + b / 2 + dx / 2``
        (the end of the step, ``x_{i+1}``, when ``dx >= B``).
    rate : (m,) ndarray
        ``Z1' - Z3'`` at the end of each step, m/m; ``1000 * mean(|rate|)`` is the IRI in m/km.

    Raises
    ------
    ParameterError
        ``elevation`` not 1-D or non-finite; profile shorter than ``car.initial_length`` or one
        moving-average base (the message gives its length and the minimum).

    References
    ----------
    .. [2] Sayers, TRR 1501, 1995.
    """
    z, dx = _profile_check(elevation, spacing, car)
    if z.ndim != 1:
        raise ParameterError(f"elevation must have shape (n,) for one track, got {z.shape}")
    x = dx * np.arange(z.shape[0])
    base = max(car.smoothing_length, dx)
    m = int(math.floor((x[-1] - base) / dx + 1e-9)) + 1
    slope = (np.interp(x[:m] + base, x, z) - z[:m]) / base
    start = (float(np.interp(car.initial_length, x, z)) - z[0]) / car.initial_length
    A, B = car.state_space()
    Phi, Gamma, _, _ = zoh_discretize(A, B, np.zeros((1, 4)), np.zeros((1, 1)), dx / car.speed)
    rate = _modal_run(Phi, Gamma[:, 0], np.array([start, 0.0, start, 0.0]), slope)
    return x[:m] + 0.5 * base + 0.5 * dx, rate


def iri(elevation, spacing, *, car: GoldenCar = GOLDEN_CAR) -> float:
    """International Roughness Index of one wheel track over its whole length.

    .. math:: \\mathrm{IRI} = \\frac{1000}{m} \\sum_{i=1}^{m} |Z_1'[i] - Z_3'[i]|

    Parameters
    ----------
    elevation : array_like
        Shape (n,), profile heights on a uniform grid, m.
    spacing : float
        Grid step, m.
    car : GoldenCar
        Car, speed, moving average and initialisation.

    Returns
    -------
    float
        IRI, m/km (= mm/m).

    Raises
    ------
    ParameterError
        See :func:`rectified_slope`.

    Examples
    --------
    >>> iri(np.zeros(100), 0.25)
    0.0
    """
    _, rate = rectified_slope(elevation, spacing, car=car)
    return float(1000.0 * np.mean(np.abs(rate)))


@dataclass(frozen=True)
class IRIRow:
    """One segment of ``iri.csv`` (the fields are its columns, in order).

    Attributes
    ----------
    start_m : float
        Segment start, m (road distance as given).
    end_m : float
        Segment end, m.
    iri_left_m_per_km : float
        IRI of the left track, m/km.
    iri_right_m_per_km : float
        IRI of the right track, m/km (the left track's for a one-track profile).
    iri_m_per_km : float
        Mean IRI of the two tracks, m/km.
    """

    start_m: float
    end_m: float
    iri_left_m_per_km: float
    iri_right_m_per_km: float
    iri_m_per_km: float


@dataclass(frozen=True, eq=False)
class IRISegments:
    """IRI per road segment of both wheel tracks.

    Parameters
    ----------
    start : (s,) ndarray
        Segment starts, m (road distance as given).
    end : (s,) ndarray
        Segment ends, m.
    left : (s,) ndarray
        IRI of the left track, m/km.
    right : (s,) ndarray
        IRI of the right track, m/km (equal to ``left`` for a one-track profile).
    tracks : int
        Number of measured tracks, 1 or 2.
    """

    start: np.ndarray
    end: np.ndarray
    left: np.ndarray
    right: np.ndarray
    tracks: int

    @property
    def mean(self) -> np.ndarray:
        """(s,) ndarray: mean IRI of the two tracks, m/km."""
        return 0.5 * (self.left + self.right)

    def to_rows(self) -> list[IRIRow]:
        """One row per segment for ``iri.csv``.

        Returns
        -------
        list of IRIRow
            ``(s,)`` rows, in segment order.
        """
        return [IRIRow(float(a), float(b), float(lt), float(rt), float(mn))
                for a, b, lt, rt, mn in zip(self.start, self.end, self.left, self.right, self.mean)]


def _uniform_distance(distance, n: int) -> tuple[np.ndarray, float]:
    """The (n,) distance and its step; ParameterError unless increasing and uniform."""
    d = check_matrix("distance", distance, (n,))
    if n < 2:
        raise ParameterError(f"distance must have at least 2 samples, got {n}")
    steps = np.diff(d)
    dx = float(np.median(steps))
    bad = np.flatnonzero(~(np.abs(steps - dx) <= 1e-6 * dx + 1e-12 * np.abs(d[1:])))
    if dx <= 0 or bad.size:
        i = int(bad[0]) if bad.size else 0
        raise ParameterError(f"distance must be increasing and uniform (step {dx:g} m), got step {steps[i]:g} m "
                             f"at sample {i + 1}")
    return d, dx


def iri_segments(distance, elevation, segment_length: float = 100.0, *, car: GoldenCar = GOLDEN_CAR
                 ) -> IRISegments:
    """IRI per segment of ``segment_length`` from the profile's first distance, per track.

    The car runs once along the whole profile (its state carries over segment boundaries); a
    segment ``(start, end]`` averages the outputs of :func:`rectified_slope` positioned in it.
    Only whole segments are reported.

    Parameters
    ----------
    distance : array_like
        Shape (n,), increasing, uniform road distance, m.
    elevation : array_like
        Shape (n,) for one track or (n, 2) for ``[left, right]``, m.
    segment_length : float
        Segment length, m (100 m is the usual reporting interval).
    car : GoldenCar
        Car, speed, moving average and initialisation.

    Returns
    -------
    IRISegments

    Raises
    ------
    ParameterError
        Bad shapes, non-uniform distance, a profile shorter than the initialisation or than one
        segment (the message gives its length and the minimum).
    """
    z = check_matrix("elevation", elevation)
    if z.ndim == 1:
        z = z[:, None]
    if z.ndim != 2 or z.shape[1] not in (1, 2):
        raise ParameterError(f"elevation must have shape (n,) or (n, 2), got {z.shape}")
    d, dx = _uniform_distance(distance, z.shape[0])
    segment_length = check_positive("segment_length", segment_length)
    _profile_check(z, dx, car)
    length = d[-1] - d[0]
    count = int(math.floor(length / segment_length + 1e-9))
    if count < 1:
        raise ParameterError(f"elevation: profile length {length:g} m is shorter than the minimum "
                             f"segment_length = {segment_length:g} m")
    start = d[0] + segment_length * np.arange(count)
    per_track = []
    for track in z.T:
        pos, rate = rectified_slope(track, dx, car=car)
        # Segment j holds the outputs with j L < pos <= (j + 1) L (up to float rounding).
        index = np.ceil(pos / segment_length - 1e-9).astype(int) - 1
        index = np.maximum(index, 0)
        keep = index < count
        sums = np.bincount(index[keep], weights=np.abs(rate[keep]), minlength=count)
        counts = np.bincount(index[keep], minlength=count)
        per_track.append(1000.0 * sums / np.maximum(counts, 1))
    right = per_track[-1]
    return IRISegments(start, start + segment_length, per_track[0], right, z.shape[1])
