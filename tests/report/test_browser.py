"""The report in a real browser: headless Chromium opens ``index.html``, every image decodes,
every video loads with a duration, and a screenshot of the page is saved.

Slow (it builds a report and starts a browser). Chromium is the distribution's package
(Debian: ``apt-get install chromium``; installed here when missing and running as root),
driven through Playwright's Python API with that executable: no browser is downloaded.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np
import pytest

pytestmark = pytest.mark.slow

BROWSERS = ("chromium", "chromium-browser", "google-chrome")
LOAD_TIMEOUT_MS = 30_000

CHECK_MEDIA = """async (timeout) => {
  const images = [...document.images].map(i => ({
    src: i.src.slice(0, 60), ok: i.complete && i.naturalWidth > 0 }));
  const wait = (v, event) => new Promise(resolve => {
    v.addEventListener(event, resolve, { once: true });
    v.addEventListener('error', resolve, { once: true });
    setTimeout(resolve, timeout);
  });
  const videos = [];
  for (const v of document.querySelectorAll('video')) {
    if (v.readyState < 1 && !v.error) { const meta = wait(v, 'loadedmetadata'); v.load(); await meta; }
    if (!v.error && v.duration > 0) {  // show a frame from the middle: it must decode
      const seeked = wait(v, 'seeked'); v.currentTime = v.duration / 2; await seeked;
    }
    videos.push({ src: v.currentSrc, duration: v.duration, ready: v.readyState,
                  error: v.error ? v.error.code : null, width: v.videoWidth });
  }
  return { images, videos };
}"""


APT_STEPS = (
    ("install", "-y", "-qq", "chromium"),
    ("update", "-qq"),
    ("install", "-y", "-qq", "chromium"),
)


def find_chromium() -> str:
    """The system's Chromium; installed from the distribution when missing (root only)."""
    for name in BROWSERS:
        if path := shutil.which(name):
            return path
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("apt-get"):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        for step in APT_STEPS:  # the package lists may be stale: update once, then retry
            subprocess.run(["apt-get", *step], env=env, capture_output=True, timeout=1200)
            if path := shutil.which("chromium"):
                return path
    pytest.skip(
        "no Chromium on this machine and it could not be installed: "
        "`apt-get install chromium` (Debian) enables the browser test"
    )


def test_report_opens_in_chromium_with_every_image_and_video_loaded(media_report, tmp_path):
    sync_api = pytest.importorskip(
        "playwright.sync_api", reason="the test extra `playwright` drives the browser"
    )
    out = media_report.out
    pngs = sorted((out / "figures").glob("*.png"))
    mp4s = sorted((out / "figures").glob("*.mp4"))
    assert pngs and mp4s
    errors: list[str] = []
    shot = tmp_path / "index.png"
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=find_chromium(), args=["--no-sandbox"])
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 900})
            page.on("pageerror", lambda err: errors.append(str(err)))
            page.goto((out / "index.html").as_uri(), wait_until="load")
            media = page.evaluate(CHECK_MEDIA, LOAD_TIMEOUT_MS)
            page.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    print(f"screenshot: {shot}")
    assert not errors
    assert len(media["images"]) == len(pngs)
    assert all(img["ok"] for img in media["images"]), media["images"]
    assert sorted(v["src"].rsplit("/", 1)[-1] for v in media["videos"]) == [p.name for p in mp4s]
    for video in media["videos"]:
        assert video["error"] is None and video["duration"] > 0 and video["width"] > 0, video
        assert video["ready"] >= 2, video  # HAVE_CURRENT_DATA: a frame was decoded
    from PIL import Image

    with Image.open(shot) as img:
        assert img.size[0] == 1200 and img.size[1] > 900  # the whole page, not the viewport
        assert np.asarray(img.convert("L")).std() > 10  # not a blank page
