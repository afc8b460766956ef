"""report.html in a real browser: headless Chromium loads it from disk, with the network off, and
every <img> must have decoded (naturalWidth > 0, equal to the PNG's own width).

Skips, saying why, when Chromium is not installed (Debian: `apt-get install -y chromium`).
"""

from __future__ import annotations

import dataclasses
import html
import json
import re
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

CHROMIUM = next(
    (
        p
        for p in (shutil.which("chromium"), shutil.which("chromium-browser"), "/usr/bin/chromium")
        if p and Path(p).is_file()
    ),
    None,
)
pytestmark = pytest.mark.skipif(
    CHROMIUM is None, reason="chromium not installed (apt-get install -y chromium)"
)

#: seconds for Chromium to start, load a ~1 MB page and dump it, with room for a loaded 2-core machine
BROWSER_TIMEOUT_S = 120
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--virtual-time-budget=10000",
)
PROBE = """<script>window.addEventListener('load', function () {
  var out = [];
  document.querySelectorAll('img').forEach(function (im) {
    out.push({alt: im.alt, complete: im.complete, w: im.naturalWidth, h: im.naturalHeight});
  });
  var pre = document.createElement('pre');
  pre.id = 'bayespinn-imgcheck';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});</script>"""


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk."""
    head = path.read_bytes()[:24]
    return struct.unpack(">II", head[16:24])


def images_as_rendered(page: Path, tmp: Path) -> list[dict]:
    """Load a copy of `page` with a probe script in headless Chromium; the probe's findings."""
    copy = tmp / "probe.html"
    copy.write_text(
        page.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"), encoding="utf-8"
    )
    profile = tmp / "chromium-profile"
    profile.mkdir()
    r = subprocess.run(
        [CHROMIUM, *FLAGS, f"--user-data-dir={profile}", "--dump-dom", copy.resolve().as_uri()],
        capture_output=True,
        text=True,
        timeout=BROWSER_TIMEOUT_S,
    )
    m = re.search(r'<pre id="bayespinn-imgcheck">(.*?)</pre>', r.stdout, re.S)
    assert m, f"chromium did not run the probe (rc {r.returncode}): {r.stderr[-2000:]}"
    return json.loads(html.unescape(m.group(1)))


def test_every_image_renders_in_chromium(tmp_path):
    from bayespinn.config import preset
    from bayespinn.options import RunOptions
    from bayespinn.pipeline import run

    cfg = preset("deflection")
    cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, n_points=30))
    out = tmp_path / "run"
    run(cfg, methods=["modal"], snr_db=20.0, seed=0, out=out, opts=RunOptions(profile="smoke"))
    page = out / "report.html"
    text = page.read_text(encoding="utf-8")
    n_img = text.count("<img ")
    assert n_img >= 3
    figures = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", (out / "report.md").read_text(encoding="utf-8"))
    rendered = images_as_rendered(page, tmp_path)
    assert len(rendered) == n_img == len(figures)
    for im, name in zip(rendered, figures, strict=True):
        assert im["complete"] and im["w"] > 0 and im["h"] > 0, im
        assert (im["w"], im["h"]) == png_size(out / name), (im, name)
