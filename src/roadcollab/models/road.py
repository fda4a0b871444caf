"""Synthetic roads: ISO 8608 roughness and the jump-diffusion (JDP) pothole model.

A road has two wheel tracks (columns ``[left, right]``). The synthetic roughness uses ISO 8608
with waviness 2, so each track's elevation is a random walk in distance: the slope is white
with one-sided spatial PSD ``4 pi^2 n0^2 Gd(n0)`` and an increment over ``ds`` has variance
``2 pi^2 n0^2 Gd(n0) ds``. Seen by a vehicle at speed ``V`` the road velocity is white in time,
one-sided PSD ``4 pi^2 n0^2 Gd(n0) V`` ((m/s)^2/Hz), i.e. a Wiener process of intensity
``2 pi^2 n0^2 Gd(n0) V`` (m^2/s). Pothole edges are the jumps of the jump-diffusion (JDP) model.

:func:`generate_road` draws a whole road from a :class:`RoadSpec`; :func:`with_anomalies` adds
anomalies drawn from a spec to an existing (measured) profile. Both live here, next to the
spec and the anomaly drawing they share. Anomaly records are in :mod:`.anomaly`, profile
containers in :mod:`.profile`, measured profiles in :mod:`roadcollab.io.profiles`.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from .._validation import check_matrix, check_nonnegative, check_positive, check_probability, check_psd
from ..errors import ParameterError
from .anomaly import ANOMALY_SIDES, Anomaly
from .profile import RoadProfile

__all__ = [
    "ISO_8608_GD0", "ISO_8608_N0", "MAX_SAMPLES", "iso_gd0", "road_velocity_psd", "wiener_intensity",
    "RoadSpec", "JumpStatistics", "jump_statistics", "random_walk", "moving_average",
    "generate_road", "with_anomalies",
]

#: Geometric-mean displacement PSD Gd(n0) (m^3) of the ISO 8608 classes at n0 = 0.1 cycle/m.
ISO_8608_GD0 = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6, "E": 4096e-6,
                "F": 16384e-6, "G": 65536e-6, "H": 262144e-6}
#: Reference spatial frequency of ISO 8608 (cycle/m).
ISO_8608_N0 = 0.1
MAX_SAMPLES = 50_000_000   # per track; a clear error beats a MemoryError deep in numpy


def iso_gd0(name: str, value) -> float:
    """Resolve an ISO class letter (or a ``RoadSpec``, or a float Gd(n0) in m^3) to Gd(n0).

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    value : str, RoadSpec or float
        Class letter ``"A"``..``"H"`` (case and surrounding spaces ignored), a spec (its
        ``iso_class``), or Gd(n0) itself in m^3 (> 0).

    Returns
    -------
    float
        Gd(n0), m^3.
    """
    if isinstance(value, RoadSpec):
        return ISO_8608_GD0[value.iso_class]
    if isinstance(value, str):
        key = value.strip().upper()
        if key not in ISO_8608_GD0:
            raise ParameterError(f"{name} must be an ISO 8608 class in A..H, got {value!r}")
        return ISO_8608_GD0[key]
    return check_positive(name, value)


def _increment_variance(gd0: float, ds: float) -> float:
    """Variance (m^2) of the random-walk elevation increment over a step ``ds`` (m)."""
    return 2.0 * math.pi**2 * ISO_8608_N0**2 * gd0 * ds


def road_velocity_psd(iso_class_or_gd0, speed) -> float:
    """One-sided time PSD of the road velocity dz/dt, ``4 pi^2 n0^2 Gd(n0) V``.

    Parameters
    ----------
    iso_class_or_gd0 : str or float
        ISO 8608 class letter ``"A"``..``"H"`` or Gd(n0) in m^3.
    speed : float
        Vehicle speed V in m/s, > 0.

    Returns
    -------
    float
        PSD in (m/s)^2/Hz, flat in frequency (waviness 2).
    """
    gd0 = iso_gd0("iso_class_or_gd0", iso_class_or_gd0)
    return 4.0 * math.pi**2 * ISO_8608_N0**2 * gd0 * check_positive("speed", speed)


def wiener_intensity(spec_or_class, speed) -> np.ndarray:
    """Two-sided intensity (m^2/s) of the white road velocity of both tracks, shape (2, 2).

    Half the one-sided PSD of :func:`road_velocity_psd` times the identity (the two tracks'
    random walks are independent).

    Parameters
    ----------
    spec_or_class : RoadSpec, str or float
        A spec, an ISO 8608 class letter or Gd(n0) in m^3.
    speed : float
        Vehicle speed, m/s, > 0.

    Returns
    -------
    numpy.ndarray
        Shape (2, 2), m^2/s.
    """
    return 0.5 * road_velocity_psd(iso_gd0("spec_or_class", spec_or_class), speed) * np.eye(2)


def _check_range(name: str, value) -> tuple[float, float]:
    """A (low, high) tuple with 0 < low <= high."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise ParameterError(f"{name} must be a (low, high) pair, got {value!r}")
    low, high = check_positive(f"{name}[0]", value[0]), check_positive(f"{name}[1]", value[1])
    if low > high:
        raise ParameterError(f"{name} must have low <= high, got ({low:g}, {high:g})")
    return low, high


