"""Brokers: the embedded one (``amqtt``, asyncio, from PyPI) and Mosquitto's configuration.

Both are configured from the fleet folder written by :func:`~roadcollab.network.fleetdir.enroll`: no
anonymous clients, the users and hashes of ``broker/``, and the topic ACL of
:func:`~roadcollab.network.fleetdir.acl_rules`. Both listen on 127.0.0.1 unless told otherwise.

``python -m roadcollab.network.brokers --fleet DIR --listen 127.0.0.1:PORT`` runs the embedded broker
on its own (the fault tests kill and restart it); ``roadcollab serve`` runs it in a thread of its own.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import pwd
import signal
import sys
import threading
from pathlib import Path

from ..errors import ParameterError
from .tls import has_tls

__all__ = ["amqtt_config", "EmbeddedBroker", "mosquitto_config", "parse_listen"]


def parse_listen(text: str, option: str = "--listen") -> tuple[str, int]:
    """``HOST:PORT`` as ``(host, port)``; one clear line if malformed.

    Parameters
    ----------
    text : str
        ``HOST:PORT``.
    option : str
        The option named in the message.
    """
    host, _, port = str(text).rpartition(":")
    if not host or not (port.isascii() and port.isdigit()) or not 0 < int(port) < 65536:
        raise ParameterError(f"{option} {text}: expected HOST:PORT with a port in 1..65535 (e.g. 127.0.0.1:1883)")
    return host, int(port)


def amqtt_config(fleet: Path, host: str, port: int) -> dict:
    """The embedded broker's configuration: password file, publish and subscribe ACLs.

    Parameters
    ----------
    fleet : Path
        The fleet folder.
    host, port : str, int
        Where the broker listens.
    """
    fleet = Path(fleet)
    rules = json.loads((fleet / "broker" / "acl.json").read_text())
    listener: dict = {"type": "tcp", "bind": f"{host}:{port}"}
    if has_tls(fleet):        # enroll --tls: TLS only (network/tls.py)
        listener.update(ssl=True, certfile=str(fleet / "broker" / "server.pem"),
                        keyfile=str(fleet / "broker" / "server.key"))
    return {
        "listeners": {"default": listener},
        "plugins": {
            "amqtt.plugins.authentication.FileAuthPlugin": {"password_file": str(fleet / "broker" / "amqtt_passwd")},
            "amqtt.plugins.topic_checking.TopicAccessControlListPlugin": {"publish_acl": rules["publish"],
                                                                           "acl": rules["subscribe"]},
        },
    }


class EmbeddedBroker:
    """The amqtt broker on its own event loop in a daemon thread.

    Parameters
    ----------
    fleet : Path
        The fleet folder.
    host, port : str, int
        Where it listens.
    """

    def __init__(self, fleet: Path, host: str, port: int) -> None:
        self.config = amqtt_config(fleet, host, port)
        self.host, self.port = host, port
        self._loop = asyncio.new_event_loop()
        self._started = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="amqtt", daemon=True)

    def _run(self) -> None:
        from amqtt.broker import Broker

        asyncio.set_event_loop(self._loop)
        try:
            self._broker = Broker(self.config, loop=self._loop)
            self._loop.run_until_complete(self._broker.start())
        except BaseException as err:  # noqa: BLE001 -- reported by start() in the caller's thread
            self._error = err
            self._started.set()
            return
        self._started.set()
        self._loop.run_forever()

    def start(self, timeout: float = 20.0) -> "EmbeddedBroker":
        """Start listening; ParameterError naming the address if it cannot.

        Parameters
        ----------
        timeout : float
            Seconds to wait for the listener.
        """
        self._thread.start()
        if not self._started.wait(timeout) or self._error is not None:
            raise ParameterError(f"--listen {self.host}:{self.port}: the embedded broker did not start "
                                 f"({type(self._error).__name__ if self._error else 'timeout'}: {self._error})")
        return self

    def stop(self, timeout: float = 10.0) -> None:
        if self._error is not None or not self._thread.is_alive():
            return
        fut = asyncio.run_coroutine_threadsafe(self._broker.shutdown(), self._loop)
        try:
            fut.result(timeout)
        except Exception:  # noqa: BLE001 -- stopping anyway
            pass
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(timeout)


def mosquitto_config(fleet: Path, host: str, port: int, data_dir: Path) -> Path:
    """Write ``data_dir/mosquitto.conf`` for the fleet (persistence in ``data_dir``); its path.

    Parameters
    ----------
    fleet : Path
        The fleet folder.
    host, port : str, int
        Where Mosquitto listens.
    data_dir : Path
        Its persistence folder (created), which also gets the config.
    """
    fleet, data_dir = Path(fleet).absolute(), Path(data_dir).absolute()
    data_dir.mkdir(parents=True, exist_ok=True)
    # Mosquitto started as root drops to the ``mosquitto`` user: it gets copies of the password file
    # and ACL (0600) it can read, in a data folder it can write.
    tls = has_tls(fleet)
    names = ("mosquitto_passwd", "mosquitto_acl") + (("server.pem", "server.key") if tls else ())
    for name in names:
        dst = data_dir / name
        dst.write_bytes((fleet / "broker" / name).read_bytes())
        dst.chmod(0o600)
    if os.geteuid() == 0:
        try:
            pw = pwd.getpwnam("mosquitto")
        except KeyError:
            pw = None
        if pw is not None:
            for p in (data_dir, *(data_dir / n for n in names)):
                os.chown(p, pw.pw_uid, pw.pw_gid)
    conf = data_dir / "mosquitto.conf"
    conf.write_text("\n".join([
        f"listener {port} {host}",
        *([f"certfile {data_dir / 'server.pem'}", f"keyfile {data_dir / 'server.key'}", "tls_version tlsv1.2"]
          if tls else []),
        "allow_anonymous false", f"password_file {data_dir / 'mosquitto_passwd'}",
        f"acl_file {data_dir / 'mosquitto_acl'}", "persistence true", f"persistence_location {data_dir}/",
        "autosave_interval 1", "max_queued_messages 100000", "log_dest stderr", "log_type error",
        "log_type warning", ""]))
    return conf


def main(argv=None) -> int:
    """``python -m roadcollab.network.brokers --fleet DIR --listen HOST:PORT``: the embedded broker alone."""
    p = argparse.ArgumentParser(prog="python -m roadcollab.network.brokers")
    p.add_argument("--fleet", required=True)
    p.add_argument("--listen", default="127.0.0.1:1883")
    args = p.parse_args(argv)
    try:
        broker = EmbeddedBroker(Path(args.fleet), *parse_listen(args.listen)).start()
    except (ParameterError, OSError) as err:
        print(f"broker: error: {err}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"broker listening on {args.listen}", flush=True)
    while not stop.wait(0.5):
        pass
    broker.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
