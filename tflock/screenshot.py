"""Screenshots of a recording as a person sees it: Rerun's web viewer in headless Chromium.

``python -m tflock.screenshot RUN.rrd -o shot.png`` (or ``tflock view RUN.rrd --screenshot shot.png``) serves the
recording with Rerun's web viewer on free local ports (:func:`tflock.record.serve_web`), opens it in Chromium
through Playwright with software WebGL, waits until the viewer has loaded the file, and saves a PNG (and the
page's console messages beside it, ``shot.console.txt``, where the viewer reports load errors).

Needs Chromium (Debian: ``apt-get install chromium``) and the ``playwright`` package (``pip install
tflock[test]``); Playwright's own browser download is not needed: Debian's ``/usr/bin/chromium`` is launched.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

#: Chromium flags that give a WebGL canvas without a GPU or display (SwiftShader's software rasteriser)
CHROMIUM_ARGS = ("--no-sandbox", "--use-gl=angle", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 "--ignore-gpu-blocklist", "--enable-webgl")
#: the browser looked for when none is given (``TFLOCK_CHROMIUM`` wins)
CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium() -> str | None:
    """Path of a Chromium executable: ``$TFLOCK_CHROMIUM`` or the first of :data:`CHROMIUM_NAMES` on the PATH."""
    given = os.environ.get("TFLOCK_CHROMIUM")
    if given:
        return given if Path(given).is_file() else None
    for name in CHROMIUM_NAMES:
        found = shutil.which(name)
        if found:
            return found
    return None


def missing_requirement() -> str | None:
    """Why screenshots cannot be taken here (one line), or None when they can."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "the playwright package is not installed (pip install playwright, or tflock[test])"
    if find_chromium() is None:
        return "no Chromium found (apt-get install chromium, or set TFLOCK_CHROMIUM to its path)"
    return None


def take_screenshots(path: Path, shots: list[Path], *, width: int = 1600, height: int = 1000, theme: str = "dark",
                     settle_s: float = 4.0, timeout_s: float = 180.0) -> list[Path]:
    """Serve `path` in the web viewer, open it in headless Chromium and save one PNG per entry of `shots`
    (taken `settle_s` apart, after the viewer has loaded the recording: its time panel stops growing). Returns the
    PNG paths; raises RuntimeError when a requirement is missing or the viewer does not come up."""
    from tflock.record import serve_web

    reason = missing_requirement()
    if reason:
        raise RuntimeError(f"cannot take screenshots: {reason}")
    from playwright.sync_api import sync_playwright

    console: list[str] = []
    with serve_web(Path(path)) as url, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium(), headless=True, args=list(CHROMIUM_ARGS))
        try:
            page = browser.new_page(viewport={"width": width, "height": height}, color_scheme=theme)
            page.on("console", lambda msg: console.append(f"{msg.type}: {msg.text}"))
            page.goto(url, timeout=timeout_s * 1000)
            page.wait_for_selector("canvas", timeout=timeout_s * 1000)
            _wait_until_loaded(page, timeout_s)
            for shot in shots:
                time.sleep(settle_s)
                shot.parent.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(shot), timeout=timeout_s * 1000)
        finally:
            browser.close()
    for shot in shots:
        shot.with_suffix(".console.txt").write_text("\n".join(console) + "\n", encoding="utf-8")
    return shots


def _wait_until_loaded(page, timeout_s: float, quiet_s: float = 6.0) -> None:
    """Wait until the page has stopped receiving data: the viewer streams the file over gRPC, and while it loads
    the canvas changes every frame. Taken as loaded once two screenshots `quiet_s` apart are identical (the
    viewer follows the newest step while data arrives, then stops there), or after `timeout_s`. A screenshot that
    does not come within what is left of `timeout_s` (software WebGL on a busy machine) counts as not loaded yet."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    deadline = time.monotonic() + timeout_s
    last = None
    while time.monotonic() < deadline:
        time.sleep(quiet_s)
        try:
            now = page.screenshot(timeout=max(1.0, deadline - time.monotonic()) * 1000)
        except PlaywrightTimeout:
            continue
        if now == last:
            return
        last = now


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tflock.screenshot", description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, help="the .rrd file")
    parser.add_argument("-o", "--out", type=Path, required=True, help="PNG to write")
    parser.add_argument("--width", type=int, default=1600)
    parser.add_argument("--height", type=int, default=1000)
    parser.add_argument("--theme", choices=("dark", "light"), default="dark")
    parser.add_argument("--timeout", type=float, default=180.0, help="seconds to wait for the viewer to load")
    args = parser.parse_args(argv)
    if not args.recording.is_file():
        print(f"error: recording not found: {args.recording}", file=sys.stderr)
        return 2
    try:
        take_screenshots(args.recording, [args.out], width=args.width, height=args.height, theme=args.theme,
                         timeout_s=args.timeout)
    except RuntimeError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