@dataclass(frozen=True)
class RoadSpec:
    """Parameters of a synthetic two-track road (see :func:`generate_road`).

    Parameters
    ----------
    length : float
        Total generated length, m.
    spacing : float
        Spatial grid step, m (at most ``length / 2`` and ``length / MAX_SAMPLES`` or more).
    iso_class : str
        ISO 8608 class ``"A"``..``"H"`` of both tracks (independent random walks).
    anomaly_density : float
        Anomalies per metre (Poisson) in ``[margin, length - margin]``.
    anomaly_margin : float
        Anomaly-free stretch at both ends, m.
    pothole_fraction : float
        Probability that an anomaly is a pothole (else a bump).
    depth_range, pothole_length_range, bump_length_range : (float, float)
        Uniform ranges of depth / height and of the lengths, m, ``0 < low <= high``.
    side_probabilities : (float, float, float)
        Probabilities of left, right and both tracks; sum to 1.
    min_anomaly_gap : float
        Clear distance between anomalies sharing a track, m.
    enveloping_length : float
        Tyre enveloping moving-average width, m (0 disables).
    """

    length: float = 330.0            # m, total generated length
    spacing: float = 0.05            # m, spatial grid step
    iso_class: str = "C"             # ISO 8608 class A..H (both tracks, independent random walks)
    anomaly_density: float = 0.02    # anomalies per metre (Poisson) in [margin, length - margin]
    anomaly_margin: float = 15.0     # m, anomaly-free stretch at both ends
    pothole_fraction: float = 0.5    # probability that an anomaly is a pothole (else a bump)
    depth_range: tuple[float, float] = (0.025, 0.10)          # m, uniform depth / height
    pothole_length_range: tuple[float, float] = (0.1, 1.0)    # m, uniform
    bump_length_range: tuple[float, float] = (0.5, 3.0)       # m, uniform
    side_probabilities: tuple[float, float, float] = (0.4, 0.4, 0.2)  # left, right, both
    min_anomaly_gap: float = 3.0     # m, clear distance between anomalies sharing a track
    enveloping_length: float = 0.25  # m, tyre enveloping moving-average width (0 disables)

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        put("length", check_positive("length", self.length))
        put("spacing", check_positive("spacing", self.spacing))
        if self.spacing > 0.5 * self.length:
            raise ParameterError(f"spacing must be <= length / 2 = {0.5 * self.length:g}, got {self.spacing:g}")
        if self.length / self.spacing > MAX_SAMPLES:
            raise ParameterError(f"length / spacing must be <= {MAX_SAMPLES}, got {self.length / self.spacing:.3g}")
        if not isinstance(self.iso_class, str) or self.iso_class.strip().upper() not in ISO_8608_GD0:
            raise ParameterError(f"iso_class must be an ISO 8608 class in A..H, got {self.iso_class!r}")
        put("iso_class", self.iso_class.strip().upper())
        put("anomaly_density", check_nonnegative("anomaly_density", self.anomaly_density))
        put("anomaly_margin", check_nonnegative("anomaly_margin", self.anomaly_margin))
        put("pothole_fraction", check_probability("pothole_fraction", self.pothole_fraction))
        for name in ("depth_range", "pothole_length_range", "bump_length_range"):
            put(name, _check_range(name, getattr(self, name)))
        probs = self.side_probabilities
        if not isinstance(probs, (tuple, list)) or len(probs) != 3:
            raise ParameterError(f"side_probabilities must be (left, right, both), got {probs!r}")
        probs = tuple(check_probability(f"side_probabilities[{i}]", p) for i, p in enumerate(probs))
        if abs(sum(probs) - 1.0) > 1e-9:
            raise ParameterError(f"side_probabilities must sum to 1, got {sum(probs):.12g}")
        put("side_probabilities", probs)
        put("min_anomaly_gap", check_nonnegative("min_anomaly_gap", self.min_anomaly_gap))
        put("enveloping_length", check_nonnegative("enveloping_length", self.enveloping_length))
        longest = max(self.pothole_length_range[1], self.bump_length_range[1])
        if self.anomaly_density > 0 and self.length - 2 * self.anomaly_margin < longest:
            raise ParameterError(f"anomaly_margin must leave room for a {longest:g} m anomaly: need "
                                 f"length - 2 * anomaly_margin >= {longest:g}, got "
                                 f"{self.length - 2 * self.anomaly_margin:g}")


