"""Road profiles: ISO 8608 roughness, anomalies with ground truth, measured profiles.

A road has two wheel tracks (columns ``[left, right]``). The synthetic roughness uses ISO 8608
with waviness 2, so each track's elevation is a random walk in distance: the slope is white
with one-sided spatial PSD ``4 pi^2 n0^2 Gd(n0)`` and an increment over ``ds`` has variance
``2 pi^2 n0^2 Gd(n0) ds``. Seen by a vehicle at speed ``V`` the road velocity is white in time,
one-sided PSD ``4 pi^2 n0^2 Gd(n0) V`` ((m/s)^2/Hz), i.e. a Wiener process of intensity
``2 pi^2 n0^2 Gd(n0) V`` (m^2/s). Pothole edges are the jumps of the jump-diffusion (JDP) model.
"""

from __future__ import annotations

import bisect
import math
import os
import dataclasses
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter1d

from .._validation import (check_matrix, check_nonnegative, check_positive, check_probability, check_psd,
                          check_real)
from ..errors import ParameterError

__all__ = [
    "ISO_8608_GD0", "ISO_8608_N0", "road_velocity_psd", "wiener_intensity",
    "Anomaly", "RoadSpec", "JumpStatistics", "RoadProfile", "TimeRoad", "MeasuredProfile",
    "generate_road", "jump_statistics", "load_profile", "measured_road", "packaged_profile_path", "with_anomalies",
]

#: Geometric-mean displacement PSD Gd(n0) (m^3) of the ISO 8608 classes at n0 = 0.1 cycle/m.
ISO_8608_GD0 = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6, "E": 4096e-6,
                "F": 16384e-6, "G": 65536e-6, "H": 262144e-6}
#: Reference spatial frequency of ISO 8608 (cycle/m).
ISO_8608_N0 = 0.1
_SIDES = ("left", "right", "both")
_KINDS = ("pothole", "bump")
_MAX_SAMPLES = 50_000_000   # per track; a clear error beats a MemoryError deep in numpy
_LATERAL_HIGHPASS = 20.0    # m, window of the moving average removed from the lateral residual


def _gd0(name: str, value) -> float:
    """Resolve an ISO class letter (or a ``RoadSpec``, or a float Gd(n0) in m^3) to Gd(n0)."""
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
    gd0 = _gd0("iso_class_or_gd0", iso_class_or_gd0)
    return 4.0 * math.pi**2 * ISO_8608_N0**2 * gd0 * check_positive("speed", speed)


def wiener_intensity(spec_or_class, speed) -> np.ndarray:
    """Two-sided intensity (m^2/s) of the white road velocity of both tracks, shape (2, 2).

    Half the one-sided PSD of :func:`road_velocity_psd` times the identity (the two tracks'
    random walks are independent). ``spec_or_class`` is a :class:`RoadSpec`, a class letter or
    Gd(n0) in m^3; ``speed`` in m/s.
    """
    return 0.5 * road_velocity_psd(_gd0("spec_or_class", spec_or_class), speed) * np.eye(2)


@dataclass(frozen=True)
class Anomaly:
    """Ground truth of a pothole (rectangular, ``-depth``) or bump (raised cosine of height ``depth``)."""

    position: float   # m, start of the anomaly along the road
    side: str         # "left" | "right" | "both"
    kind: str         # "pothole" | "bump"
    depth: float      # m, > 0: depth of a pothole or height of a bump
    length: float     # m, > 0, extent along the road

    def __post_init__(self):
        check_anomaly_fields(self)
        object.__setattr__(self, "length", check_positive("length", self.length))

    @property
    def center(self) -> float:
        """Middle of the anomaly (m)."""
        return self.position + 0.5 * self.length

    @property
    def end(self) -> float:
        """End of the anomaly (m)."""
        return self.position + self.length

    @property
    def tracks(self) -> tuple[int, ...]:
        """Elevation columns hit: ``(0,)`` left, ``(1,)`` right, ``(0, 1)`` both."""
        return {"left": (0,), "right": (1,), "both": (0, 1)}[self.side]

    def elevation(self, distance) -> np.ndarray:
        """Elevation added by this anomaly at ``distance`` (m, shape (n,)); returns (n,) m."""
        x = np.asarray(distance, dtype=float)
        u = (x - self.position) / self.length
        if self.kind == "pothole":
            # Half-open so that the two edges are single jumps of -depth and +depth.
            return np.where((u >= 0.0) & (u < 1.0), -self.depth, 0.0)
        return np.where((u >= 0.0) & (u <= 1.0), self.depth * 0.5 * (1.0 - np.cos(2 * np.pi * u)), 0.0)


