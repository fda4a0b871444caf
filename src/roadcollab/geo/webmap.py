"""The web map: ``map.html``, one self-contained file that works offline.

Leaflet 1.9.4 (BSD-2-Clause, ``roadcollab/data/leaflet/``, from the npm registry's ``leaflet``
package) is inlined into the page with its stylesheet, so the page needs no network and no
files beside it. Segments are polylines coloured by IRI (:data:`IRI_CLASSES`, with a legend);
anomalies are circle markers (potholes red, bumps blue) whose popup gives kind, depth and votes; a
click on a segment shows its numbers. An online tile layer is added only when the command is given
``--tiles URL`` (off by default: the page then draws on a plain background).

The drawn features carry the CSS classes ``rc-segment`` and ``rc-anomaly`` (Leaflet puts a
layer's ``className`` on its SVG path), which is how the browser test counts them.
"""

from __future__ import annotations

import html
import json
from importlib import resources
from pathlib import Path

__all__ = ["IRI_CLASSES", "leaflet_files", "map_html", "write_map"]

#: (upper bound m/km, colour, label): IRI classes for the legend (the World Bank's ranges for paved
#: roads: below 2 new or very good, 2-4 good, 4-6 fair, 6-10 poor, above 10 very poor).
IRI_CLASSES = ((2.0, "#1a9850", "< 2 very good"), (4.0, "#91cf60", "2-4 good"), (6.0, "#fee08b", "4-6 fair"),
               (10.0, "#fc8d59", "6-10 poor"), (float("inf"), "#d73027", "> 10 very poor"))

_PAGE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>{leaflet_css}</style>
<style>
html, body, #map {{ height: 100%; margin: 0; }}
#map {{ background: #f2efe9; }}
.rc-legend {{ background: white; padding: 6px 10px; font: 13px/1.4 sans-serif; border-radius: 4px;
             box-shadow: 0 0 6px rgba(0,0,0,.3); }}
