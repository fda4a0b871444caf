"""The live map of ``serve --map HOST:PORT``: the road store's content as ``roadcollab map``'s ``map.html``,
served by the standard library's :mod:`http.server` in a thread, redrawn as the store changes.

``GET /`` is the same offline page as ``map.html`` (:func:`roadcollab.geo.webmap.map_html`, Leaflet
bundled) with one more script: every ``poll_s`` seconds it fetches ``GET /data.json`` (the segments and
anomalies GeoJSON of the store, and a version) and, when the version changed, redraws both layers. Each
request opens the store afresh (read only), so whoever writes it (``serve --roads``, ``roadcollab map``)
is seen. Only segments with a geometry (two or more positions) are drawn: a networked fleet enrolled on a
road (:mod:`roadcollab.network.fleetroad`) writes its segments' LineStrings; one without a road (drives
without GPS) writes none, and its segments are not drawn.
"""

from __future__ import annotations

import hashlib
import json
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

from ..errors import ParameterError
from ..geo.export import anomalies_geojson, segments_geojson
from ..geo.webmap import map_html
from ..store import RoadStore

__all__ = ["LiveMap", "POLL_SCRIPT"]

#: Redraws the page's two layers (``segs``, ``marks``, ``drawn`` of map_html's script) from /data.json.
POLL_SCRIPT = """<script>
"use strict";
window.roadcollab.version = %(version)s;
window.roadcollab.polls = 0;
async function rcPoll() {
  try {
    const r = await fetch("data.json", {cache: "no-store"});
    const d = await r.json();
    window.roadcollab.polls += 1;
    if (d.version !== window.roadcollab.version) {
      const first = segs.getLayers().length === 0;
      segs.clearLayers(); marks.clearLayers(); drawn.segments = 0; drawn.anomalies = 0;
      segs.addData(d.segments); marks.addData(d.anomalies);
      window.roadcollab.version = d.version;
      if (first && all.getLayers().length && all.getBounds().isValid()) { map.fitBounds(all.getBounds(), {padding: [20, 20]}); }
    }
  } catch (e) { /* the service stopped or is busy: try again at the next poll */ }
  setTimeout(rcPoll, %(poll_ms)d);
}
setTimeout(rcPoll, %(poll_ms)d);
</script></body>"""


def _content(url) -> dict:
    """``{"segments": fc, "anomalies": fc, "version": str}`` of the store (segments with a geometry)."""
    with RoadStore.open(url) as store:
        segs = [s for s in store.segments() if s.lonlat.ndim == 2 and len(s.lonlat) >= 2]
        anoms = [a for a in store.anomalies() if not (a.lon == 0.0 and a.lat == 0.0)]
    data: dict = {"segments": segments_geojson(segs), "anomalies": anomalies_geojson(anoms)}
    data["version"] = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:16]
    return data


class LiveMap:
    """The live map's HTTP server (a daemon thread); :meth:`start`, :meth:`stop`.

    Parameters
    ----------
    roads_url : str or Path
        The road store (an SQLite file or a PostgreSQL URL).
    host : str
        Listening address (``127.0.0.1`` for loopback only).
    port : int
        0: any free port (see :attr:`port` after :meth:`start`).
    poll_s : float
        How often the page asks for new data, s.
    """

    def __init__(self, roads_url, host: str = "127.0.0.1", port: int = 0, *, poll_s: float = 2.0) -> None:
        self.roads_url, self.host, self.port, self.poll_s = roads_url, host, int(port), float(poll_s)
        self._server: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None

    @property
    def url(self) -> str:
        """``http://HOST:PORT/``."""
        return f"http://{self.host}:{self.port}/"

    def page(self) -> bytes:
        """The HTML page with the store's content now and the polling script."""
        data = _content(self.roads_url)
        html = map_html(data["segments"], data["anomalies"], title="roadcollab road condition (live)")
        script = POLL_SCRIPT % {"version": json.dumps(data["version"]), "poll_ms": int(self.poll_s * 1000)}
        return html.replace("</body>", script, 1).encode("utf-8")

    def start(self) -> "LiveMap":
        """Listen and serve in a thread.

        Raises
        ------
        ParameterError
            The address cannot be bound.
        """
        live = self

        class Handler(BaseHTTPRequestHandler):
            def do_GET(self):  # noqa: N802 (http.server's name)
                path = self.path.split("?", 1)[0]
                try:
                    if path in ("/", "/map.html"):
                        body, kind = live.page(), "text/html; charset=utf-8"
                    elif path == "/data.json":
                        body, kind = json.dumps(_content(live.roads_url)).encode(), "application/json"
                    else:
                        self.send_error(404)
                        return
                except Exception as err:   # a store being created or locked: the page retries
                    self.send_error(503, str(err).splitlines()[0][:200])
                    return
                self.send_response(200)
                self.send_header("Content-Type", kind)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, format, *args):  # noqa: A002 (http.server's signature)
                pass

        try:
            self._server = ThreadingHTTPServer((self.host, self.port), Handler)
        except OSError as err:
            raise ParameterError(f"--map {self.host}:{self.port}: cannot listen there ({err.strerror})") from None
        self._server.daemon_threads = True
        self.port = int(self._server.server_address[1])
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="roadcollab-livemap", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving and close the socket."""
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
