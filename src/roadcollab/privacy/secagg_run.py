"""One secure-aggregation session simulated end to end, what its parties see, and what it costs.

:func:`run_secure_aggregation` plays every vehicle and the aggregator of :mod:`.secure_aggregation`
in-process, with dropouts, and times each vehicle's work per round. The hooks for the security study:

- :func:`aggregator_view` / :class:`AggregatorView`: everything the aggregator receives (roster, sealed
  shares it forwards, masked vectors, reveals) and the sum it computes;
- :func:`collusion_view`: what the aggregator learns together with ``c`` colluding vehicles (their
  secrets, inputs and the shares sealed for them): the sum of the honest survivors and, only if
  ``c >= t``, individual honest inputs (recovered by actually running the reconstruction);
- :func:`secure_aggregation_cost`: ms, bytes and rounds per vehicle for ``baselines.csv``.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np

from .._validation import check_int
from ..errors import MessageError, ParameterError
from ..wire.message import InversionMessage
from ._secagg_kernels import KEY_NBYTES, decode_sum, derive, encode_fixed, prg_ring, shamir_combine
# The protocol's private helpers are shared with this module only (same concept, split for size).
from .secure_aggregation import (_SEALED_NBYTES, AggregateResult, KeyAdvert, MaskedInput, Reveal, SealedShares,
                                 SecAggSpec, _collect, _open_share, _pair_mask, advertise_keys, mask_input,
                                 reveal_shares, session_id, share_keys, unmask)
from .secagg_messages import VehicleSecrets

__all__ = ["ROUNDS", "AggregatorView", "SecAggRun", "CollusionView", "run_secure_aggregation", "aggregator_view",
           "collusion_view", "secure_aggregation_cost"]

ROUNDS = ("advertise_keys", "share_keys", "masked_input", "unmasking")
_ROUTE_NBYTES = 4   # recipient id in the clear on each sealed share, for the aggregator to forward it


@dataclass(frozen=True)
class AggregatorView:
    """Everything the (honest-but-curious) aggregator receives in one session, and its result.

    Attributes
    ----------
    roster : dict of int to KeyAdvert
        ``U_1``.
    sealed : dict of (int, int) to bytes
        ``(sender, recipient)`` -> ciphertext it forwarded (it holds no key to open them).
    masked : dict of int to ndarray
        ``U_2``: each vehicle's masked ring vector, (L, 2) uint64.
    reveals : tuple of Reveal
        Round 3 answers.
    result : AggregateResult
        The unmasked sum.
    frac_bits : int
        Fixed-point fraction bits of the session.
    """

    roster: dict[int, KeyAdvert]
    sealed: dict[tuple[int, int], bytes]
    masked: dict[int, np.ndarray]
    reveals: tuple[Reveal, ...]
    result: AggregateResult
    frac_bits: int

    def masked_as_float(self, vehicle: int) -> np.ndarray:
        """A masked vector read as if it were a plain fixed-point input (the naive attacker's view), m/s.

        Parameters
        ----------
        vehicle : int
            A survivor's id.

        Returns
        -------
        (L, 2) ndarray
        """
        if vehicle not in self.masked:
            raise ParameterError(f"vehicle must be one of {sorted(self.masked)}, got {vehicle!r}")
        return decode_sum(self.masked[vehicle], self.frac_bits)


@dataclass(frozen=True)
class SecAggRun:
    """A simulated session: the aggregator's view, per-vehicle cost and (simulation only) the vehicles' state.

    Attributes
    ----------
    view : AggregatorView
    spec : SecAggSpec
    session : bytes
    inputs : tuple of ndarray
        Vehicle ``i``'s input is ``inputs[i - 1]`` (m/s), as given (before clipping).
    secrets : tuple of VehicleSecrets
        What a colluding vehicle would hand over (used by :func:`collusion_view`).
    vehicle_ms : (n, 4) ndarray
        Wall-clock ms of each vehicle per round (:data:`ROUNDS`); 0 where it did not take part.
    bytes_sent : (n, 4) ndarray of int
        Bytes each vehicle sent per round.
    bytes_received : (n,) ndarray of int
        Bytes each vehicle received (roster, sealed shares addressed to it, the survivor list).
    aggregator_ms : float
        Wall-clock ms of :func:`unmask`.
    """

    view: AggregatorView
    spec: SecAggSpec
    session: bytes
    inputs: tuple[np.ndarray, ...]
    secrets: tuple[VehicleSecrets, ...]
    vehicle_ms: np.ndarray
    bytes_sent: np.ndarray
    bytes_received: np.ndarray
    aggregator_ms: float

    @property
    def result(self) -> AggregateResult:
        """The aggregate (sum over the survivors)."""
        return self.view.result

    @property
    def average(self) -> np.ndarray:
        """The fused estimate, m/s: the survivors' average."""
        return self.view.result.average


_T = TypeVar("_T")

#: What :func:`run_secure_aggregation` passes every message through (``None``: delivered as is).
Transport = Callable[[Any], Any]


def _timed(fn: Callable[..., _T], *args: Any) -> tuple[_T, float]:
    """``(fn(*args), ms)``."""
    t0 = time.perf_counter()
    out = fn(*args)
    return out, (time.perf_counter() - t0) * 1e3


def _deliver(transport: Transport | None, message: _T, kind: type[_T]) -> _T:
    """``message`` as its recipient gets it: through ``transport`` (if any), still of type ``kind``."""
    if transport is None:
        return message
    out = transport(message)
    if not isinstance(out, kind):
        raise MessageError(f"a {kind.__name__} arrived as a {type(out).__name__}")
    return out


def _forward_sealed(transport: Transport | None, sender: int, recipient: int, ciphertext: bytes, session: bytes) -> bytes:
    """Sealed shares ``sender -> recipient`` as forwarded by the aggregator (through ``transport``)."""
    out = _deliver(transport, SealedShares(sender, recipient, ciphertext, session=session), SealedShares)
    if (out.sender, out.recipient, out.session) != (sender, recipient, session):
        raise MessageError(f"sealed shares {sender} -> {recipient} arrived with another route or session")
    return out.ciphertext


def _check_ids(name: str, ids: Iterable[int], n: int) -> frozenset[int]:
    """A set of vehicle ids in ``1..n``."""
    out = frozenset(check_int(name, i, low=1, high=n) for i in ids)
    return out


def _check_inputs(inputs: Iterable[Any]) -> tuple[np.ndarray, ...]:
    """The vehicles' inputs as finite float arrays of one common shape (L, 2)."""
    arrs = tuple(np.asarray(z.z if isinstance(z, InversionMessage) else z, dtype=float) for z in inputs)
    if not arrs or any(a.shape != arrs[0].shape or a.ndim != 2 or a.shape[1] != 2 for a in arrs):
        raise ParameterError(f"inputs must be (L, 2) arrays of one shape, got {[a.shape for a in arrs]}")
    if not all(np.all(np.isfinite(a)) for a in arrs):
        raise ParameterError("inputs must be finite")
    return arrs


def run_secure_aggregation(inputs: Sequence[Any], spec: SecAggSpec = SecAggSpec(), *, session: bytes | None = None,
                           dropped_before_masking: Iterable[int] = (), silent_in_unmasking: Iterable[int] = (),
                           rng: int | np.random.Generator | None = None,
                           transport: Transport | None = None) -> SecAggRun:
    """Run one session with every vehicle and the aggregator in-process.

    Parameters
    ----------
    inputs : sequence of (L, 2) array_like or InversionMessage
        Vehicle ``i`` (``1..n``) contributes ``inputs[i - 1]`` (``z``, m/s).
    spec : SecAggSpec
        ``k``, ``t``, clipping bound and resolution.
    session : bytes, optional
        Domain separation, default ``session_id(0, 0)``.
    dropped_before_masking : iterable of int
        Vehicles that share their keys (round 1) and then vanish before sending ``y_i``; their
        pairwise masks are removed by reconstructing their ``s_sk``.
    silent_in_unmasking : iterable of int
        Survivors that send ``y_i`` but do not answer in round 3.
    rng : None, int or numpy.random.Generator
        None: every vehicle's root secret from :func:`os.urandom` (as deployed). Otherwise the roots
        are drawn from ``np.random.default_rng(rng)``: reproducible, for simulation and tests only.
    transport : callable, optional
        Applied to every message on its way (KeyAdvert, SealedShares, MaskedInput, Reveal); it returns
        what the recipient gets, e.g. ``lambda m: decode(encode(m))`` to send each one over the wire
        format of :mod:`roadcollab.wire.protocol`. Default: delivered as is.

    Returns
    -------
    SecAggRun

    Raises
    ------
    AggregationRefused
        Fewer than ``k`` survivors or fewer than ``t`` answers in round 3.
    """
    zs = _check_inputs(inputs)
    n = spec.check_fleet(len(zs))
    session = session_id(0, 0) if session is None else session
    gone = _check_ids("dropped_before_masking", dropped_before_masking, n)
    silent = _check_ids("silent_in_unmasking", silent_in_unmasking, n)
    gen = None if rng is None else np.random.default_rng(rng)
    ids = list(range(1, n + 1))
    ms = np.zeros((n, len(ROUNDS)))
    sent = np.zeros((n, len(ROUNDS)), dtype=np.int64)
    recv = np.zeros(n, dtype=np.int64)
    secrets, roster = {}, {}
    for i in ids:
        root = os.urandom(KEY_NBYTES) if gen is None else gen.bytes(KEY_NBYTES)
        (secrets[i], advert), ms[i - 1, 0] = _timed(lambda v, r: advertise_keys(v, session, root=r), i, root)
        roster[i] = _deliver(transport, advert, KeyAdvert)
        sent[i - 1, 0] = advert.nbytes
    sealed = {}
    for i in ids:
        out, ms[i - 1, 1] = _timed(share_keys, secrets[i], roster, spec)
        sealed.update({(i, j): _forward_sealed(transport, i, j, c, session) for j, c in out.items()})
        sent[i - 1, 1] = sum(len(c) + _ROUTE_NBYTES for c in out.values())
    masked = {}
    for i in ids:
        if i not in gone:
            mine, ms[i - 1, 2] = _timed(mask_input, secrets[i], zs[i - 1], roster, spec)
            masked[i] = _deliver(transport, mine, MaskedInput)
            sent[i - 1, 2] = mine.nbytes
    survivors = sorted(masked)
    reveals = []
    for j in survivors:
        if j not in silent:
            for_j = {i: sealed[(i, j)] for i in ids if i != j}
            rev, ms[j - 1, 3] = _timed(reveal_shares, secrets[j], for_j, roster, survivors, spec)
            reveals.append(_deliver(transport, rev, Reveal))
            sent[j - 1, 3] = rev.nbytes
    # Each vehicle receives the roster, the n - 1 shares sealed for it and the survivor list.
    recv[:] = n * roster[1].nbytes + (n - 1) * (_SEALED_NBYTES + _ROUTE_NBYTES) + _ROUTE_NBYTES * len(survivors)
    result, agg_ms = _timed(unmask, roster, masked.values(), reveals, spec, session)
    view = AggregatorView(roster, sealed, {i: m.y for i, m in masked.items()}, tuple(reveals), result,
                          spec.frac_bits)
    return SecAggRun(view, spec, session, zs, tuple(secrets[i] for i in ids), ms, sent, recv, agg_ms)


def aggregator_view(run: SecAggRun) -> AggregatorView:
    """What the aggregator sees in ``run`` (masked vectors, sealed shares, reveals, the aggregate sum).

    Parameters
    ----------
    run : SecAggRun

    Returns
    -------
    AggregatorView
    """
    if not isinstance(run, SecAggRun):
        raise ParameterError(f"run must be a SecAggRun, got {type(run).__name__}")
    return run.view


@dataclass(frozen=True)
class CollusionView:
    """What the aggregator computes together with colluding vehicles.

    Attributes
    ----------
    colluders : tuple of int
        The colluding vehicles (their secrets, inputs and the shares sealed for them are pooled).
    honest : tuple of int
        Honest vehicles whose inputs are in the aggregate (survivors not colluding).
    honest_sum : (L, 2) ndarray
        ``sum_{honest} clip(z_i)``, m/s: the aggregate minus the colluders' own inputs.
    recovered : dict of int to ndarray
        Honest inputs recovered one by one (m/s). Empty unless ``len(colluders) >= t``: with ``t`` shares
        the coalition rebuilds an honest ``s_sk`` and strips every mask (``b_i`` is revealed in round 3).
    """

    colluders: tuple[int, ...]
    honest: tuple[int, ...]
    honest_sum: np.ndarray
    recovered: dict[int, np.ndarray]


def _strip_masks(run: SecAggRun, h: int, s_sk: bytes) -> np.ndarray:
    """Honest survivor ``h``'s input from ``y_h``, its revealed ``b_h`` and its reconstructed ``s_sk``, m/s."""
    view, spec = run.view, run.spec
    y = view.masked[h]
    b_h = shamir_combine(_collect(view.reveals, "self_mask_shares", h), spec.threshold, f"b of vehicle {h}")
    x = y - prg_ring(derive(b_h, b"self", run.session, h), y.shape)
    for j in view.roster:
        if j != h:
            x = x - _pair_mask(s_sk, h, j, view.roster[j].s_pk, run.session, y.shape)
    return decode_sum(x, spec.frac_bits)


def collusion_view(run: SecAggRun, colluders: Iterable[int]) -> CollusionView:
    """The aggregator colluding with ``c`` vehicles: the honest sum, and individual inputs if it can.

    The coalition subtracts its own (clipped, quantised) inputs from the aggregate. For each honest survivor
    it then opens the shares of that vehicle's ``s_sk`` sealed for the colluders and tries to reconstruct
    the key; this succeeds exactly when ``c >= t``.

    Parameters
    ----------
    run : SecAggRun
    colluders : iterable of int
        Ids of the colluding vehicles.

    Returns
    -------
    CollusionView
    """
    if not isinstance(run, SecAggRun):
        raise ParameterError(f"run must be a SecAggRun, got {type(run).__name__}")
    n = len(run.inputs)
    coal = sorted(_check_ids("colluders", colluders, n))
    spec, view = run.spec, run.view
    survivors = view.result.survivors
    own = sum((decode_sum(encode_fixed(run.inputs[c - 1], spec.clip, spec.frac_bits), spec.frac_bits)
               for c in coal if c in survivors), np.zeros_like(view.result.total))
    honest = tuple(i for i in survivors if i not in coal)
    recovered = {}
    for h in honest:
        shares = {c: _open_share(run.secrets[c - 1], h, view.sealed[(h, c)], view.roster)[0] for c in coal}
        try:
            s_sk = shamir_combine(shares, spec.threshold, f"s_sk of vehicle {h}")
        except MessageError:
            continue    # fewer than t shares: nothing about s_sk is known
        recovered[h] = _strip_masks(run, h, s_sk)
    return CollusionView(tuple(coal), honest, view.result.total - own, recovered)


def _cost_inputs(values: Any, n: int, gen: np.random.Generator) -> list[np.ndarray]:
    """``n`` distinct inputs of the shape of ``values``: scaled copies plus a little noise."""
    z = np.asarray(values.z if isinstance(values, InversionMessage) else values, dtype=float)
    z = z.reshape(-1, 2) if z.ndim == 1 and z.size % 2 == 0 else z
    if z.ndim != 2 or z.shape[1] != 2 or z.size == 0 or not np.all(np.isfinite(z)):
        raise ParameterError(f"values must be a finite (L, 2) array, got shape {z.shape}")
    scale = float(np.std(z)) or 1.0
    return [z * (1.0 + 0.1 * gen.standard_normal()) + 0.01 * scale * gen.standard_normal(z.shape) for _ in range(n)]


def secure_aggregation_cost(values: Any, *, n_vehicles: int = 10, spec: SecAggSpec = SecAggSpec(), dropped: int = 0,
                            repeats: int = 3, rng: int | np.random.Generator | None = None) -> dict[str, Any]:
    """Cost per vehicle of one secure aggregation of messages like ``values`` (for ``baselines.csv``).

    Parameters
    ----------
    values : (L, 2) array_like or InversionMessage
        One vehicle's ``z`` (m/s); the ``n_vehicles`` inputs are scaled, noisy copies of it.
    n_vehicles : int
        Vehicles in the session (>= ``spec.min_inputs``).
    spec : SecAggSpec
        ``k``, ``t``, clipping bound and resolution.
    dropped : int
        Vehicles (the last ids) that drop out before masking; the aggregator's recovery is timed.
    repeats : int
        Sessions run; times are medians over them.
    rng : None, int or numpy.random.Generator
        Draws the inputs and the vehicles' root secrets (reproducible; see :func:`run_secure_aggregation`).

    Returns
    -------
    dict
        ``ms_per_message`` (median over sessions of the mean per-vehicle ms over all rounds),
        ``ms_by_round`` (dict, :data:`ROUNDS` -> ms), ``bytes_per_message`` (bytes a vehicle sends in all
        rounds, mean over vehicles that complete them), ``bytes_received``, ``rounds`` (4),
        ``aggregator_ms``, ``max_rel_error`` (of the average against the plain float average of the
        clipped inputs, relative to its peak), ``n_vehicles``, ``min_inputs``, ``threshold``, ``dropped``,
        ``resolution`` (m/s), ``clip`` (m/s), ``n_values``.
    """
    n = spec.check_fleet(check_int("n_vehicles", n_vehicles, low=2))
    dropped = check_int("dropped", dropped, low=0, high=n - spec.min_inputs)
    repeats = check_int("repeats", repeats, low=1)
    gen = np.random.default_rng(rng)
    zs = _cost_inputs(values, n, gen)
    gone = range(n - dropped + 1, n + 1)
    runs = [run_secure_aggregation(zs, spec, dropped_before_masking=gone, rng=gen) for _ in range(repeats)]
    full = slice(0, n - dropped)        # vehicles that take part in every round
    plain = np.mean([np.clip(z, -spec.clip, spec.clip) for z in zs[:n - dropped]], axis=0)
    err = max(float(np.max(np.abs(r.average - plain))) for r in runs) / max(float(np.max(np.abs(plain))), 1e-300)
    per_round = np.median([r.vehicle_ms[full].mean(axis=0) for r in runs], axis=0)
    return {
        "ms_per_message": float(np.median([r.vehicle_ms[full].sum(axis=1).mean() for r in runs])),
        "ms_by_round": dict(zip(ROUNDS, (float(v) for v in per_round))),
        "bytes_per_message": int(round(runs[0].bytes_sent[full].sum(axis=1).mean())),
        "bytes_received": int(runs[0].bytes_received[0]),
        "rounds": len(ROUNDS),
        "aggregator_ms": float(np.median([r.aggregator_ms for r in runs])),
        "max_rel_error": err,
        "n_vehicles": n, "min_inputs": spec.min_inputs, "threshold": spec.threshold, "dropped": dropped,
        "resolution": spec.resolution, "clip": spec.clip, "n_values": int(zs[0].size),
    }
