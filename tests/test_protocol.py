"""Tests of roadcollab.wire.protocol: the binary wire format for untrusted vehicle-to-vehicle messages."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from roadcollab.wire import protocol
from roadcollab.errors import MessageError
from roadcollab.wire.message import ExchangeMessage, InversionMessage
from roadcollab.wire.secagg import KeyAdvert, MaskedInput, Reveal, SealedShares
from roadcollab.lti.realisation import StateSpaceData
from roadcollab.wire.protocol import (
    FORMAT_VERSION,
    MAGIC,
    MAX_COUNT,
    MAX_MESSAGE_BYTES,
    MAX_ORDER,
    MAX_SIGNAL_LENGTH,
    decode,
    encode,
    example_message,
    message_nbytes,
    write_example,
)

MECHANISMS = ["none", "paper", "hardened", "fused"]
MECH_CODE = {"none": 1, "paper": 2, "hardened": 3, "fused": 4}
FS = 100.0

# No example database: nothing may land in the repository.
FUZZ = settings(max_examples=400, deadline=None, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


# --- an independent writer of the documented layout -------------------------------------------
# Written from the module docstring's table, not from protocol.py, so that it checks the
# documentation and lets the tests craft hostile messages that encode() would refuse.

def raw_exchange(T, S, e, wf, *, fs=FS, n_samples=None, mechanism="paper", magic=MAGIC,
                 version=FORMAT_VERSION, msg_type=1, mech_code=None, reserved=0, payload_nbytes=None,
                 orders=None, dts=None, extra=b""):
    """T and S are (A, B, C, D) tuples of arrays."""
    payload = b"".join(np.asarray(a, dtype="<f8").tobytes() for a in (*T, *S, e, wf))
    nT, nS = orders if orders is not None else (np.shape(T[0])[0], np.shape(S[0])[0])
    dT, dS = dts if dts is not None else (1.0 / fs, 1.0 / fs)
    head = struct.pack("<4sBBBBdIIQ", magic, version, msg_type,
                       MECH_CODE[mechanism] if mech_code is None else mech_code, reserved, fs,
                       len(e) // 2 if n_samples is None else n_samples, len(e),
                       len(payload) if payload_nbytes is None else payload_nbytes)
    return head + struct.pack("<IIdd", nT, nS, dT, dS) + payload + extra


def raw_inversion(z, *, fs=FS, n_samples=None, mechanism="fused", count=2, msg_type=2, reserved=0):
    payload = np.asarray(z, dtype="<f8").tobytes()
    head = struct.pack("<4sBBBBdIIQ", MAGIC, FORMAT_VERSION, msg_type, MECH_CODE[mechanism], 0, fs,
                       len(z) // 2 if n_samples is None else n_samples, len(z), len(payload))
    return head + struct.pack("<II", count, reserved) + payload


def stable_system(n, rng, radius=0.9):
    A = rng.standard_normal((n, n))
    if n:
        A *= radius / np.max(np.abs(np.linalg.eigvals(A)))
    return A, rng.standard_normal((n, 2)), rng.standard_normal((2, n)), rng.standard_normal((2, 2))


def small_parts(seed=0, nT=1, nS=2, L=12):
    rng = np.random.default_rng(seed)
    return stable_system(nT, rng), stable_system(nS, rng), rng.standard_normal((L, 2)), rng.standard_normal((L, 2))


def small_exchange(seed=0, mechanism="paper", **kw):
    T, S, e, wf = small_parts(seed, **kw)
    return ExchangeMessage(mechanism, FS, len(e) // 2, StateSpaceData(*T, 1.0 / FS),
                           StateSpaceData(*S, 1.0 / FS), e, wf)


def small_inversion(seed=0, mechanism="fused", L=12, count=2):
    z = np.random.default_rng(seed).standard_normal((L, 2))
    return InversionMessage(mechanism, FS, L // 2, z, count)


def arrays_of(msg):
    if isinstance(msg, InversionMessage):
        return {"z": msg.z}
    out = {"e": msg.e, "wf": msg.wf}
    for name in ("T", "S"):
        for p in "ABCD":
            out[f"{name}.{p}"] = getattr(getattr(msg, name), p)
    return out


def assert_same(a, b):
    assert type(a) is type(b)
    assert (a.mechanism, a.sample_rate, a.n_samples) == (b.mechanism, b.sample_rate, b.n_samples)
    if isinstance(a, InversionMessage):
        assert a.count == b.count
    else:
        assert (a.T.dt, a.S.dt) == (b.T.dt, b.S.dt)
    xa, xb = arrays_of(a), arrays_of(b)
    for k in xa:
        assert xb[k].dtype == np.float64, k
        assert xa[k].shape == xb[k].shape, k
        # Bit-identical, not just equal: compare the raw bytes too (catches -0.0 vs 0.0).
        assert np.array_equal(xa[k], xb[k]) and xa[k].tobytes() == np.asarray(xb[k], "<f8").tobytes(), k


# --- round trips and layout --------------------------------------------------------------------

@pytest.mark.parametrize("mechanism", MECHANISMS)
def test_round_trip_every_mechanism(mechanism):
    msg = example_message(mechanism, rng=3)
    data = encode(msg)
    assert isinstance(data, bytes)
    out = decode(data)
    assert_same(out, msg)
    assert out.mechanism == mechanism


@pytest.mark.parametrize("wrap", [bytes, bytearray, memoryview, lambda b: memoryview(bytearray(b))[::1]])
def test_decode_accepts_bytes_like(wrap):
    msg = small_exchange()
    assert_same(decode(wrap(encode(msg))), msg)


def test_decode_non_contiguous_memoryview():
    data = encode(small_inversion())
    doubled = bytearray(len(data) * 2)
    doubled[::2] = data
    assert_same(decode(memoryview(doubled)[::2]), small_inversion())


def test_round_trip_is_bit_exact_for_awkward_floats():
    msg = small_exchange()
    e = msg.e.copy()
    e[:6, 0] = [-0.0, 5e-324, np.finfo(float).max, -np.finfo(float).tiny, 1 / 3, np.nextafter(1.0, 2.0)]
    msg = ExchangeMessage("none", 1 / 3, 1, _sys(msg.T, dt=3.0), _sys(msg.S, dt=3.0), e, msg.wf)
    out = decode(encode(msg))
    assert_same(out, msg)
    assert np.signbit(out.e[0, 0]) and out.sample_rate == 1 / 3


def test_encode_matches_documented_layout():
    T, S, e, wf = small_parts()
    msg = small_exchange()
    assert encode(msg) == raw_exchange(T, S, e, wf)
    inv = small_inversion()
    assert encode(inv) == raw_inversion(inv.z)


@pytest.mark.parametrize("mechanism", MECHANISMS)
def test_encoded_size_formula(mechanism):
    msg = example_message(mechanism, rng=0)
    data = encode(msg)
    if isinstance(msg, ExchangeMessage):
        nT, nS, L = msg.T.order, msg.S.order, msg.e.shape[0]
        floats = nT * nT + 4 * nT + 4 + nS * nS + 4 * nS + 4 + 4 * L
        expected = 56 + 8 * floats
    else:
        expected = 40 + 8 * 2 * msg.z.shape[0]
    assert len(data) == expected == message_nbytes(msg)


def test_max_message_bytes_is_the_largest_valid_message():
    assert MAX_MESSAGE_BYTES == 56 + 8 * (2 * (MAX_ORDER + 2) ** 2 + 4 * MAX_SIGNAL_LENGTH)


def test_a_validated_message_is_frozen_and_not_checked_again_unless_it_could_have_changed():
    msg = small_exchange()
    for name, arr in arrays_of(msg).items():
        assert not arr.flags.writeable, name        # what was checked cannot change in place
    assert encode(msg) == encode(msg)
    # Unfrozen by hand and poisoned: the memo no longer applies and encode refuses.
    msg.e.setflags(write=True)
    msg.e[0, 0] = np.nan
    with pytest.raises(MessageError, match="e must be finite"):
        encode(msg)
    # A message holding a view of a writable array is validated at every encode.
    base = np.random.default_rng(3).standard_normal((12, 2))
    inv = InversionMessage("hardened", FS, 6, base[:], 1)
    assert base.flags.writeable
    encode(inv)
    base[1, 1] = np.inf
    with pytest.raises(MessageError, match="z must be finite"):
        encode(inv)


def test_decoded_arrays_are_owned_read_only_copies():
    buf = bytearray(encode(small_exchange()))
    out = decode(buf)
    for name, arr in arrays_of(out).items():
        assert arr.flags.owndata and arr.base is None, name
        assert not arr.flags.writeable, name
        with pytest.raises(ValueError):
            arr[0, 0] = 1.0
    before = out.e.copy()
    buf[56 + 8 * (9 + 16):] = bytes(len(buf) - 56 - 8 * (9 + 16))  # zero the caller's e/wf bytes
    assert np.array_equal(out.e, before)


# --- refused corruptions ------------------------------------------------------------------------

@pytest.mark.parametrize("data", [encode(small_exchange()), encode(small_inversion())],
                         ids=["exchange", "inversion"])
def test_every_truncation_refused(data):
    for k in range(len(data)):
        with pytest.raises(MessageError, match="truncated"):
            decode(data[:k])


def test_truncation_message_names_declared_and_actual():
    data = encode(small_inversion(L=12))   # payload 12 * 2 * 8 = 192 bytes
    with pytest.raises(MessageError, match=r"^truncated: header declares 192 payload bytes, got 190$"):
        decode(data[:-2])


@pytest.mark.parametrize("data", [encode(small_exchange()), encode(small_inversion())],
                         ids=["exchange", "inversion"])
def test_appended_byte_refused(data):
    with pytest.raises(MessageError, match=r"trailing data: .* \(1 extra\)"):
        decode(data + b"\x00")


def test_wrong_magic():
    with pytest.raises(MessageError, match="wrong magic"):
        decode(b"RCOX" + encode(small_exchange())[4:])
    with pytest.raises(MessageError, match="wrong magic"):
        decode(b"GIF89a")


def test_version_2_refused():
    data = bytearray(encode(small_exchange()))
    data[4] = 2
    with pytest.raises(MessageError, match="unsupported format version 2, expected 1"):
        decode(bytes(data))


@pytest.mark.parametrize("msg_type", [0, 7, 255])
def test_unknown_message_type(msg_type):
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match=f"unknown message type {msg_type}"):
        decode(raw_exchange(T, S, e, wf, msg_type=msg_type))


@pytest.mark.parametrize("code", [0, 6, 200])
def test_unknown_mechanism(code):
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match=f"unknown mechanism code {code}"):
        decode(raw_exchange(T, S, e, wf, mech_code=code))


def test_type_mechanism_mismatch():
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match="'fused' requires an inversion message, got an exchange"):
        decode(raw_exchange(T, S, e, wf, mechanism="fused"))
    with pytest.raises(MessageError, match="'paper' requires an exchange message"):
        decode(raw_inversion(np.zeros((8, 2)), mechanism="paper"))


def test_reserved_bytes_must_be_zero():
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match="reserved header byte"):
        decode(raw_exchange(T, S, e, wf, reserved=1))
    with pytest.raises(MessageError, match="reserved inversion header field"):
        decode(raw_inversion(np.zeros((8, 2)), reserved=7))


def test_nan_in_e_refused():
    T, S, e, wf = small_parts()
    e[3, 1] = np.nan
    with pytest.raises(MessageError, match=r"e must be finite, got 1 non-finite"):
        decode(raw_exchange(T, S, e, wf))


def test_inf_in_A_refused():
    T, S, e, wf = small_parts()
    A = S[0].copy()
    A[1, 0] = -np.inf
    with pytest.raises(MessageError, match=r"S\.A must be finite"):
        decode(raw_exchange(T, (A, *S[1:]), e, wf))


def test_nan_in_z_refused():
    z = np.zeros((8, 2))
    z[-1, -1] = np.nan
    with pytest.raises(MessageError, match="z must be finite"):
        decode(raw_inversion(z))


@pytest.mark.parametrize("orders", [(MAX_ORDER + 1, 1), (1, 2**32 - 1)])
def test_oversized_order_refused_from_header_before_allocating(orders, monkeypatch):
    def must_not_allocate(*args, **kwargs):  # pragma: no cover - reached only on failure
        raise AssertionError("decode read a payload array for an oversized header")

    monkeypatch.setattr(protocol, "_read_array", must_not_allocate)
    head = struct.pack("<4sBBBBdIIQ", MAGIC, 1, 1, 2, 0, FS, 100, 200, 2**63) \
        + struct.pack("<IIdd", *orders, 1 / FS, 1 / FS)
    with pytest.raises(MessageError, match=r"oversized: order of [TS] must be in \[0, 64\] \(MAX_ORDER\)"):
        decode(head)


def test_oversized_length_refused_from_header():
    head = struct.pack("<4sBBBBdIIQ", MAGIC, 1, 2, 4, 0, FS, 100, MAX_SIGNAL_LENGTH + 1, 16 * (MAX_SIGNAL_LENGTH + 1))
    with pytest.raises(MessageError, match="oversized or empty: signal length"):
        decode(head + struct.pack("<II", 1, 0))


def test_oversized_byte_count_refused():
    data = bytearray(MAX_MESSAGE_BYTES + 1)
    data[:40] = encode(small_inversion())[:40]
    with pytest.raises(MessageError, match=f"oversized: {MAX_MESSAGE_BYTES + 1} bytes exceeds MAX_MESSAGE_BYTES"):
        decode(memoryview(data))


def test_declared_payload_inconsistent_with_dimensions():
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match="header declares 99 payload bytes but its dimensions imply"):
        decode(raw_exchange(T, S, e, wf, payload_nbytes=99))


def test_declared_orders_inconsistent_with_payload():
    T, S, e, wf = small_parts()  # orders 1 and 2; claim 2 and 1 (same total floats)
    with pytest.raises(MessageError):
        decode(raw_exchange(T, S, e, wf, orders=(2, 2)))


@pytest.mark.parametrize("which", ["T", "S"])
def test_unstable_A_refused(which):
    rng = np.random.default_rng(5)
    T, S, e, wf = small_parts()
    unstable = stable_system(3, rng, radius=1.01)
    parts = dict(T=T, S=S)
    parts[which] = unstable
    with pytest.raises(MessageError, match=f"{which} must be discrete-time stable .* got 1.01"):
        decode(raw_exchange(parts["T"], parts["S"], e, wf))


def test_marginally_stable_A_refused():
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match="stable"):
        decode(raw_exchange((np.eye(1), *T[1:]), S, e, wf))


@pytest.mark.parametrize("dts", [(1 / FS * (1 + 1e-9), 1 / FS), (1 / FS, 2 / FS), (1 / FS, np.nan)])
def test_wrong_dt_refused(dts):
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match=r"\.dt must equal 1/sample_rate"):
        decode(raw_exchange(T, S, e, wf, dts=dts))


def test_dt_within_tolerance_accepted():
    T, S, e, wf = small_parts()
    out = decode(raw_exchange(T, S, e, wf, dts=(1 / FS * (1 + 5e-13), 1 / FS)))
    assert out.T.dt == 1 / FS * (1 + 5e-13)


@pytest.mark.parametrize("n_samples", [13, 0, 2**32 - 1])
def test_n_samples_out_of_range(n_samples):
    T, S, e, wf = small_parts()  # L = 12
    with pytest.raises(MessageError, match=rf"n_samples must be in \[1, signal length 12\], got {n_samples}"):
        decode(raw_exchange(T, S, e, wf, n_samples=n_samples))


@pytest.mark.parametrize("fs", [0.0, -1.0, 2e6, np.nan, np.inf])
def test_sample_rate_out_of_range(fs):
    with pytest.raises(MessageError, match="sample_rate must be finite and in"):
        decode(raw_inversion(np.zeros((8, 2)), fs=fs))


def test_subnormal_sample_rate_refused_for_exchange():
    T, S, e, wf = small_parts()
    with pytest.raises(MessageError, match="too small"):
        decode(raw_exchange(T, S, e, wf, fs=5e-324, dts=(1.0, 1.0)))


@pytest.mark.parametrize("count, mechanism", [(0, "fused"), (MAX_COUNT + 1, "fused"), (2, "hardened")])
def test_count_out_of_range(count, mechanism):
    with pytest.raises(MessageError, match="count must be"):
        decode(raw_inversion(np.zeros((8, 2)), count=count, mechanism=mechanism))


@pytest.mark.parametrize("data", ["RCOL", None, [1, 2, 3], 42, np.zeros(8)])
def test_non_bytes_input_refused(data):
    with pytest.raises(MessageError, match="message must be bytes, bytearray or memoryview"):
        decode(data)


# --- encode refuses what decode would refuse -------------------------------------------------------

def _replace(msg, **kw):
    fields = {k: getattr(msg, k) for k in msg.__dataclass_fields__}
    fields.update(kw)
    return type(msg)(**fields)


def _sys(sys, **kw):
    fields = dict(A=sys.A, B=sys.B, C=sys.C, D=sys.D, dt=sys.dt)
    fields.update(kw)
    return StateSpaceData(**fields)


def _with_nan(a, value=np.nan):
    a = np.array(a, dtype=float)
    a.flat[a.size // 2] = value
    return a


@pytest.mark.parametrize("bad, match", [
    (lambda m: _replace(m, e=_with_nan(m.e)), r"^e must be finite"),
    (lambda m: _replace(m, wf=_with_nan(m.wf, np.inf)), r"^wf must be finite"),
    (lambda m: _replace(m, T=_sys(m.T, B=_with_nan(m.T.B, -np.inf))), r"^T\.B must be finite"),
    (lambda m: _replace(m, S=_sys(m.S, D=_with_nan(m.S.D))), r"^S\.D must be finite"),
    (lambda m: _replace(m, sample_rate=np.nan), "sample_rate must be finite"),
    (lambda m: _replace(m, T=_sys(m.T, dt=np.inf)), r"T\.dt must equal"),
])
def test_encode_refuses_non_finite(bad, match):
    with pytest.raises(MessageError, match=match):
        encode(bad(small_exchange()))


def test_encode_refuses_non_finite_inversion():
    msg = small_inversion()
    with pytest.raises(MessageError, match="z must be finite"):
        encode(_replace(msg, z=_with_nan(msg.z)))


@pytest.mark.parametrize("bad, match", [
    (lambda m: _replace(m, T=_sys(m.T, A=1.01 * np.eye(1))), "T must be discrete-time stable"),
    (lambda m: _replace(m, T=_sys(m.T, dt=2 / FS)), r"T\.dt must equal"),
    (lambda m: _replace(m, n_samples=m.e.shape[0] + 1), "n_samples must be in"),
    (lambda m: _replace(m, n_samples=True), "n_samples must be an integer"),
    (lambda m: _replace(m, n_samples=3.0), "n_samples must be an integer"),
    (lambda m: _replace(m, mechanism="hardened"), "'hardened' requires an inversion message"),
    (lambda m: _replace(m, mechanism="PAPER"), "mechanism must be one of"),
    (lambda m: _replace(m, e=m.e[:, :1]), r"e must have shape \(any, 2\), got \(12, 1\)"),
    (lambda m: _replace(m, wf=m.wf[:-1]), r"wf must have shape \(12, 2\), got \(11, 2\)"),
    (lambda m: _replace(m, e=m.e.ravel()), r"e must have shape"),
    (lambda m: _replace(m, T=_sys(m.T, A=np.zeros((2, 3)))), r"T\.A must have shape \(2, 2\)"),
    (lambda m: _replace(m, e=m.e.astype(complex)), "must be a real float array, got dtype complex128"),
    (lambda m: _replace(m, e=m.e.astype(object)), "must be a real float array"),
    (lambda m: _replace(m, T="not a system"), "T must be a StateSpaceData"),
    (lambda m: _replace(m, e=np.zeros((MAX_SIGNAL_LENGTH + 1, 2)), wf=np.zeros((MAX_SIGNAL_LENGTH + 1, 2))),
     "oversized or empty"),
    (lambda m: _replace(m, T=_sys(m.T, A=np.zeros((MAX_ORDER + 1,) * 2), B=np.zeros((MAX_ORDER + 1, 2)),
                                  C=np.zeros((2, MAX_ORDER + 1)))), "oversized: order of T"),
])
def test_encode_refuses_malformed(bad, match):
    with pytest.raises(MessageError, match=match):
        encode(bad(small_exchange()))


def test_encode_refuses_wrong_shape_B():
    msg = small_exchange(nS=3)
    with pytest.raises(MessageError, match=r"S\.B must have shape \(3, 2\), got \(2, 3\)"):
        encode(_replace(msg, S=_sys(msg.S, B=msg.S.B.T)))


@pytest.mark.skipif(np.dtype(np.longdouble).itemsize <= 8, reason="long double is float64 here")
def test_encode_refuses_precision_loss():
    msg = small_inversion()
    with pytest.raises(MessageError, match="at most float64"):
        encode(_replace(msg, z=msg.z.astype(np.longdouble)))


def test_encode_upcasts_float32_exactly():
    msg = small_inversion()
    z32 = msg.z.astype(np.float32)
    out = decode(encode(_replace(msg, z=z32)))
    assert out.z.dtype == np.float64 and np.array_equal(out.z, z32.astype(np.float64))


@pytest.mark.parametrize("msg", [None, "x", small_exchange().T])
def test_encode_refuses_non_messages(msg):
    with pytest.raises(MessageError, match="message must be an ExchangeMessage or InversionMessage"):
        encode(msg)


def test_static_gain_systems_allowed():
    msg = small_exchange(nT=0, nS=0)
    assert msg.T.order == 0
    out = decode(encode(msg))
    assert_same(out, msg)
    assert len(encode(msg)) == 56 + 8 * (4 + 4 + 4 * 12)


# --- examples -----------------------------------------------------------------------------------

@pytest.mark.parametrize("mechanism", MECHANISMS)
def test_example_message_is_valid_and_reproducible(mechanism):
    msg = example_message(mechanism, rng=7)
    assert msg.mechanism == mechanism
    assert (msg.sample_rate, msg.n_samples) == (200.0, 400)
    if isinstance(msg, ExchangeMessage):
        assert msg.e.shape == msg.wf.shape == (600, 2)
        for sys in (msg.T, msg.S):
            assert np.isclose(np.max(np.abs(sys.poles())), 0.9)
    else:
        assert msg.z.shape == (600, 2)
        assert msg.count == (1 if mechanism == "hardened" else 3)
    assert encode(example_message(mechanism, rng=7)) == encode(msg)
    assert encode(example_message(mechanism, rng=8)) != encode(msg)


def test_example_message_unknown_mechanism():
    with pytest.raises(MessageError, match="mechanism must be one of"):
        example_message("secret")


@pytest.mark.parametrize("mechanism", MECHANISMS)
def test_write_example(tmp_path, mechanism):
    path = tmp_path / f"{mechanism}.rcol"
    n = write_example(path, mechanism=mechanism, seed=4)
    data = path.read_bytes()
    assert n == len(data) and data.startswith(MAGIC)
    assert_same(decode(data), example_message(mechanism, rng=4))


# --- fuzzing ------------------------------------------------------------------------------------

def _decode_only_message_error(data):
    """Decode; return the message or None. Any exception but MessageError fails the test."""
    try:
        return decode(data)
    except MessageError:
        return None


SECAGG = (KeyAdvert, SealedShares, MaskedInput, Reveal)


def _check_decoded(msg, data):
    if isinstance(msg, SECAGG):
        assert msg.mechanism == "secure_aggregation"
        assert encode(msg) == bytes(data)
        return
    for name, arr in arrays_of(msg).items():
        assert np.isfinite(arr).all(), name
    # Whatever decode accepts, encode accepts too, and reproduces the very same bytes.
    assert encode(msg) == bytes(data)


@FUZZ
@given(st.binary(max_size=512))
def test_fuzz_arbitrary_bytes(data):
    msg = _decode_only_message_error(data)
    if msg is not None:
        _check_decoded(msg, data)


@st.composite
def plausible_headers(draw):
    """A well-formed prefix with random fields, then random payload bytes: reaches deep checks."""
    # Mostly valid choices (so that most examples get past the header), sometimes anything.
    msg_type = draw(st.sampled_from([1, 1, 1, 2, 2, 2, 0, 3]))
    consistent = {1: [1, 2], 2: [3, 4]}.get(msg_type, [1])
    mech = draw(st.sampled_from(consistent * 4) | st.integers(0, 5))
    fs = draw(st.sampled_from([FS, FS, FS]) | st.floats(allow_nan=True, allow_infinity=True))
    L = draw(st.integers(1, 8) | st.integers(0, 2**32 - 1))
    n = draw(st.integers(1, max(1, min(L, 8))) | st.integers(0, 2**32 - 1))
    if msg_type == 1:
        nT, nS = draw(st.integers(0, 3)), draw(st.integers(0, 3))
        dt = draw(st.one_of(st.just(1 / fs if fs else 0.0), st.floats()))
        ext = struct.pack("<IIdd", nT, nS, dt, dt)
        floats = (nT + 2) ** 2 + (nS + 2) ** 2 + 4 * L
    else:
        count = 1 if mech == 3 else draw(st.integers(1, 3) | st.integers(0, 2**32 - 1))
        ext = struct.pack("<II", count, draw(st.sampled_from([0, 0, 0, 1])))
        floats = 2 * L
    floats = min(floats, 100)  # huge declared lengths are refused from the header anyway
    nbytes = 8 * floats + draw(st.sampled_from([0, 0, 0, -1, 1, 8]))
    declared = max(0, nbytes + draw(st.sampled_from([0, 0, 0, 8, -8])))
    head = struct.pack("<4sBBBBdIIQ", MAGIC, 1, msg_type, mech, 0, fs, n, L, declared)
    # Payload floats drawn as values (so most are finite and reach the stability check) or raw bytes.
    values = draw(st.lists(st.floats(-2, 2) | st.floats(), min_size=floats, max_size=floats))
    payload = np.asarray(values, "<f8").tobytes()
    if nbytes != len(payload):
        payload = draw(st.binary(min_size=max(0, nbytes), max_size=max(0, nbytes)))
    return head + ext + payload


@FUZZ
@given(plausible_headers())
def test_fuzz_structured_headers(data):
    msg = _decode_only_message_error(data)
    if msg is not None:
        _check_decoded(msg, data)


@st.composite
def plausible_secagg(draw):
    """A secure-aggregation header (types 3-6) with random fields, then a payload of about the right size."""
    msg_type = draw(st.sampled_from([3, 4, 5, 6]))
    mech = draw(st.sampled_from([5, 5, 5, 5, 4, 0, 6]))
    vehicle = draw(st.sampled_from([1, 2, 7]) | st.integers(0, 2**32 - 1))
    small = st.integers(0, 4) | st.integers(0, 2**32 - 1)
    n1 = {3: 0, 4: draw(st.sampled_from([2, 3]) | small), 5: draw(st.integers(1, 4) | small)}.get(msg_type)
    n1 = draw(st.integers(0, 3) | small) if n1 is None else n1
    n2 = draw(st.integers(0, 3) | small) if msg_type == 6 else draw(st.sampled_from([0, 0, 0, 1]))
    size = {3: 64, 4: 156, 5: 16 * n1, 6: 70 * (n1 + n2)}[msg_type]
    size = min(size, 600) + draw(st.sampled_from([0, 0, 0, -1, 1, 70]))
    declared = max(0, size + draw(st.sampled_from([0, 0, 0, 8, -8])))
    head = struct.pack("<4sBBBB16sQIIII", MAGIC, 1, msg_type, mech, 0, draw(st.binary(min_size=16, max_size=16)),
                       declared, vehicle, n1, n2, draw(st.sampled_from([0, 0, 0, 1])))
    if msg_type == 6 and size > 0:
        # Entries drawn as values: owners near each other, shares around the field size 2^521 - 1.
        owners = draw(st.lists(st.integers(0, 6), min_size=n1 + n2, max_size=n1 + n2)) if n1 + n2 <= 8 else []
        shares = st.integers(0, 2**521) | st.integers(0, 2**528 - 1)
        body = b"".join(struct.pack("<I", o) + draw(shares).to_bytes(66, "little") for o in owners)
        if len(body) == size:
            return head + body
    return head + draw(st.binary(min_size=max(0, size), max_size=max(0, size)))


@FUZZ
@given(plausible_secagg())
def test_fuzz_structured_secagg_headers(data):
    msg = _decode_only_message_error(data)
    if msg is not None:
        _check_decoded(msg, data)


def _secagg_valid():
    """One encoded message of each secure-aggregation type (small, fixed content)."""
    keys = bytes(range(32))
    y = np.arange(6, dtype=np.uint64).reshape(3, 2) * np.uint64(0x9E3779B97F4A7C15)
    msgs = [KeyAdvert(2, keys, keys[::-1]), SealedShares(2, 5, bytes(range(156))), MaskedInput(3, y),
            Reveal(4, {1: 5, 4: 2**520}, {2: 0, 6: 2**521 - 2})]
    return [encode(m) for m in msgs]


VALID = [encode(small_exchange(1)), encode(small_exchange(2, mechanism="none", nT=0, nS=3, L=6)),
         encode(small_inversion(3)), encode(small_inversion(4, mechanism="hardened", L=8, count=1))] + _secagg_valid()


@st.composite
def mutated(draw):
    data = bytearray(draw(st.sampled_from(VALID)))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["flip", "set", "truncate", "splice", "insert", "delete"]))
        pos = draw(st.integers(0, max(0, len(data) - 1)))
        if op == "flip" and data:
            data[pos] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and data:
            data[pos] = draw(st.integers(0, 255))
        elif op == "truncate":
            del data[pos:]
        elif op == "splice":
            other = draw(st.sampled_from(VALID))
            cut = draw(st.integers(0, len(other)))
            data = data[:pos] + other[cut:]
        elif op == "insert":
            data[pos:pos] = draw(st.binary(min_size=1, max_size=16))
        elif op == "delete":
            del data[pos:pos + draw(st.integers(1, 16))]
    return bytes(data)


@FUZZ
@given(mutated())
def test_fuzz_mutated_valid_encodings(data):
    msg = _decode_only_message_error(data)
    if msg is not None:
        _check_decoded(msg, data)


def test_messages_validate_at_construction():
    """A message that fails the codec's checks cannot be built, so every message that exists encodes."""
    msg = small_exchange()
    bad_e = msg.e.copy()
    bad_e[3, 1] = np.inf
    with pytest.raises(MessageError, match="e must be finite"):
        ExchangeMessage(msg.mechanism, msg.sample_rate, msg.n_samples, msg.T, msg.S, bad_e, msg.wf)
    with pytest.raises(MessageError, match="discrete-time stable"):
        ExchangeMessage(msg.mechanism, msg.sample_rate, msg.n_samples, _sys(msg.T, A=1.01 * np.eye(msg.T.order)),
                        msg.S, msg.e, msg.wf)
    inv = small_inversion()
    with pytest.raises(MessageError, match="mechanism must be one of"):
        InversionMessage("gossip", inv.sample_rate, inv.n_samples, inv.z, inv.count)
    assert decode(encode(msg)).mechanism == msg.mechanism
