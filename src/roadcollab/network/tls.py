"""TLS for the fleet's broker: a fleet CA, the broker's certificate, and every party's trust in it.

``roadcollab enroll --tls`` (optionally ``--tls-host NAME`` for each name or address the broker is
reached by beyond ``127.0.0.1`` and ``localhost``) writes, with the ``cryptography`` package's X.509
builder (ECDSA P-256, SHA-256)::

    DIR/authority/tls-ca.key   the CA's private key (0600; keep it offline with the authority key)
    DIR/broker/ca.pem          the CA certificate
    DIR/broker/server.pem      the broker's certificate (subjectAltName: 127.0.0.1, localhost, --tls-host)
    DIR/broker/server.key      its private key (0600)
    DIR/vehicles/vK/ca.pem     the CA certificate, named by ``ca_file`` in the folder's broker.toml
    DIR/service/ca.pem         the same, for the service

The embedded broker and Mosquitto's configuration then listen with TLS only (``brokers.py``), and
clients connect with ``mqtts://HOST:PORT`` (default port 8883): the broker's certificate is checked
against the fleet CA and the host name, so the passwords in ``broker.toml`` never cross the network in
the clear and a broker without the fleet's certificate is refused.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from ..errors import ParameterError

__all__ = ["write_fleet_tls", "has_tls", "CA_FILE"]

CA_FILE = "ca.pem"
_DAYS = 3 * 365


def _write(path: Path, data: bytes, secret: bool = False) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600 if secret else 0o644)
    with os.fdopen(fd, "wb") as fh:
        fh.write(data)


def _key_pem(key) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _san(hosts) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for h in ["127.0.0.1", "localhost", *hosts]:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            if not h or any(c.isspace() for c in h) or len(h) > 253:
                raise ParameterError(f"--tls-host {h!r}: expected a host name or an IP address") from None
            names.append(x509.DNSName(h))
    return x509.SubjectAlternativeName(list(dict.fromkeys(names)))


def write_fleet_tls(folder, fleet_id: str, parties: list[Path], hosts=()) -> None:
    """Create the fleet CA and the broker certificate in a new fleet folder (module docstring).

    Parameters
    ----------
    folder : str or Path
        The fleet folder (``authority/`` and ``broker/`` exist; nothing is replaced).
    fleet_id : str
    parties : list of Path
        Folders that get ``ca.pem`` (the vehicles' and the service's).
    hosts : iterable of str
        More names or addresses of the broker.
    """
    folder = Path(folder)
    now = datetime.datetime.now(datetime.timezone.utc)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"roadcollab fleet {fleet_id} CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name).public_key(ca_key.public_key())
          .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(minutes=5))
          .not_valid_after(now + datetime.timedelta(days=_DAYS))
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=False, content_commitment=False, key_encipherment=False,
                                       data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                       crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    key = ec.generate_private_key(ec.SECP256R1())
    cert = (x509.CertificateBuilder()
            .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"roadcollab broker {fleet_id}")]))
            .issuer_name(ca_name).public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5)).not_valid_after(now + datetime.timedelta(days=_DAYS))
            .add_extension(_san(hosts), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(ca_key, hashes.SHA256()))
    ca_pem = ca.public_bytes(serialization.Encoding.PEM)
    _write(folder / "authority" / "tls-ca.key", _key_pem(ca_key), secret=True)
    _write(folder / "broker" / CA_FILE, ca_pem)
    _write(folder / "broker" / "server.pem", cert.public_bytes(serialization.Encoding.PEM) + ca_pem)
    _write(folder / "broker" / "server.key", _key_pem(key), secret=True)
    for p in parties:
        _write(Path(p) / CA_FILE, ca_pem)


def has_tls(fleet) -> bool:
    """True when the fleet folder holds a broker certificate (``enroll --tls``).

    Parameters
    ----------
    fleet : str or Path
        The fleet folder.
    """
    return (Path(fleet) / "broker" / "server.pem").is_file()
