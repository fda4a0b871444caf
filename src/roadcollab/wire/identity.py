"""Fleet identities: an Ed25519 fleet authority, the trust anchor and key files (certificates: :mod:`.certificate`;
signed envelopes: :mod:`.envelope`).

The paper's vehicles exchange messages with no trusted authority for the *data*; a fleet still needs to
know *who* may take part, or a server can invent participants (a Sybil roster) or substitute keys. This
module gives the fleet authority of the networked fleet: it signs one certificate per vehicle binding
the vehicle's id to its Ed25519 public key, and every party checks certificates against the authority's
public key alone. The authority only enrols; it never sees a message.

Wire form (all integers big-endian, every variable field length-prefixed, so no two field lists encode
to the same bytes)::

    certificate := "RCCERT1" 0x00 | u16 len fleet_id | fleet_id | u16 len vehicle_id | vehicle_id
                   | 32-byte Ed25519 public key | u64 issued_s | 64-byte authority signature

Signatures are over a domain-separated byte string (:data:`CERT_CONTEXT`; envelopes have their own), so a signature made for one purpose
does not verify for another. Keys come from the operating system's CSPRNG (``cryptography``), never from
the simulation's seed plan: a seeded key is a known key.

Everything read from outside raises :class:`~roadcollab.errors.MessageError` (a certificate or envelope
from the network) or :class:`~roadcollab.errors.FileFormatError` (a key file).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .._validation import StrPath
from ..errors import FileFormatError, MessageError, ParameterError
from .certificate import _KEY, CERT_CONTEXT, Certificate, _ed25519, check_id, verify_signature

__all__ = ["CERT_CONTEXT", "Certificate", "FleetAuthority", "VehicleIdentity", "FleetTrust", "verify_signature",
           "check_id"]

if TYPE_CHECKING:
    from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

@dataclass(frozen=True)
class FleetTrust:
    """What every party needs to check a certificate: the authority's public key and the revoked ids.

    Attributes
    ----------
    fleet_id : str
    authority_key : bytes
        32-byte raw Ed25519 public key of the fleet authority.
    revoked : frozenset of str
        Vehicle ids whose certificates are no longer accepted.
    """

    fleet_id: str
    authority_key: bytes
    revoked: frozenset[str] = frozenset()

    def check(self, cert: Certificate) -> Certificate:
        """Accept ``cert`` if it is this fleet's, signed by its authority and not revoked.

        Parameters
        ----------
        cert : Certificate

        Returns
        -------
        Certificate
            ``cert``.

        Raises
        ------
        MessageError
            Another fleet, a bad signature or a revoked vehicle.
        """
        if cert.fleet_id != self.fleet_id:
            raise MessageError(f"certificate of fleet {cert.fleet_id!r}, expected {self.fleet_id!r}")
        verify_signature(self.authority_key, cert.signed_bytes(), cert.signature,
                         f"certificate of {cert.vehicle_id!r}")
        if cert.vehicle_id in self.revoked:
            raise MessageError(f"certificate of {cert.vehicle_id!r}: revoked")
        return cert

    def save(self, path: StrPath) -> Path:
        """Write the trust anchor (fleet id, authority public key in hex, revoked ids) as a small TOML file.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        Path
        """
        path = Path(path)
        revoked = ", ".join(f'"{v}"' for v in sorted(self.revoked))
        path.write_text(f'fleet_id = "{self.fleet_id}"\nauthority_key = "{self.authority_key.hex()}"\n'
                        f"revoked = [{revoked}]\n")
        return path

    @classmethod
    def load(cls, path: StrPath) -> "FleetTrust":
        """Read a file written by :meth:`save`; :class:`~roadcollab.errors.FileFormatError` if malformed.

        Parameters
        ----------
        path : str or Path

        Returns
        -------
        FleetTrust
        """
        data = _read_toml(path)
        try:
            fleet = check_id("fleet_id", data["fleet_id"])
            key = bytes.fromhex(data["authority_key"])
            revoked = frozenset(check_id("revoked id", v) for v in data.get("revoked", []))
        except (KeyError, TypeError, ValueError) as err:
            raise FileFormatError(f"{path}: expected fleet_id, authority_key (64 hex digits) and revoked, "
                                  f"({type(err).__name__}: {err})") from None
        if len(key) != _KEY:
            raise FileFormatError(f"{path}: authority_key must be {_KEY} bytes, got {len(key)}")
        return cls(fleet, key, revoked)


def _read_toml(path: StrPath) -> dict[str, Any]:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: not found (expected a regular file)")
    try:
        data: dict[str, Any] = tomllib.loads(path.read_text())
        return data
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise FileFormatError(f"{path}: not valid TOML ({err})") from None


def _write_private(path: Path, data: bytes) -> None:
    """Create ``path`` readable by its owner only (never replacing an existing key)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def _load_private(path: StrPath) -> Ed25519PrivateKey:
    from cryptography.hazmat.primitives import serialization

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{path}: not found (expected a private key file)")
    try:
        key = serialization.load_pem_private_key(path.read_bytes(), password=None)
    except (ValueError, TypeError) as err:
        raise FileFormatError(f"{path}: not a PEM private key ({err})") from None
    ed25519_key: type[Ed25519PrivateKey] = _ed25519().Ed25519PrivateKey
    if not isinstance(key, ed25519_key):
        raise FileFormatError(f"{path}: expected an Ed25519 private key")
    return key


def _pem(key: Ed25519PrivateKey) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _raw_public(key: Ed25519PrivateKey) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.public_key().public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)


