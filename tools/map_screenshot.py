"""Open a ``map.html`` in headless Chromium with the network blocked; count the drawn features; screenshot it.

Usage: ``python tools/map_screenshot.py results/map/map.html docs/map.png``. Needs the Debian
``chromium`` package and the ``playwright`` Python client (its own browser download is not used).
The same function is the browser test's (tests/test_map_e2e.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync"]


def render_map(html: Path, png: Path | None = None, *, timeout_s: float = 60.0) -> dict:
    """Load the page offline; return the drawn counts, the requests made and the console errors."""
    from playwright.sync_api import sync_playwright

    requests, errors = [], []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, timeout=timeout_s * 1000)
        try:
            context = browser.new_context(offline=True, viewport={"width": 1200, "height": 800})
            page = context.new_page()
            page.route("**/*", lambda route: route.continue_() if route.request.url.startswith("file:")
                       else (requests.append(route.request.url), route.abort()))
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(Path(html).resolve().as_uri(), timeout=timeout_s * 1000)
            page.wait_for_function("window.roadcollab !== undefined", timeout=timeout_s * 1000)
            counts = page.evaluate("""() => ({
                segments: document.querySelectorAll('path.rc-segment').length,
                anomalies: document.querySelectorAll('path.rc-anomaly').length,
                legend: document.querySelectorAll('.rc-legend').length,
                drawn: window.roadcollab.drawn})""")
            page.locator("path.rc-segment").first.click(force=True)
            popup = page.locator(".leaflet-popup-content").first.inner_text(timeout=timeout_s * 1000)
            if png is not None:
                page.wait_for_timeout(800)          # the popup fades in over 200 ms
                page.screenshot(path=str(png))
        finally:
            browser.close()
    return {**counts, "popup": popup, "requests": requests, "errors": errors}


if __name__ == "__main__":
    print(render_map(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else None))