.rc-legend i {{ display: inline-block; width: 18px; height: 10px; margin-right: 6px; }}
</style></head>
<body><div id="map"></div>
<script>{leaflet_js}</script>
<script type="application/json" id="rc-data">{data}</script>
<script>
"use strict";
const data = JSON.parse(document.getElementById("rc-data").textContent);
const classes = data.classes;
function colour(iri) {{ for (const c of classes) {{ if (iri < c[0]) return c[1]; }} return classes[classes.length - 1][1]; }}
const map = L.map("map", {{preferCanvas: false}});
if (data.tiles) {{ L.tileLayer(data.tiles, {{maxZoom: 19, attribution: data.attribution}}).addTo(map); }}
const drawn = {{segments: 0, anomalies: 0}};
const esc = s => String(s).replace(/[&<>"']/g, c => ({{"&": "&amp;", "<": "&lt;", ">": "&gt;", '"': "&quot;", "'": "&#39;"}})[c]);
const fmt = (v, d) => (v === null || v === undefined) ? "n/a" : Number(v).toFixed(d);
const segs = L.geoJSON(data.segments, {{
  style: f => ({{color: colour(f.properties.iri_m_per_km), weight: 7, opacity: 0.9, className: "rc-segment"}}),
  onEachFeature: (f, layer) => {{
    const p = f.properties; drawn.segments += 1;
    layer.bindPopup(`<b>${{esc(p.road_id)}}</b> ${{p.direction > 0 ? "forward" : "backward"}}, ${{fmt(p.from_m, 0)}}-${{fmt(p.to_m, 0)}} m<br>` +
      `IRI ${{fmt(p.iri_m_per_km, 2)}} m/km (${{fmt(p.iri_in_per_mi, 0)}} in/mi)<br>` +
      `95 % interval ${{fmt(p.iri_low, 2)}}-${{fmt(p.iri_high, 2)}} m/km<br>` +
      `${{p.n_vehicles}} vehicle(s), updated ${{esc(p.last_update)}}`);
  }}}}).addTo(map);
const marks = L.geoJSON(data.anomalies, {{
  pointToLayer: (f, ll) => L.circleMarker(ll, {{radius: 7, color: "#222", weight: 1, fillOpacity: 0.9,
    fillColor: f.properties.kind === "pothole" ? "#b2182b" : "#2166ac", className: "rc-anomaly"}}),
  onEachFeature: (f, layer) => {{
    const p = f.properties; drawn.anomalies += 1;
    layer.bindPopup(`<b>${{esc(p.kind)}}</b> (${{esc(p.side)}}), depth ${{fmt(100 * p.depth_m, 1)}} cm<br>` +
      `${{p.votes}} vote(s); road ${{esc(p.road_id)}} at ${{fmt(p.measure_m, 1)}} m<br>` +
      `${{fmt(p.lat, 6)}}, ${{fmt(p.lon, 6)}}; last seen ${{esc(p.last_seen)}}`);
  }}}}).addTo(map);
const all = L.featureGroup([segs, marks]);
if (all.getLayers().length && all.getBounds().isValid()) {{ map.fitBounds(all.getBounds(), {{padding: [20, 20]}}); }}
else {{ map.setView([0, 0], 2); }}
const legend = L.control({{position: "bottomright"}});
legend.onAdd = () => {{
  const d = L.DomUtil.create("div", "rc-legend");
  d.innerHTML = "<b>IRI (m/km)</b><br>" + classes.map(c => `<i style="background:${{c[1]}}"></i>${{c[2]}}`).join("<br>") +
    `<br><i style="background:#b2182b;border-radius:50%;width:10px"></i>pothole ` +
    `<i style="background:#2166ac;border-radius:50%;width:10px"></i>bump`;
  return d;
}};
legend.addTo(map);
window.roadcollab = {{drawn: drawn, map: map}};
</script></body></html>
"""


def leaflet_files() -> dict:
    """The bundled Leaflet's script, stylesheet and licence.

    Returns
    -------
    dict
        ``{"js": str, "css": str, "license": str}``.
    """
    root = resources.files("roadcollab") / "data" / "leaflet"
    return {k: (root / name).read_text(encoding="utf-8")
            for k, name in (("js", "leaflet.js"), ("css", "leaflet.css"), ("license", "LICENSE"))}


def map_html(segments_fc: dict, anomalies_fc: dict, *, title: str = "roadcollab road condition",
             tiles: str | None = None, attribution: str = "") -> str:
    """The page (module docstring).

    Parameters
    ----------
    segments_fc, anomalies_fc : dict
        GeoJSON FeatureCollections (:func:`roadcollab.geo.export.segments_geojson` and ``anomalies_geojson``).
    title : str
    tiles : str, optional
        A tile URL template (``https://.../{z}/{x}/{y}.png``); None draws no tiles (offline).
    attribution : str
        The tiles' attribution.

    Returns
    -------
    str
    """
    lf = leaflet_files()
    classes = [[c if c != float("inf") else 1e9, col, label] for c, col, label in IRI_CLASSES]
    data = json.dumps({"segments": segments_fc, "anomalies": anomalies_fc, "classes": classes, "tiles": tiles,
                       "attribution": attribution}, allow_nan=False)
    data = data.replace("</", "<\\/")             # nothing in the data can close the script element
    return _PAGE.format(title=html.escape(title), leaflet_css=lf["css"], leaflet_js=lf["js"], data=data)


def write_map(path, segments_fc: dict, anomalies_fc: dict, *, tiles: str | None = None) -> Path:
    """Write ``map.html``.

    Parameters
    ----------
    path : str or Path
    segments_fc, anomalies_fc : dict
        GeoJSON FeatureCollections.
    tiles : str, optional
        Tile URL template (default none: offline).

    Returns
    -------
    Path
    """
    path = Path(path)
    path.write_text(map_html(segments_fc, anomalies_fc, tiles=tiles), encoding="utf-8")
    return path
