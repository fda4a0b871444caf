"""A fleet folder: the authority, one identity and broker login per vehicle, the broker's users and ACLs.

Layout written by :func:`enroll` (``roadcollab enroll``)::

    DIR/fleet.toml                    [plan] of the fleet (RoadPlan), [aggregation] (AggregationPolicy)
    DIR/authority/authority.key       Ed25519 authority key (0600) and trust.toml (the trust anchor)
    DIR/vehicles/vK/                  identity.key (0600), certificate.bin, trust.toml, broker.toml,
                                      relay.key (0600, the fleet's relay key: secure aggregation)
    DIR/service/broker.toml           the service's broker login
    DIR/service/identity.key, certificate.bin, x25519.key
                                      validated aggregation: the service as the leading aggregator ``aggregator-a``
    DIR/helper/, DIR/helper-c/        validated aggregation: the helpers ``aggregator-b`` and ``aggregator-c``
                                      (identity, x25519.key, trust.toml, broker.toml, fleet.toml), to hand to
                                      their operators (``helper/`` only with ``aggregators = 2``)
    DIR/broker/amqtt_passwd           user:argon2 hash (the embedded broker)
    DIR/broker/mosquitto_passwd       user:$7$ PBKDF2-SHA512 hash (Mosquitto's own format)
    DIR/broker/mosquitto_acl          Mosquitto ACL
    DIR/broker/acl.json               the same rules for the embedded broker

``broker.toml`` holds ``username`` and ``password`` (mode 0600), so any MQTT client can act as that
vehicle. ACL: vehicle ``vK`` may publish only under ``rc/F/v/vK/`` and on its own round topics
``rc/F/secagg/+/+/+/vK``, and read only ``rc/F/ack/vK``, the waiting messages and the round messages
addressed to it (``rc/F/secagg/+/+/to/vK``); the service reads every vehicle topic and writes acks,
waiting messages and round messages.
"""

from __future__ import annotations

import base64
import hashlib
import json
import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from ..errors import FileFormatError, ParameterError
from ..wire.identity import FleetAuthority, FleetTrust, VehicleIdentity, _read_toml, check_id
from .aggregation import HELPER_IDS, AggregationPolicy
from .plan import RoadPlan
from .prioround import PrioParams
from .relaykey import RelayKey
from .tls import CA_FILE, write_fleet_tls

__all__ = ["Login", "enroll", "load_plan", "load_aggregation", "load_login", "load_trust", "acl_rules",
           "write_broker", "SERVICE_USER", "HELPER_FOLDERS"]

SERVICE_USER = "service"
#: The folder of each helper in a fleet folder.
HELPER_FOLDERS = {"aggregator-b": "helper", "aggregator-c": "helper-c"}


@dataclass(frozen=True)
class Login:
    """An MQTT login: ``username``, ``password``, and the CA file that the broker's TLS certificate must
    chain to (``mqtts://`` brokers; None without TLS)."""

    username: str
    password: str
    ca_file: Path | None = None


