"""Signed envelopes: a payload with the sender's certificate and its Ed25519 signature.

Wire form (big-endian)::

    envelope := "RCENV1" 0x00 | u32 len certificate | certificate | u32 len payload | payload
                | 64-byte signature of the vehicle

The signature covers :data:`ENVELOPE_CONTEXT`, the caller's ``context`` (e.g. the topic and session id;
bound but not sent), the certificate and the payload, each length-prefixed: an envelope replayed into
another topic or session, or re-labelled with another vehicle's certificate, does not verify.
"""

from __future__ import annotations

import struct

from ..errors import MessageError, ParameterError
from .identity import _SIG, Certificate, FleetTrust, VehicleIdentity, _Reader, verify_signature

__all__ = ["ENVELOPE_CONTEXT", "MAX_ENVELOPE_PAYLOAD", "seal_envelope", "open_envelope"]

ENVELOPE_MAGIC = b"RCENV1\x00"
ENVELOPE_CONTEXT = b"roadcollab/envelope/v1\x00"
#: The largest payload an envelope carries (the largest roadcollab message plus headroom).
MAX_ENVELOPE_PAYLOAD = 64 * 1024 * 1024


def _envelope_signed(context: bytes, cert: bytes, payload: bytes) -> bytes:
    return (ENVELOPE_CONTEXT + struct.pack(">I", len(context)) + bytes(context)
            + struct.pack(">I", len(cert)) + cert + struct.pack(">I", len(payload)) + bytes(payload))


def seal_envelope(identity: VehicleIdentity, payload: bytes, context: bytes = b"") -> bytes:
    """``payload`` with the sender's certificate and its signature over ``context`` and both.

    Parameters
    ----------
    identity : VehicleIdentity
    payload : bytes
    context : bytes
        Bound into the signature but not sent (e.g. the topic and session): the receiver must supply the
        same context, so an envelope replayed into another topic or session does not verify.

    Returns
    -------
    bytes
    """
    if len(payload) > MAX_ENVELOPE_PAYLOAD:
        raise ParameterError(f"payload of {len(payload)} bytes exceeds {MAX_ENVELOPE_PAYLOAD}")
    cert = identity.certificate.to_bytes()
    sig = identity.sign(_envelope_signed(context, cert, payload))
    return ENVELOPE_MAGIC + struct.pack(">I", len(cert)) + cert + struct.pack(">I", len(payload)) + bytes(payload) + sig


def open_envelope(data: bytes, trust: FleetTrust, context: bytes = b"") -> tuple[Certificate, bytes]:
    """Check an envelope from :func:`seal_envelope`: the certificate against ``trust``, the signature against it.

    Parameters
    ----------
    data : bytes
        Untrusted.
    trust : FleetTrust
    context : bytes
        What the sender must have bound (see :func:`seal_envelope`).

    Returns
    -------
    certificate : Certificate
        The sender's (checked).
    payload : bytes

    Raises
    ------
    MessageError
        Malformed, oversized, another fleet, revoked, or a bad signature.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise MessageError(f"envelope must be bytes, got {type(data).__name__}")
    r = _Reader(data, "envelope")
    if r.take(len(ENVELOPE_MAGIC)) != ENVELOPE_MAGIC:
        raise MessageError("envelope: wrong magic")
    n_cert = r.u(">I")
    if n_cert > 1024:
        raise MessageError(f"envelope: certificate of {n_cert} bytes")
    cert_bytes = r.take(n_cert)
    n_payload = r.u(">I")
    if n_payload > MAX_ENVELOPE_PAYLOAD:
        raise MessageError(f"envelope: payload of {n_payload} bytes exceeds {MAX_ENVELOPE_PAYLOAD}")
    payload, sig = r.take(n_payload), r.take(_SIG)
    r.end()
    cert = trust.check(Certificate.from_bytes(cert_bytes))
    verify_signature(cert.public_key, _envelope_signed(context, cert_bytes, payload), sig,
                     f"envelope from {cert.vehicle_id!r}")
    return cert, payload