@dataclass(frozen=True, eq=False)
class JumpStatistics:
    """Compound-Poisson jump parameters of the pothole edges seen by one vehicle.

    Parameters
    ----------
    rate : float
        Jumps per second per track, 1/s, >= 0.
    mean : numpy.ndarray
        Mean jump of ``[left, right]``, m, shape (2,).
    covariance : numpy.ndarray
        Jump covariance, m^2, shape (2, 2), positive semidefinite; ``rate * covariance`` is
        the second-moment intensity when the mean is 0.
    """

    rate: float              # 1/s, jumps per second per track
    mean: np.ndarray         # m, shape (2,), mean jump of [left, right]
    covariance: np.ndarray   # m^2, shape (2, 2); rate * covariance = second-moment intensity

    def __post_init__(self):
        object.__setattr__(self, "rate", check_nonnegative("rate", self.rate))
        mean = check_matrix("mean", self.mean, (2,))
        cov = check_psd("covariance", self.covariance, 2)
        for name, arr in (("mean", mean), ("covariance", cov)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def intensity(self) -> np.ndarray:
        """Second-moment intensity ``rate * (covariance + mean mean^T)`` (m^2/s), shape (2, 2)."""
        return self.rate * (self.covariance + np.outer(self.mean, self.mean))


def jump_statistics(spec: RoadSpec, speed) -> JumpStatistics:
    """Compound-Poisson description of the pothole edges for a vehicle at ``speed`` (m/s).

    Each pothole gives two edges (``-depth`` then ``+depth``), so the jump mean is 0. An edge
    hits the left track with probability ``pL + pB`` and the right with ``pR + pB``
    (``side_probabilities = (pL, pR, pB)``); a "both" pothole jumps both tracks by the same
    depth, which is the only source of correlation between tracks. With ``p = mean hit
    probability`` the returned ``rate = 2 * density * pothole_fraction * p * speed`` and
    ``covariance = E[depth^2] / p * [[pL + pB, pB], [pB, pR + pB]]``, so that
    ``rate * covariance`` equals the exact second-moment intensity of the 2-D jump process.
    With symmetric sides (the default) the diagonal is ``E[depth^2]`` and the correlation
    is ``pB / (pL + pB)`` (1/3 by default).

    Ignores the slight thinning by ``min_anomaly_gap`` (anomalies are redrawn, not dropped,
    so the count is kept whenever there is room) and the smoothing of edges by enveloping.

    Parameters
    ----------
    spec : RoadSpec
    speed : float
        Vehicle speed, m/s, > 0.

    Returns
    -------
    JumpStatistics
    """
    if not isinstance(spec, RoadSpec):
        raise ParameterError(f"spec must be a RoadSpec, got {type(spec).__name__}")
    speed = check_positive("speed", speed)
    p_left, p_right, p_both = spec.side_probabilities
    hit = np.array([[p_left + p_both, p_both], [p_both, p_right + p_both]])
    p_mean = 0.5 * (hit[0, 0] + hit[1, 1])   # > 0: the three probabilities sum to 1
    lo, hi = spec.depth_range
    depth_sq = (lo * lo + lo * hi + hi * hi) / 3.0   # E[d^2] for d ~ U(lo, hi)
    rate = 2.0 * spec.anomaly_density * spec.pothole_fraction * p_mean * speed
    return JumpStatistics(rate=rate, mean=np.zeros(2), covariance=depth_sq / p_mean * hit)


def random_walk(n: int, spacing: float, gd0: float, rng: np.random.Generator, tracks: int = 2) -> np.ndarray:
    """ISO 8608 (waviness 2) random-walk elevation, starting at 0, shape (n, tracks) in m.

    Parameters
    ----------
    n : int
        Samples per track (>= 1).
    spacing : float
        Grid step, m.
    gd0 : float
        Gd(n0), m^3.
    rng : numpy.random.Generator
        Draws ``(n - 1, tracks)`` standard normals.
    tracks : int
        Independent tracks (columns).

    Returns
    -------
    numpy.ndarray
        Shape (n, tracks), m; row 0 is 0.
    """
    steps = rng.standard_normal((n - 1, tracks)) * math.sqrt(_increment_variance(gd0, spacing))
    return np.vstack([np.zeros((1, tracks)), np.cumsum(steps, axis=0)])


def moving_average(elevation: np.ndarray, spacing: float, width: float) -> np.ndarray:
    """Centred moving average along axis 0 over ``width`` m; same length as the input.

    Uses the odd number of samples nearest to ``width / spacing`` (rounded up when even) and
    replicates the end values beyond the profile, so there is no start-up transient. A window
    of one sample returns the input unchanged. Used as tyre enveloping and as the lateral
    high-pass of measured profiles.

    Parameters
    ----------
    elevation : numpy.ndarray
        Shape (n,) or (n, tracks), m, on a grid of step ``spacing``.
    spacing : float
        Grid step, m.
    width : float
        Window width, m (0 disables).

    Returns
    -------
    numpy.ndarray
        Same shape as ``elevation``, m (a copy when the window is one sample).
    """
    size = int(round(width / spacing))
    size += 1 - size % 2
    if size <= 1:
        return elevation.copy()
    return uniform_filter1d(elevation, size=size, axis=0, mode="nearest")


def _draw_anomalies(spec: RoadSpec, rng: np.random.Generator) -> tuple[Anomaly, ...]:
    """Poisson anomalies between the margins, redrawing positions to keep ``min_anomaly_gap``."""
    if spec.anomaly_density == 0.0:
        return ()
    count = rng.poisson(spec.anomaly_density * (spec.length - 2 * spec.anomaly_margin))
    gap = spec.min_anomaly_gap
    # Per track, sorted starts and ends of the placed anomalies; kept apart by the gap, so both
    # are sorted and the only candidate conflict is the last one starting before end + gap.
    starts: list[list[float]] = [[], []]
    ends: list[list[float]] = [[], []]
    placed: list[Anomaly] = []
    for _ in range(count):
        kind = "pothole" if rng.random() < spec.pothole_fraction else "bump"
        side = ANOMALY_SIDES[rng.choice(3, p=spec.side_probabilities)]
        depth = rng.uniform(*spec.depth_range)
        length = rng.uniform(*(spec.pothole_length_range if kind == "pothole" else spec.bump_length_range))
        last_start = spec.length - spec.anomaly_margin - length
        for _try in range(100):   # redraw the position, not the count, so the density holds
            cand = Anomaly(rng.uniform(spec.anomaly_margin, last_start), side, kind, depth, length)
            idx = [bisect.bisect_left(starts[t], cand.end + gap) for t in cand.tracks]
            if all(i == 0 or ends[t][i - 1] <= cand.position - gap for t, i in zip(cand.tracks, idx)):
                for t, i in zip(cand.tracks, idx):
                    starts[t].insert(i, cand.position)
                    ends[t].insert(i, cand.end)
                placed.append(cand)
                break
    return tuple(sorted(placed, key=lambda a: a.position))


def generate_road(spec: RoadSpec, *, rng=None) -> RoadProfile:
    """Generate a synthetic two-track road with ground-truth anomalies.

    Each track is an independent ISO 8608 random walk starting at 0 on the grid
    ``distance = spacing * arange(n)``, ``n = floor(length / spacing) + 1``, plus the
    anomalies on that side, then tyre enveloping (centred moving average over
    ``enveloping_length``, ends replicated so the length is kept; 0 disables it).
    The random walk is drawn before the anomalies, so for a fixed seed changing only the
    anomaly settings leaves the roughness unchanged (useful for ablations).

    Parameters
    ----------
    spec : RoadSpec
    rng : None, int or numpy.random.Generator
        Seed or generator, normalised with ``np.random.default_rng``.

    Returns
    -------
    RoadProfile
        ``elevation`` of shape (n, 2) in m, ``source = "synthetic ISO <class>"``.
    """
    if not isinstance(spec, RoadSpec):
        raise ParameterError(f"spec must be a RoadSpec, got {type(spec).__name__}")
    rng = np.random.default_rng(rng)
    n = int(math.floor(spec.length / spec.spacing + 1e-9)) + 1
    distance = spec.spacing * np.arange(n)
    elevation = random_walk(n, spec.spacing, ISO_8608_GD0[spec.iso_class], rng)
    anomalies = _draw_anomalies(spec, rng)
    for anomaly in anomalies:
        # Evaluate on the anomaly's own stretch only: O(length) instead of O(road) per anomaly.
        lo, hi = np.searchsorted(distance, [anomaly.position, anomaly.end], side="left")
        hi = min(hi + 1, n)
        shape = anomaly.elevation(distance[lo:hi])
        for col in anomaly.tracks:
            elevation[lo:hi, col] += shape
    elevation = moving_average(elevation, spec.spacing, spec.enveloping_length)
    return RoadProfile(distance, elevation, anomalies, f"synthetic ISO {spec.iso_class}")



def with_anomalies(profile: RoadProfile, spec: RoadSpec, *, rng=None) -> RoadProfile:
    """Add potholes and bumps drawn from ``spec`` to a (measured) profile, with ground truth.

    Anomalies are drawn over the profile's length with ``spec``'s density, sizes, sides and
    margins, enveloped like the tyre (``spec.enveloping_length``) and added to the elevation of
    the tracks they sit on: measured roughness with known anomalies.

    Parameters
    ----------
    profile : RoadProfile
        The road, e.g. from :func:`roadcollab.io.profiles.measured_road`.
    spec : RoadSpec
        Anomaly settings (its ``length`` and ``spacing`` are replaced by the profile's).
    rng : numpy.random.Generator | int | None

    Returns
    -------
    RoadProfile
        Same distance grid; elevation plus the enveloped anomalies, m; ``anomalies`` are the
        profile's followed by the new ones (positions in the profile's distance).
    """
    if not isinstance(profile, RoadProfile):
        raise ParameterError(f"profile must be a RoadProfile, got {type(profile).__name__}")
    if not isinstance(spec, RoadSpec):
        raise ParameterError(f"spec must be a RoadSpec, got {type(spec).__name__}")
    rng = np.random.default_rng(rng)
    d = profile.distance
    spacing = float(np.median(np.diff(d)))
    local = dataclasses.replace(spec, length=float(d[-1] - d[0]), spacing=spacing)
    anomalies = _draw_anomalies(local, rng)
    x = d - d[0]
    bumps = np.zeros_like(profile.elevation)
    for a in anomalies:
        shape = a.elevation(x)
        for t in a.tracks:
            bumps[:, t] += shape
    if spec.enveloping_length > 0:
        bumps = moving_average(bumps, spacing, spec.enveloping_length)
    shifted = tuple(dataclasses.replace(a, position=a.position + float(d[0])) for a in anomalies)
    return RoadProfile(d, profile.elevation + bumps, profile.anomalies + shifted,
                       f"{profile.source} + synthetic anomalies")