class FleetAuthority:
    """The fleet authority: an Ed25519 key that signs vehicle certificates.

    Parameters
    ----------
    fleet_id : str
    private_key : cryptography Ed25519PrivateKey
        Use :meth:`generate` or :meth:`load`.
    """

    def __init__(self, fleet_id: str, private_key: Ed25519PrivateKey) -> None:
        self.fleet_id = check_id("fleet_id", fleet_id)
        self._key = private_key
        self.public_key = _raw_public(private_key)

    @classmethod
    def generate(cls, fleet_id: str) -> "FleetAuthority":
        """A new authority with a fresh key from the OS CSPRNG.

        Parameters
        ----------
        fleet_id : str

        Returns
        -------
        FleetAuthority
        """
        return cls(fleet_id, _ed25519().Ed25519PrivateKey.generate())

    def trust(self, revoked: Iterable[str] = ()) -> FleetTrust:
        """The public trust anchor of this authority.

        Parameters
        ----------
        revoked : iterable of str
            Vehicle ids no longer accepted.

        Returns
        -------
        FleetTrust
        """
        return FleetTrust(self.fleet_id, self.public_key, frozenset(revoked))

    def issue(self, vehicle_id: str, public_key: bytes, *, issued_s: int | None = None) -> Certificate:
        """Sign a certificate binding ``vehicle_id`` to ``public_key``.

        Parameters
        ----------
        vehicle_id : str
        public_key : bytes
            32 raw Ed25519 bytes.
        issued_s : int, optional
            Issue time, s since the epoch (default now).

        Returns
        -------
        Certificate
        """
        check_id("vehicle_id", vehicle_id)
        if len(bytes(public_key)) != _KEY:
            raise ParameterError(f"public_key must be {_KEY} raw Ed25519 bytes, got {len(bytes(public_key))}")
        unsigned = Certificate(self.fleet_id, vehicle_id, bytes(public_key),
                               int(time.time()) if issued_s is None else int(issued_s), b"")
        return Certificate(self.fleet_id, vehicle_id, bytes(public_key), unsigned.issued_s,
                           self._key.sign(unsigned.signed_bytes()))

    def save(self, folder: StrPath) -> Path:
        """Write ``authority.key`` (PEM, mode 0600; an existing key is never replaced) and ``trust.toml``.

        Parameters
        ----------
        folder : str or Path
            Created if absent.

        Returns
        -------
        Path
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        _write_private(folder / "authority.key", _pem(self._key))
        self.trust().save(folder / "trust.toml")
        return folder

    @classmethod
    def load(cls, folder: StrPath) -> "FleetAuthority":
        """Read a folder written by :meth:`save`.

        Parameters
        ----------
        folder : str or Path

        Returns
        -------
        FleetAuthority
        """
        folder = Path(folder)
        trust = FleetTrust.load(folder / "trust.toml")
        auth = cls(trust.fleet_id, _load_private(folder / "authority.key"))
        if auth.public_key != trust.authority_key:
            raise FileFormatError(f"{folder}: authority.key does not match trust.toml")
        return auth


class VehicleIdentity:
    """A vehicle's Ed25519 key and its certificate; signs envelopes.

    Parameters
    ----------
    certificate : Certificate
    private_key : cryptography Ed25519PrivateKey
        Must match ``certificate.public_key``.
    """

    def __init__(self, certificate: Certificate, private_key: Ed25519PrivateKey) -> None:
        if _raw_public(private_key) != certificate.public_key:
            raise ParameterError(f"the private key of {certificate.vehicle_id!r} does not match its certificate")
        self.certificate = certificate
        self._key = private_key

    @property
    def vehicle_id(self) -> str:
        return self.certificate.vehicle_id

    @classmethod
    def enroll(cls, authority: FleetAuthority, vehicle_id: str) -> "VehicleIdentity":
        """A fresh key pair for ``vehicle_id`` with a certificate from ``authority``.

        Parameters
        ----------
        authority : FleetAuthority
        vehicle_id : str

        Returns
        -------
        VehicleIdentity
        """
        key = _ed25519().Ed25519PrivateKey.generate()
        return cls(authority.issue(vehicle_id, _raw_public(key)), key)

    def sign(self, data: bytes) -> bytes:
        """The 64-byte Ed25519 signature of ``data`` (callers add their own domain separation).

        Parameters
        ----------
        data : bytes

        Returns
        -------
        bytes
        """
        return self._key.sign(bytes(data))

    def save(self, folder: StrPath) -> Path:
        """Write ``identity.key`` (PEM, 0600; never replaced) and ``certificate.bin``.

        Parameters
        ----------
        folder : str or Path
            Created if absent.

        Returns
        -------
        Path
        """
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        _write_private(folder / "identity.key", _pem(self._key))
        (folder / "certificate.bin").write_bytes(self.certificate.to_bytes())
        return folder

    @classmethod
    def load(cls, folder: StrPath) -> "VehicleIdentity":
        """Read a folder written by :meth:`save`.

        Parameters
        ----------
        folder : str or Path

        Returns
        -------
        VehicleIdentity
        """
        folder = Path(folder)
        path = folder / "certificate.bin"
        if not path.is_file():
            raise FileFormatError(f"{path}: not found (expected the vehicle's certificate)")
        try:
            cert = Certificate.from_bytes(path.read_bytes())
        except MessageError as err:
            raise FileFormatError(f"{path}: {err}") from None
        try:
            return cls(cert, _load_private(folder / "identity.key"))
        except ParameterError as err:
            raise FileFormatError(f"{folder}: {err}") from None
