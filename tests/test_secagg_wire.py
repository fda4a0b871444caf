"""Tests of the wire format of the secure-aggregation messages (roadcollab.wire.secagg + protocol)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from roadcollab.errors import MessageError
from roadcollab.privacy.secagg_run import run_secure_aggregation
from roadcollab.privacy.secure_aggregation import SecAggSpec, session_id, unmask
from roadcollab.wire.protocol import MAX_MESSAGE_BYTES, MAX_SIGNAL_LENGTH, MAX_VEHICLES, decode, encode, message_nbytes
from roadcollab.wire.secagg import KeyAdvert, MaskedInput, Reveal, SealedShares

SPEC = SecAggSpec(min_inputs=5, threshold=4)
P = 2 ** 521 - 1
SESSION = session_id(3, 2)


def _inputs(n=7, length=16, seed=0):
    gen = np.random.default_rng(seed)
    return [0.05 * gen.standard_normal((length, 2)) for _ in range(n)]


def _recorded_run(**kw):
    log = []
    run = run_secure_aggregation(_inputs(), SPEC, session=SESSION, rng=1, transport=lambda m: log.append(m) or m, **kw)
    return run, log


RUN, LOG = _recorded_run(dropped_before_masking=(6,))
BY_TYPE = {cls: [m for m in LOG if type(m) is cls] for cls in (KeyAdvert, SealedShares, MaskedInput, Reveal)}
SAMPLES = [BY_TYPE[cls][0] for cls in BY_TYPE]
IDS = ["key_advert", "sealed_shares", "masked_input", "reveal"]


# --- an independent writer of the documented layout (protocol module docstring) -------------------

def raw(msg_type, vehicle, n1=0, n2=0, payload=b"", *, session=SESSION, mech=5, version=1, reserved7=0,
        reserved=0, declared=None):
    head = struct.pack("<4sBBBB16sQIIII", b"RCOL", version, msg_type, mech, reserved7, session,
                       len(payload) if declared is None else declared, vehicle, n1, n2, reserved)
    return head + payload


def raw_of(m):
    if isinstance(m, KeyAdvert):
        return raw(3, m.vehicle, payload=m.c_pk + m.s_pk, session=m.session)
    if isinstance(m, SealedShares):
        return raw(4, m.sender, m.recipient, payload=m.ciphertext, session=m.session)
    if isinstance(m, MaskedInput):
        return raw(5, m.vehicle, m.y.shape[0], payload=m.y.astype("<u8").tobytes(), session=m.session)
    entries = [sorted(m.self_mask_shares.items()), sorted(m.key_shares.items())]
    body = b"".join(struct.pack("<I", o) + y.to_bytes(66, "little") for lst in entries for o, y in lst)
    return raw(6, m.vehicle, len(entries[0]), len(entries[1]), body, session=m.session)


def assert_same(a, b):
    assert type(a) is type(b)
    if isinstance(a, MaskedInput):
        assert (a.vehicle, a.session) == (b.vehicle, b.session)
        assert b.y.dtype == np.uint64 and np.array_equal(a.y, b.y)
    else:
        assert a == b


# --- round trips and layout ------------------------------------------------------------------------

def test_a_session_sends_every_message_type():
    n = len(RUN.inputs)
    assert [len(BY_TYPE[c]) for c in BY_TYPE] == [n, n * (n - 1), n - 1, n - 1]


@pytest.mark.parametrize("msg", LOG, ids=lambda m: type(m).__name__)
def test_round_trip_every_message_of_a_session(msg):
    data = encode(msg)
    # nbytes counts the sender id (or the routing id) that the 48-byte header carries.
    assert len(data) == message_nbytes(msg) == 48 + msg.nbytes - 4
    out = decode(data)
    assert_same(out, msg)
    assert out.mechanism == "secure_aggregation" and out.session == SESSION
    assert encode(out) == data


@pytest.mark.parametrize("msg", SAMPLES, ids=IDS)
def test_encode_matches_documented_layout(msg):
    assert encode(msg) == raw_of(msg)


def test_sizes():
    key, sealed, masked, rev = (encode(m) for m in SAMPLES)
    assert (len(key), len(sealed), len(masked)) == (48 + 64, 48 + 156, 48 + 16 * 16)
    assert len(rev) == 48 + 70 * len(RUN.inputs)     # one share per roster member
    assert MAX_MESSAGE_BYTES >= 48 + 16 * MAX_SIGNAL_LENGTH and MAX_MESSAGE_BYTES >= 48 + 70 * MAX_VEHICLES


def test_decoded_masked_input_is_an_owned_read_only_copy():
    buf = bytearray(encode(SAMPLES[2]))
    out = decode(buf)
    assert out.y.flags.owndata and not out.y.flags.writeable
    before = out.y.copy()
    buf[48:] = bytes(len(buf) - 48)
    assert np.array_equal(out.y, before)


def test_session_over_the_wire_gives_the_same_aggregate():
    kw = dict(dropped_before_masking=(2,), silent_in_unmasking=(5,))
    plain = run_secure_aggregation(_inputs(seed=4), SPEC, session=SESSION, rng=7, **kw)
    wired = run_secure_aggregation(_inputs(seed=4), SPEC, session=SESSION, rng=7, transport=lambda m: decode(encode(m)),
                                   **kw)
    assert wired.result.survivors == plain.result.survivors and wired.result.dropped == (2,)
    assert np.array_equal(wired.result.total, plain.result.total)
    truth = np.mean([z for i, z in enumerate(_inputs(seed=4), 1) if i != 2], axis=0)
    assert np.max(np.abs(wired.average - truth)) <= 0.5 * SPEC.resolution * (1 + 1e-9)


def test_a_transport_that_changes_the_type_is_refused():
    with pytest.raises(MessageError, match="arrived as"):
        run_secure_aggregation(_inputs(), SPEC, rng=1, transport=lambda m: encode(m))


def test_messages_from_another_session_are_refused():
    masked = [MaskedInput(i, y, session=SESSION) for i, y in RUN.view.masked.items()]
    moved = [MaskedInput(m.vehicle, m.y, session=session_id(3, 3)) for m in masked[:1]] + masked[1:]
    assert np.array_equal(unmask(RUN.view.roster, masked, RUN.view.reveals, SPEC, SESSION).total, RUN.result.total)
    with pytest.raises(MessageError, match="MaskedInput of vehicle 1 belongs to another session"):
        unmask(RUN.view.roster, moved, RUN.view.reveals, SPEC, SESSION)


# --- refused corruptions -----------------------------------------------------------------------

@pytest.mark.parametrize("data", [encode(m) for m in SAMPLES], ids=IDS)
def test_every_truncation_refused(data):
    for k in range(len(data)):
        with pytest.raises(MessageError, match="truncated"):
            decode(data[:k])


@pytest.mark.parametrize("data", [encode(m) for m in SAMPLES], ids=IDS)
def test_appended_byte_refused(data):
    with pytest.raises(MessageError, match="trailing data"):
        decode(data + b"\0")


KEY = bytes(range(32))


@pytest.mark.parametrize("make, match", [
    (lambda: KeyAdvert(1, KEY[:31], KEY), "c_pk must be 32 bytes, got 31 bytes"),
    (lambda: KeyAdvert(1, KEY, bytearray(KEY)), "s_pk must be 32 bytes, got bytearray"),
    (lambda: KeyAdvert(0, KEY, KEY), "vehicle must be a positive int"),
    (lambda: KeyAdvert(2 ** 32, KEY, KEY), "vehicle must be a positive int"),
    (lambda: KeyAdvert(True, KEY, KEY), "vehicle must be an integer"),
    (lambda: KeyAdvert(1, KEY, KEY, session=bytes(15)), "session must be 16 bytes"),
    (lambda: SealedShares(1, 2, bytes(155)), "ciphertext must be 156 bytes"),
    (lambda: SealedShares(1, 2, bytes(157)), "ciphertext must be 156 bytes"),
    (lambda: SealedShares(3, 3, bytes(156)), "addressed to itself"),
    (lambda: SealedShares(3, 0, bytes(156)), "recipient must be a positive int"),
    (lambda: MaskedInput(1, np.zeros((4, 2))), "uint64"),
    (lambda: MaskedInput(1, np.zeros((4, 3), np.uint64)), "uint64"),
    (lambda: MaskedInput(1, np.zeros(8, np.uint64)), "uint64"),
    (lambda: MaskedInput(1, np.zeros((0, 2), np.uint64)), "masked input length must be in"),
    (lambda: MaskedInput(1, [[1, 2]]), "uint64"),
    (lambda: Reveal(1), "a reveal must carry 1 to"),
    (lambda: Reveal(1, {2: P}), "outside GF"),
    (lambda: Reveal(1, {2: -1}), "outside GF"),
    (lambda: Reveal(1, {0: 5}), "owner must be a positive int"),
    (lambda: Reveal(1, {2: 5}, {2: 6}), "both shares of owners \\[2\\]"),
    (lambda: Reveal(1, {2: 5.0}), "share must be an integer"),
    (lambda: Reveal(1, [(2, 5)]), "must be a dict"),
    (lambda: Reveal(1, {i: 1 for i in range(1, MAX_VEHICLES + 2)}), "oversized"),
])
def test_construction_refuses_what_the_codec_refuses(make, match):
    with pytest.raises(MessageError, match=match):
        make()


def _entry(owner, share=7):
    return struct.pack("<I", owner) + share.to_bytes(66, "little")


@pytest.mark.parametrize("data, match", [
    (raw(3, 1, payload=KEY + KEY, mech=4), "key_advert message requires mechanism 'secure_aggregation', got 'fused'"),
    (raw(3, 1, payload=KEY + KEY, reserved=1), "reserved secure-aggregation header field must be 0"),
    (raw(3, 1, payload=KEY + KEY, reserved7=1), "reserved header byte 7"),
    (raw(3, 1, n1=1, payload=KEY + KEY), "unused key_advert header fields must be 0"),
    (raw(5, 1, n1=1, n2=1, payload=bytes(16)), "unused masked_input header fields must be 0"),
    (raw(3, 0, payload=KEY + KEY), "vehicle must be a positive int"),
    (raw(3, 1, payload=KEY + KEY[:31] + b"\0\0"), "header declares 65 payload bytes but its dimensions imply 64"),
    (raw(3, 1, payload=KEY + KEY, declared=63), "declares 63 payload bytes"),
    (raw(4, 2, 2, payload=bytes(156)), "addressed to itself"),
    (raw(5, 1, 0, payload=b""), "oversized or empty"),
    (raw(5, 1, MAX_SIGNAL_LENGTH + 1, payload=bytes(16), declared=16 * (MAX_SIGNAL_LENGTH + 1)), "oversized"),
    (raw(5, 1, 2, payload=bytes(16)), "header declares 16 payload bytes but its dimensions imply 32"),
    (raw(6, 1, 0, 0, payload=b""), "a reveal must carry 1 to"),
    (raw(6, 1, MAX_VEHICLES, 1, payload=_entry(1), declared=70 * (MAX_VEHICLES + 1)), "oversized"),
    (raw(6, 1, 2, 0, _entry(3) + _entry(2)), "owner ids must be strictly increasing, got 2 after 3"),
    (raw(6, 1, 2, 0, _entry(3) + _entry(3)), "owner ids must be strictly increasing, got 3 after 3"),
    (raw(6, 1, 1, 1, _entry(3) + _entry(3)), "both shares of owners"),
    (raw(6, 1, 1, 0, _entry(0)), "owner must be a positive int"),
    (raw(6, 1, 0, 1, _entry(2, P)), "outside GF"),
    (raw(6, 1, 0, 1, _entry(2, 2 ** 528 - 1)), "outside GF"),
    (raw(2, 1, payload=bytes(8), mech=5)[:32] + bytes(8) + bytes(16), "'secure_aggregation' requires a secure-aggregation"),
])
def test_decode_refuses_malformed(data, match):
    with pytest.raises(MessageError, match=match):
        decode(data)


def test_largest_valid_masked_input_and_reveal_decode():
    assert decode(raw(6, 1, 0, 1, _entry(2, P - 1))).key_shares == {2: P - 1}
    y = np.full((3, 2), 2 ** 64 - 1, np.uint64)
    assert np.array_equal(decode(raw(5, 2 ** 32 - 1, 3, payload=y.tobytes())).y, y)