def check_anomaly_fields(obj) -> None:
    """Validate (and normalise) ``position``, ``side``, ``kind`` and ``depth`` of a frozen
    anomaly-like dataclass (a true :class:`Anomaly` or a detection)."""
    object.__setattr__(obj, "position", check_real("position", obj.position))
    if obj.side not in _SIDES:
        raise ParameterError(f"side must be one of {_SIDES}, got {obj.side!r}")
    if obj.kind not in _KINDS:
        raise ParameterError(f"kind must be one of {_KINDS}, got {obj.kind!r}")
    object.__setattr__(obj, "depth", check_positive("depth", obj.depth))


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
    """Parameters of a synthetic two-track road (see :func:`generate_road`)."""

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
        if self.length / self.spacing > _MAX_SAMPLES:
            raise ParameterError(f"length / spacing must be <= {_MAX_SAMPLES}, got {self.length / self.spacing:.3g}")
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
    """Compound-Poisson jump parameters of the pothole edges seen by one vehicle."""

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


def _random_walk(n: int, spacing: float, gd0: float, rng: np.random.Generator, tracks: int = 2) -> np.ndarray:
    """ISO 8608 (waviness 2) random-walk elevation, starting at 0, shape (n, tracks) in m."""
    steps = rng.standard_normal((n - 1, tracks)) * math.sqrt(_increment_variance(gd0, spacing))
    return np.vstack([np.zeros((1, tracks)), np.cumsum(steps, axis=0)])