def _write_secret(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(text)


def _mosquitto_hash(password: str) -> str:
    """Mosquitto 2's password-file hash ``$7$101$salt$hash`` (PBKDF2-HMAC-SHA512, 101 rounds, 12-byte salt)."""
    salt = secrets.token_bytes(12)
    dk = hashlib.pbkdf2_hmac("sha512", password.encode(), salt, 101, 64)
    return f"$7$101${base64.b64encode(salt).decode()}${base64.b64encode(dk).decode()}"


def _argon2_hash(password: str) -> str:
    from pwdlib.hashers.argon2 import Argon2Hasher   # amqtt's own hasher (a dependency of amqtt)

    # Light parameters (8 MiB, one pass): a login is a random 24-byte token, not a human password, and
    # the broker verifies one hash per connection (the defaults take 0.6 s each on this machine).
    return Argon2Hasher(time_cost=1, memory_cost=8192, parallelism=1).hash(password)


def acl_rules(fleet_id: str, vehicles: list[str], helpers=(), leader: str = "aggregator-a") -> dict:
    """``{"publish": {user: [filters]}, "subscribe": {user: [filters]}}`` of the fleet (module docstring).

    Parameters
    ----------
    fleet_id : str
    vehicles : list of str
        Vehicle ids.
    helpers : sequence of str
        The users of the helper aggregators (validated sessions, :mod:`roadcollab.network.prioround`): each
        publishes its messages and key advert and reads the other aggregators' messages, the uploads
        forwarded to it and the key adverts; the service and the vehicles get the session topics of their
        roles. A helper's user name is its certificate id.
    leader : str
        The certificate id of the service as the leading aggregator (where it advertises its key).
    """
    root = f"rc/{fleet_id}"
    pub = {SERVICE_USER: [f"{root}/ack/#", f"{root}/seg/#", f"{root}/secagg/+/+/to/+"]}
    sub = {SERVICE_USER: [f"{root}/#", f"$share/{fleet_id}/{root}/#"]}
    for v in vehicles:
        pub[v] = [f"{root}/v/{v}/#", f"{root}/secagg/+/+/+/{v}"]
        sub[v] = [f"{root}/ack/{v}", f"{root}/seg/+/waiting", f"{root}/secagg/+/+/to/{v}"]
    if helpers:
        prio = f"{root}/prio"
        pub[SERVICE_USER] += [f"{prio}/+/+/to/+", f"{prio}/+/+/agg/{leader}", f"{prio}/+/+/fwd/+", f"{prio}/key/{leader}"]
        for helper in helpers:
            pub[helper] = [f"{prio}/+/+/agg/{helper}", f"{prio}/key/{helper}"]
            sub[helper] = [f"{prio}/+/+/agg/+", f"{prio}/+/+/fwd/{helper}", f"{prio}/key/+"]
        for v in vehicles:
            pub[v].append(f"{prio}/+/+/up/{v}")
            sub[v] += [f"{prio}/+/+/to/{v}", f"{prio}/key/+"]
    return {"publish": pub, "subscribe": sub}


def write_broker(folder: Path, logins: dict[str, str], rules: dict) -> Path:
    """Write a broker folder: password files for the embedded broker and Mosquitto, the ACL (both forms).

    Parameters
    ----------
    folder : Path
        Created; must not exist (nothing is replaced).
    logins : dict
        User to password.
    rules : dict
        From :func:`acl_rules`.

    Returns
    -------
    Path
    """
    folder = Path(folder)
    folder.mkdir()
    _write_secret(folder / "amqtt_passwd", "".join(f"{u}:{_argon2_hash(p)}\n" for u, p in logins.items()))
    _write_secret(folder / "mosquitto_passwd", "".join(f"{u}:{_mosquitto_hash(p)}\n" for u, p in logins.items()))
    (folder / "acl.json").write_text(json.dumps(rules, indent=1))
    (folder / "mosquitto_acl").write_text(_mosquitto_acl(rules))
    return folder


def _mosquitto_acl(rules: dict) -> str:
    lines = []
    for user in rules["publish"]:
        lines.append(f"user {user}")
        lines += [f"topic write {t}" for t in rules["publish"][user]]
        lines += [f"topic read {t}" for t in rules["subscribe"][user] if not t.startswith("$share")]
        lines.append("")
    return "\n".join(lines)


def enroll(folder, n_vehicles: int, plan: RoadPlan, aggregation: AggregationPolicy | None = None, *,
           tls_hosts=None) -> list[str]:
    """Create a fleet folder (module docstring) with vehicles ``v1..vN``.

    Parameters
    ----------
    folder : str or Path
        Must not hold a fleet yet (nothing is ever replaced).
    n_vehicles : int
        1..10000.
    plan : RoadPlan
    aggregation : AggregationPolicy, optional
        Default: in the clear.
    tls_hosts : list of str, optional
        Given: the broker listens with TLS (:mod:`roadcollab.network.tls`); the names or addresses it is
        reached by beyond 127.0.0.1 and localhost. None: no TLS.

    Returns
    -------
    list of str
        The vehicle ids.

    Raises
    ------
    ParameterError
        A folder that already holds a fleet, or a bad count.
    """
    folder = Path(folder)
    if isinstance(n_vehicles, bool) or not isinstance(n_vehicles, int) or not 1 <= n_vehicles <= 10000:
        raise ParameterError(f"--vehicles must be an integer in 1..10000, got {n_vehicles!r}")
    if (folder / "fleet.toml").exists() or (folder / "authority").exists():
        raise ParameterError(f"--fleet {folder}: already holds a fleet (enroll never replaces one)")
    if folder.exists() and not folder.is_dir():
        raise ParameterError(f"--fleet {folder}: expected a folder, got a file")
    if folder.is_dir() and any(folder.iterdir()):  # never write among files that are not ours
        raise ParameterError(f"--fleet {folder}: the folder is not empty; enroll creates a fleet in a new or empty "
                             "folder")
    folder.mkdir(parents=True, exist_ok=True)
    auth = FleetAuthority.generate(plan.fleet_id)
    auth.save(folder / "authority")
    aggregation = AggregationPolicy() if aggregation is None else aggregation
    if not isinstance(aggregation, AggregationPolicy):
        raise ParameterError("aggregation must be an AggregationPolicy")
    lines = "\n".join(f"{k} = {json.dumps(v)}" for k, v in plan.to_dict().items())
    agg = "\n".join(f"{k} = {json.dumps(v)}" for k, v in aggregation.to_dict().items())
    (folder / "fleet.toml").write_text(f"[plan]\n{lines}\n\n[aggregation]\n{agg}\n")
    ids = [f"v{k}" for k in range(1, n_vehicles + 1)]
    logins = {SERVICE_USER: secrets.token_urlsafe(24)}
    (folder / "service").mkdir()
    relay = RelayKey.generate() if aggregation.secure else None
    for v in ids:
        logins[v] = secrets.token_urlsafe(24)
        d = folder / "vehicles" / v
        VehicleIdentity.enroll(auth, v).save(d)
        auth.trust().save(d / "trust.toml")
        if relay is not None:     # every vehicle, never the service (network/relaykey.py)
            relay.save(d / "relay.key")
    for user, pw in logins.items():
        d = folder / ("service" if user == SERVICE_USER else f"vehicles/{user}")
        ca = f'ca_file = "{CA_FILE}"\n' if tls_hosts is not None else ""
        _write_secret(d / "broker.toml", f'username = "{user}"\npassword = "{pw}"\n{ca}')
    helpers = _write_aggregators(folder, auth, aggregation.aggregators) if aggregation.validated else []
    for helper in helpers:
        logins[helper] = secrets.token_urlsafe(24)
        ca = f'ca_file = "{CA_FILE}"\n' if tls_hosts is not None else ""
        _write_secret(folder / HELPER_FOLDERS[helper] / "broker.toml",
                      f'username = "{helper}"\npassword = "{logins[helper]}"\n{ca}')
    write_broker(folder / "broker", logins, acl_rules(plan.fleet_id, ids, helpers=helpers))
    if tls_hosts is not None:
        parties = [folder / "service"] + [folder / "vehicles" / v for v in ids] + \
            [folder / HELPER_FOLDERS[h] for h in helpers]
        write_fleet_tls(folder, plan.fleet_id, parties, tls_hosts)
    return ids


def _write_aggregators(folder: Path, auth: FleetAuthority, count: int) -> list[str]:
    """The aggregators of validated aggregation: the service's identity and X25519 key in ``service/``,
    each helper's folder (:data:`HELPER_FOLDERS`, with a copy of ``fleet.toml``); the helpers' user names."""
    VehicleIdentity.enroll(auth, PrioParams.leader_id).save(folder / "service")     # the parameters' default id
    RelayKey.generate().save(folder / "service" / "x25519.key")
    helpers = list(HELPER_IDS[:count - 1])
    for helper in helpers:
        d = folder / HELPER_FOLDERS[helper]
        VehicleIdentity.enroll(auth, helper).save(d)
        RelayKey.generate().save(d / "x25519.key")
        auth.trust().save(d / "trust.toml")
        (d / "fleet.toml").write_text((folder / "fleet.toml").read_text())
    return helpers


def _fleet_toml(folder) -> tuple[Path, dict]:
    """``(path, table)`` of ``folder/fleet.toml``; one line naming the folder if there is none."""
    path = Path(folder) / "fleet.toml"
    if not path.is_file():
        raise ParameterError(f"--fleet {folder}: no fleet.toml (create the fleet with 'roadcollab enroll')")
    return path, _read_toml(path)


def load_plan(folder) -> RoadPlan:
    """The [plan] of ``folder/fleet.toml``.

    Parameters
    ----------
    folder : str or Path
        The fleet folder.
    """
    path, data = _fleet_toml(folder)
    return RoadPlan.from_dict(data.get("plan"), str(path))


def load_aggregation(folder) -> AggregationPolicy:
    """The [aggregation] of ``folder/fleet.toml`` (in the clear when the table is absent: older fleets).

    Parameters
    ----------
    folder : str or Path
        The fleet folder.
    """
    path, data = _fleet_toml(folder)
    table = data.get("aggregation")
    return AggregationPolicy() if table is None else AggregationPolicy.from_dict(table, str(path))


def load_trust(folder) -> FleetTrust:
    """The fleet's trust anchor ``folder/authority/trust.toml``.

    Parameters
    ----------
    folder : str or Path
        The fleet folder.

    Returns
    -------
    FleetTrust
    """
    return FleetTrust.load(Path(folder) / "authority" / "trust.toml")


def load_login(path) -> Login:
    """``username`` and ``password`` of a ``broker.toml``.

    Parameters
    ----------
    path : str or Path
        A ``broker.toml``.
    """
    data = _read_toml(path)
    try:
        ca = data.get("ca_file")
        login = Login(check_id("username", data["username"]), str(data["password"]),
                      None if ca is None else Path(path).parent / str(ca))
    except (KeyError, ParameterError) as err:
        raise FileFormatError(f"{path}: expected username and password ({err})") from None
    if login.ca_file is not None and not login.ca_file.is_file():
        raise FileFormatError(f"{path}: ca_file {login.ca_file} not found (the fleet CA that 'enroll --tls' writes)")
    return login
