"""The MQTT transport: a paho-mqtt 2.x client with QoS 1, a persistent session and reconnection.

* QoS 1 for every publish and subscription; ``clean_session=False`` with a fixed client id, so the
  broker keeps the subscriptions and queues messages while a client is away (a restarted broker with
  persistence, or Mosquitto, delivers them on reconnect).
* Reconnection is paho's own loop with exponential backoff (0.1 s doubling to 5 s); every
  (re)connection re-subscribes and calls ``on_connect`` (the service then republishes its retained
  waiting messages, which the embedded broker keeps in memory only).
* A broker that refuses the login is reported once, as a :class:`~roadcollab.errors.ParameterError`
  naming the broker and the user.
"""

from __future__ import annotations

import queue
import ssl
import threading
import time
from urllib.parse import urlsplit

from ..errors import ParameterError

__all__ = ["parse_broker_url", "MqttClient"]


def parse_broker_url(url: str) -> tuple[str, int]:
    """``mqtt://HOST:PORT`` or ``mqtts://HOST:PORT`` (TLS) as ``(host, port)`` (default port 1883 / 8883).

    Parameters
    ----------
    url : str
        ``mqtt://HOST:PORT`` or ``mqtts://HOST:PORT``.
    """
    try:
        u = urlsplit(str(url))
        port = u.port or (8883 if u.scheme == "mqtts" else 1883)
    except ValueError as err:
        raise ParameterError(f"--broker {url}: expected mqtt://HOST:PORT or mqtts://HOST:PORT ({err})") from None
    if u.scheme not in ("mqtt", "mqtts") or not u.hostname or u.path not in ("", "/"):
        raise ParameterError(f"--broker {url}: expected mqtt://HOST:PORT or mqtts://HOST:PORT (TLS; e.g. "
                             "mqtt://127.0.0.1:1883)")
    return u.hostname, port


class MqttClient:
    """A :class:`~roadcollab.network.transport.Transport` over MQTT.

    Parameters
    ----------
    url : str
        ``mqtt://HOST:PORT``, or ``mqtts://HOST:PORT``: TLS, the broker's certificate checked against
        ``login.ca_file`` and the host name.
    login : Login
        Username and password (and the fleet CA for ``mqtts``).
    client_id : str
        Fixed per party (the persistent session is keyed by it).
    on_connect : callable, optional
        Called (in paho's thread) after every successful (re)connection.
    """

    def __init__(self, url: str, login, client_id: str, *, on_connect=None) -> None:
        import paho.mqtt.client as mqtt

        self.host, self.port = parse_broker_url(url)
        self.url, self.login = url, login
        self.inbox: queue.Queue = queue.Queue()
        self.filters: list[str] = []
        self.connected = threading.Event()
        self.refused: str | None = None
        self.connections = 0
        self.bytes_out = self.bytes_in = 0
        self._user_on_connect = on_connect
        self._c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=False,
                              protocol=mqtt.MQTTv311)
        self._c.username_pw_set(login.username, login.password)
        if str(url).startswith("mqtts://"):
            if getattr(login, "ca_file", None) is None:
                raise ParameterError(f"--broker {url}: TLS needs the fleet CA (ca_file in broker.toml, written by "
                                     "'roadcollab enroll --tls')")
            # CERT_REQUIRED and the host-name check: a broker without the fleet's certificate is refused.
            self._c.tls_set(ca_certs=str(login.ca_file), cert_reqs=ssl.CERT_REQUIRED,
                            tls_version=ssl.PROTOCOL_TLS_CLIENT)
        # paho annotates the delays as int but uses them as seconds in float arithmetic (a 0.1 s first retry)
        self._c.reconnect_delay_set(min_delay=0.1, max_delay=5)  # type: ignore[arg-type]
        self._c.max_inflight_messages_set(100)
        self._c.on_connect = self._on_connect
        self._c.on_disconnect = self._on_disconnect
        self._c.on_message = self._on_message

    def _on_connect(self, client, userdata, flags, reason_code, properties) -> None:
        if reason_code.is_failure:
            self.refused = str(reason_code)
            return
        self.connections += 1
        for f in self.filters:
            client.subscribe(f, qos=1)
        self.connected.set()
        if self._user_on_connect is not None:
            self._user_on_connect()

    def _on_disconnect(self, client, userdata, flags, reason_code, properties) -> None:
        self.connected.clear()

    def _on_message(self, client, userdata, msg) -> None:
        self.bytes_in += len(msg.topic) + len(msg.payload)
        self.inbox.put((msg.topic, bytes(msg.payload)))

    def connect(self, timeout: float = 30.0) -> "MqttClient":
        """Connect (retrying with backoff until ``timeout``); ParameterError if refused or unreachable.

        Parameters
        ----------
        timeout : float
            Seconds.
        """
        self._c.connect_async(self.host, self.port, keepalive=10)
        self._c.loop_start()
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.connected.wait(0.1):
                return self
            if self.refused:
                self.close()
                raise ParameterError(f"--broker {self.url}: the broker refused user {self.login.username!r} "
                                     f"({self.refused})")
        self.close()
        hint = " (TLS: does the broker hold the fleet's certificate for this host name?)" \
            if str(self.url).startswith("mqtts://") else ""
        raise ParameterError(f"--broker {self.url}: no connection within {timeout:g} s{hint}")

    def subscribe(self, topic_filter: str) -> None:
        self.filters.append(topic_filter)
        if self.connected.is_set():
            self._c.subscribe(topic_filter, qos=1)

    def publish(self, topic: str, payload: bytes, retain: bool = False) -> None:
        self.bytes_out += len(topic) + len(payload)
        self._c.publish(topic, payload, qos=1, retain=retain)   # queued by paho while disconnected

    def receive(self, timeout: float) -> tuple[str, bytes] | None:
        try:
            return self.inbox.get(timeout=timeout)
        except queue.Empty:
            return None

    def close(self) -> None:
        try:
            self._c.disconnect()
        finally:
            self._c.loop_stop()