def _moving_average(elevation: np.ndarray, spacing: float, width: float) -> np.ndarray:
    """Centred moving average along axis 0 over ``width`` m; same length as the input.

    Uses the odd number of samples nearest to ``width / spacing`` (rounded up when even) and
    replicates the end values beyond the profile, so there is no start-up transient. A window
    of one sample returns the input unchanged.
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
        side = _SIDES[rng.choice(3, p=spec.side_probabilities)]
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
    elevation = _random_walk(n, spec.spacing, ISO_8608_GD0[spec.iso_class], rng)
    anomalies = _draw_anomalies(spec, rng)
    for anomaly in anomalies:
        # Evaluate on the anomaly's own stretch only: O(length) instead of O(road) per anomaly.
        lo, hi = np.searchsorted(distance, [anomaly.position, anomaly.end], side="left")
        hi = min(hi + 1, n)
        shape = anomaly.elevation(distance[lo:hi])
        for col in anomaly.tracks:
            elevation[lo:hi, col] += shape
    elevation = _moving_average(elevation, spec.spacing, spec.enveloping_length)
    return RoadProfile(distance, elevation, anomalies, f"synthetic ISO {spec.iso_class}")


@dataclass(frozen=True, eq=False)
class TimeRoad:
    """The road seen by a vehicle at constant speed, sampled in time.

    The elevation is taken as linear between samples, so the road velocity is exactly
    piecewise constant and a zero-order-hold discretisation of the vehicle is exact.
    """

    time: np.ndarray        # s, shape (N,): k / sample_rate, start of each sample interval
    elevation: np.ndarray   # m, shape (N + 1, 2): [left, right] at k / sample_rate, k = 0..N
    velocity: np.ndarray    # m/s, shape (N, 2): (elevation[k + 1] - elevation[k]) * sample_rate
    speed: float            # m/s
    sample_rate: float      # Hz
    start: float            # m, road distance of sample 0
    anomalies: tuple[Anomaly, ...] = ()   # overlapping the window, positions in road distance

    def __post_init__(self):
        time = check_matrix("time", self.time, (None,))
        n = time.shape[0]
        elevation = check_matrix("elevation", self.elevation, (n + 1, 2))
        velocity = check_matrix("velocity", self.velocity, (n, 2))
        for name, arr in (("time", time), ("elevation", elevation), ("velocity", velocity)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "speed", check_positive("speed", self.speed))
        object.__setattr__(self, "sample_rate", check_positive("sample_rate", self.sample_rate))
        object.__setattr__(self, "start", check_real("start", self.start))
        object.__setattr__(self, "anomalies", tuple(self.anomalies))

    @property
    def positions(self) -> np.ndarray:
        """Road distance (m) of the elevation samples, shape (N + 1,)."""
        return self.start + self.speed * np.arange(self.time.shape[0] + 1) / self.sample_rate

    def position(self, k) -> float:
        """Road distance (m) of elevation sample ``k`` (may be fractional)."""
        return self.start + self.speed * check_real("k", k) / self.sample_rate


@dataclass(frozen=True, eq=False)
class RoadProfile:
    """A two-track road profile on a distance grid."""

    distance: np.ndarray    # m, shape (n,), strictly increasing
    elevation: np.ndarray   # m, shape (n, 2), columns [left, right]
    anomalies: tuple[Anomaly, ...] = ()   # ground truth (empty for measured roads)
    source: str = ""        # e.g. "synthetic ISO C" or the file name

    def __post_init__(self):
        distance = check_matrix("distance", self.distance, (None,))
        if distance.shape[0] < 2 or np.any(np.diff(distance) <= 0):
            raise ParameterError(f"distance must be strictly increasing with >= 2 points, got {distance.shape[0]} "
                                 f"points and {int(np.sum(np.diff(distance) <= 0))} non-increasing steps")
        elevation = check_matrix("elevation", self.elevation, (distance.shape[0], 2))
        for name, arr in (("distance", distance), ("elevation", elevation)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        if not all(isinstance(a, Anomaly) for a in self.anomalies):
            raise ParameterError("anomalies must be a sequence of Anomaly")
        object.__setattr__(self, "anomalies", tuple(self.anomalies))
        if not isinstance(self.source, str):
            raise ParameterError(f"source must be a str, got {type(self.source).__name__}")

    @property
    def length(self) -> float:
        """Covered distance (m)."""
        return float(self.distance[-1] - self.distance[0])

    def sample(self, speed, sample_rate, *, start=0.0, duration=None) -> TimeRoad:
        """Elevation seen at constant ``speed`` (m/s), sampled at ``sample_rate`` (Hz).

        Linear interpolation in distance at ``x_k = start + speed * k / sample_rate`` for
        ``k = 0..N`` with ``N = floor(duration * sample_rate)`` (``duration`` in s; default:
        up to the end of the profile). The window ``[start, x_N]`` must lie in the profile.
        """
        speed = check_positive("speed", speed)
        sample_rate = check_positive("sample_rate", sample_rate)
        start = check_real("start", start)
        first, last = float(self.distance[0]), float(self.distance[-1])
        tol = 1e-9 * max(1.0, abs(first), abs(last))   # absorbs float rounding of x_N
        if not first - tol <= start < last:
            raise ParameterError(f"start must lie in the profile [{first:g}, {last:g}) m, got {start:g}")
        if duration is None:
            duration = (last - start) / speed
        else:
            duration = check_positive("duration", duration)
        n = int(math.floor(duration * sample_rate + 1e-9))
        end = start + speed * n / sample_rate
        if n < 1:
            raise ParameterError(f"duration must cover at least one sample interval 1/sample_rate = "
                                 f"{1 / sample_rate:g} s, got {duration:g} s")
        if end > last + tol:
            raise ParameterError(f"duration must keep the window inside the profile: start + speed * duration = "
                                 f"{end:g} m > profile end {last:g} m (max duration {(last - start) / speed:g} s)")
        x = np.clip(start + speed * np.arange(n + 1) / sample_rate, first, last)
        elevation = np.column_stack([np.interp(x, self.distance, self.elevation[:, c]) for c in range(2)])
        inside = tuple(a for a in self.anomalies if a.end >= start and a.position <= end)
        return TimeRoad(time=np.arange(n) / sample_rate, elevation=elevation,
                        velocity=np.diff(elevation, axis=0) * sample_rate, speed=speed,
                        sample_rate=sample_rate, start=start, anomalies=inside)


@dataclass(frozen=True, eq=False)
class MeasuredProfile:
    """One measured track as read from a file: ``distance`` (n,) m, ``elevation`` (n,) m."""

    distance: np.ndarray   # m, shape (n,), as in the file
    elevation: np.ndarray  # m, shape (n,)
    spacing: float         # m, median distance step
    source: str            # the file path as given

    def __post_init__(self):
        distance = check_matrix("distance", self.distance, (None,))
        elevation = check_matrix("elevation", self.elevation, (distance.shape[0],))
        for name, arr in (("distance", distance), ("elevation", elevation)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "spacing", check_positive("spacing", self.spacing))

    def __len__(self) -> int:
        return int(self.distance.shape[0])


def packaged_profile_path():
    """Path (a ``Traversable``; a ``pathlib.Path`` in normal installs) of ``data/profile_1.txt``."""
    return resources.files("roadcollab") / "data" / "profile_1.txt"


def load_profile(path) -> MeasuredProfile:
    """Read rows ``distance_m elevation_m`` (whitespace or comma separated; ``#`` comments).

    Raises
    ------
    ParameterError
        Naming the file and 1-based line: not 2 numbers, non-finite values, non-increasing or
        non-uniform distance (relative tolerance 1e-6 of the spacing), fewer than 8 rows.
    """
    name = str(path)
    try:
        text = (Path(path) if isinstance(path, (str, os.PathLike)) else path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise ParameterError(f"path: cannot read profile file {name}: {err}") from err
    rows, lines = [], []
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        tokens = [t.strip() for t in line.split(",")] if "," in line else line.split()
        try:
            values = [float(t) for t in tokens]
        except ValueError:
            values = []
        if len(values) != 2:
            raise ParameterError(f"{name}: line {lineno}: expected 2 numbers 'distance_m elevation_m', got {raw!r}")
        if not all(math.isfinite(v) for v in values):
            raise ParameterError(f"{name}: line {lineno}: expected finite numbers, got {raw!r}")
        if rows and values[0] <= rows[-1][0]:
            raise ParameterError(f"{name}: line {lineno}: expected distance > {rows[-1][0]:g} (increasing), "
                                 f"got {values[0]:g}")
        rows.append(values)
        lines.append(lineno)
    if len(rows) < 8:
        raise ParameterError(f"{name}: expected at least 8 data rows, got {len(rows)}")
    data = np.array(rows)
    steps = np.diff(data[:, 0])
    spacing = float(np.median(steps))
    # Tolerance relative to the spacing, plus float rounding of large distance values.
    bad = np.flatnonzero(np.abs(steps - spacing) > 1e-6 * spacing + 1e-12 * np.abs(data[1:, 0]))
    if bad.size:
        i = int(bad[0])
        raise ParameterError(f"{name}: line {lines[i + 1]}: expected uniform spacing {spacing:g} m, "
                             f"got step {steps[i]:g} m")
    return MeasuredProfile(data[:, 0], data[:, 1], spacing, name)


def _detrend(distance: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Remove the least-squares line (DC and slope are unobservable to accelerometers)."""
    slope, offset = np.polyfit(distance, z, 1)
    return z - (offset + slope * distance)


def measured_road(path=None, *, second_track="lateral", lateral_class="A", detrend=True, spacing=None,
                  enveloping_length=0.25, rng=None) -> RoadProfile:
    """Two-track road from a measured single-track profile (left track).

    Parameters
    ----------
    path : str, PathLike or None
        Profile file (see :func:`load_profile`); None uses :func:`packaged_profile_path`.
    second_track : {"lateral", "same", "synthetic"}
        Right track: ``"lateral"`` = left + an independent ISO ``lateral_class`` random walk
        high-passed by subtracting its 20 m centred moving average (coherent at long, independent
        at short wavelengths); ``"same"`` = left; ``"synthetic"`` = an independent ISO
        ``lateral_class`` random walk (also detrended when ``detrend``).
    lateral_class : str or float
        ISO 8608 class (or Gd(n0) in m^3) of the right-track random walk.
    detrend : bool
        Remove a least-squares line from the measured track.
    spacing : float or None
        Resample linearly to this grid step (m); None keeps the file's spacing.
    enveloping_length : float
        Tyre enveloping moving-average width (m), as in :func:`generate_road`; 0 disables.
    rng : None, int or numpy.random.Generator

    Returns
    -------
    RoadProfile
        Distance starting at 0, elevation (n, 2) m, no anomalies, ``source`` = file name.
    """
    if second_track not in ("lateral", "same", "synthetic"):
        raise ParameterError(f"second_track must be 'lateral', 'same' or 'synthetic', got {second_track!r}")
    gd0 = _gd0("lateral_class", lateral_class)
    enveloping_length = check_nonnegative("enveloping_length", enveloping_length)
    if not isinstance(detrend, (bool, np.bool_)):
        raise ParameterError(f"detrend must be a bool, got {detrend!r}")
    rng = np.random.default_rng(rng)
    measured = load_profile(packaged_profile_path() if path is None else path)
    distance = measured.distance - measured.distance[0]
    left = _detrend(distance, measured.elevation) if detrend else measured.elevation.copy()
    step = measured.spacing
    if spacing is not None:
        step = check_positive("spacing", spacing)
        if not distance[-1] / _MAX_SAMPLES <= step <= 0.5 * distance[-1]:
            raise ParameterError(f"spacing must lie in [{distance[-1] / _MAX_SAMPLES:g}, {0.5 * distance[-1]:g}] m "
                                 f"(at most {_MAX_SAMPLES} samples, at least 3), got {step:g}")
        grid = step * np.arange(int(math.floor(distance[-1] / step + 1e-9)) + 1)
        left, distance = np.interp(grid, distance, left), grid
    if second_track == "same":
        right = left.copy()
    else:
        walk = _random_walk(distance.shape[0], step, gd0, rng, tracks=1)[:, 0]
        if second_track == "lateral":
            right = left + walk - _moving_average(walk, step, _LATERAL_HIGHPASS)
        else:
            right = _detrend(distance, walk) if detrend else walk
    elevation = _moving_average(np.column_stack([left, right]), step, enveloping_length)
    return RoadProfile(distance, elevation, (), Path(measured.source).name)


def with_anomalies(profile: RoadProfile, spec: RoadSpec, *, rng=None) -> RoadProfile:
    """Add potholes and bumps drawn from ``spec`` to a (measured) profile, with ground truth.

    Anomalies are drawn over the profile's length with ``spec``'s density, sizes, sides and
    margins, enveloped like the tyre (``spec.enveloping_length``) and added to the elevation of
    the tracks they sit on: measured roughness with known anomalies.

    Parameters
    ----------
    profile : RoadProfile
    spec : RoadSpec
        Anomaly settings (its ``length`` and ``spacing`` are replaced by the profile's).
    rng : numpy.random.Generator | int | None

    Returns
    -------
    RoadProfile
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
        bumps = _moving_average(bumps, spacing, spec.enveloping_length)
    shifted = tuple(dataclasses.replace(a, position=a.position + float(d[0])) for a in anomalies)
    return RoadProfile(d, profile.elevation + bumps, profile.anomalies + shifted,
                       f"{profile.source} + synthetic anomalies")
