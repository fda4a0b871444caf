"""Fleet identities (wire/identity.py): certificates, trust, signed envelopes, key files."""

import os
import stat

import pytest

from roadcollab.errors import FileFormatError, MessageError, ParameterError
from roadcollab.wire.envelope import open_envelope, seal_envelope
from roadcollab.wire.identity import Certificate, FleetAuthority, FleetTrust, VehicleIdentity, check_id


@pytest.fixture(scope="module")
def fleet():
    auth = FleetAuthority.generate("fleet-a")
    return auth, [VehicleIdentity.enroll(auth, f"v{i}") for i in range(1, 4)]


def test_certificate_roundtrip_and_check(fleet):
    auth, vs = fleet
    cert = vs[0].certificate
    back = Certificate.from_bytes(cert.to_bytes())
    assert back == cert
    assert auth.trust().check(back) is back


def test_certificate_rejects_every_tampered_byte(fleet):
    auth, vs = fleet
    raw = vs[1].certificate.to_bytes()
    trust = auth.trust()
    for i in range(len(raw)):
        bad = bytearray(raw)
        bad[i] ^= 0x01
        with pytest.raises(MessageError):
            trust.check(Certificate.from_bytes(bytes(bad)))


def test_other_authority_and_revocation(fleet):
    auth, vs = fleet
    other = FleetAuthority.generate("fleet-a")  # same name, another key: a forged authority
    with pytest.raises(MessageError, match="bad signature"):
        other.trust().check(vs[0].certificate)
    with pytest.raises(MessageError, match="revoked"):
        auth.trust(revoked={"v1"}).check(vs[0].certificate)
    with pytest.raises(MessageError, match="fleet"):
        FleetTrust("fleet-b", auth.public_key).check(vs[0].certificate)


def test_envelope_binds_payload_sender_and_context(fleet):
    auth, vs = fleet
    trust = auth.trust()
    env = seal_envelope(vs[0], b"payload", b"topic/seg1")
    cert, payload = open_envelope(env, trust, b"topic/seg1")
    assert (cert.vehicle_id, payload) == ("v1", b"payload")
    with pytest.raises(MessageError):  # replayed into another context
        open_envelope(env, trust, b"topic/seg2")
    for i in range(len(env)):
        bad = bytearray(env)
        bad[i] ^= 0x80
        with pytest.raises(MessageError):
            open_envelope(bytes(bad), trust, b"topic/seg1")
    for n in range(len(env)):  # every truncation
        with pytest.raises(MessageError):
            open_envelope(env[:n], trust, b"topic/seg1")


def test_envelope_with_swapped_certificate_is_refused(fleet):
    """v2 signs, but the envelope carries v1's certificate: the claim to be v1 fails."""
    auth, vs = fleet
    env = seal_envelope(vs[1], b"x")
    c1, c2 = vs[0].certificate.to_bytes(), vs[1].certificate.to_bytes()
    assert len(c1) == len(c2)
    with pytest.raises(MessageError, match="bad signature"):
        open_envelope(env.replace(c2, c1), auth.trust())


def test_key_files_roundtrip_private_and_never_replaced(tmp_path, fleet):
    auth, vs = fleet
    auth.save(tmp_path / "authority")
    vs[2].save(tmp_path / "v3")
    assert stat.S_IMODE(os.stat(tmp_path / "v3" / "identity.key").st_mode) == 0o600
    back = VehicleIdentity.load(tmp_path / "v3")
    assert back.certificate == vs[2].certificate
    assert FleetAuthority.load(tmp_path / "authority").public_key == auth.public_key
    assert FleetTrust.load(tmp_path / "authority" / "trust.toml") == auth.trust()
    with pytest.raises(FileExistsError):
        vs[2].save(tmp_path / "v3")
    (tmp_path / "bad.toml").write_text("fleet_id = 3\n")
    with pytest.raises(FileFormatError, match="bad.toml"):
        FleetTrust.load(tmp_path / "bad.toml")


@pytest.mark.parametrize("bad", ["", ".", "..", "a/b", "x" * 65, "v#1", "é"])
def test_ids_are_safe_in_topics_and_paths(bad):
    with pytest.raises(ParameterError):
        check_id("vehicle_id", bad)
