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
    (taken `settle_s` apart, after the viewer has loaded the recording: its step timeline reaches the recording's
    last frame and the picture stops changing, see :func:`_wait_until_loaded`). Returns the PNG paths; raises
    RuntimeError when a requirement is missing, the viewer does not come up, or it has not finished loading within
    `timeout_s` (the PNGs are then still written, showing what had loaded)."""
    from tflock.record import read_recording, serve_web

    reason = missing_requirement()
    if reason:
        raise RuntimeError(f"cannot take screenshots: {reason}")
    from playwright.sync_api import sync_playwright

    try:
        last_step = read_recording(Path(path)).last_step
    except ValueError:  # not a tflock recording: wait for the picture alone
        last_step = None
    console: list[str] = []
    with serve_web(Path(path)) as url, sync_playwright() as p:
        browser = p.chromium.launch(executable_path=find_chromium(), headless=True, args=list(CHROMIUM_ARGS))
        try:
            page = browser.new_page(viewport={"width": width, "height": height}, color_scheme=theme)
            page.on("console", lambda msg: console.append(f"{msg.type}: {msg.text}"))
            page.goto(url, timeout=timeout_s * 1000)
            page.wait_for_selector("canvas", timeout=timeout_s * 1000)
            unfinished = _wait_until_loaded(page, timeout_s, last_step)
            for shot in shots:
                time.sleep(settle_s)
                shot.parent.mkdir(parents=True, exist_ok=True)
                page.screenshot(path=str(shot), timeout=timeout_s * 1000)
        finally:
            browser.close()
    for shot in shots:
        shot.with_suffix(".console.txt").write_text("\n".join(console) + "\n", encoding="utf-8")
    if unfinished:
        saved = ", ".join(str(shot) for shot in shots)
        raise RuntimeError(f"{unfinished}: {saved} may show a partly loaded recording (raise --timeout)")
    return shots


def _varint(buf: bytes, i: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        byte = buf[i]
        value |= (byte & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if byte < 0x80:
            return value, i


def loaded_step(state: bytes, timeline: str = "step") -> int | None:
    """The last time of a sequence `timeline` in the viewer's state (the bytes of the web viewer's
    ``WebHandle.viewer_state()``, a protobuf message), or None where the state names no such timeline yet.

    The state is no public API: it holds, per timeline, a message ``{1: {1: name}, 2: 1 (sequence), 3: {...times}}``;
    the largest time in it is where the viewer is (it follows the newest data while a file streams in)."""
    name = timeline.encode()
    key = b"\n" + bytes([len(name) + 2]) + b"\n" + bytes([len(name)]) + name + b"\x10\x01\x1a"
    found = None
    start = state.find(key)
    while start >= 0:
        try:
            size, i = _varint(state, start + len(key))
            body, i = state[i:i + size], 0
            while i < len(body):
                tag, i = _varint(body, i)
                if tag & 7 != 0:  # only varint fields hold times here
                    break
                value, i = _varint(body, i)
                found = value if found is None else max(found, value)
        except IndexError:
            pass
        start = state.find(key, start + 1)
    return found


#: the viewer's state where the page has one: None before the viewer has started (``window._handle`` is set once
#: its WebAssembly runs), a string where this viewer build offers no state, else the state's bytes
_STATE_JS = ("() => !window._handle ? null : (typeof window._handle.viewer_state !== 'function' ? 'no state'"
             " : Array.from(window._handle.viewer_state()))")


def _wait_until_loaded(page, timeout_s: float, last_step: int | None = None, quiet_s: float = 6.0) -> str | None:
    """Wait until the viewer has loaded the recording; return None once it has, or why not when `timeout_s` has
    passed. The viewer streams the file over gRPC and follows the newest step, so it has loaded once its step
    timeline reaches `last_step` (the last frame; read from the viewer's state, :func:`loaded_step`) and two
    screenshots `quiet_s` apart are identical. Before the viewer has started, or until its timeline reaches
    `last_step`, identical pictures do not count (a busy machine can hold the loading screen, or a half-loaded run,
    still for longer than `quiet_s`). Only a viewer build without a readable state is judged by the pictures alone,
    as is a file without a `last_step`. A screenshot that does not come within what is left of `timeout_s`
    (software WebGL on a busy machine) counts as not loaded yet."""
    from playwright.sync_api import Error as PlaywrightError
    from playwright.sync_api import TimeoutError as PlaywrightTimeout

    deadline = time.monotonic() + timeout_s
    last, reached, started = None, None, False
    while time.monotonic() < deadline:
        time.sleep(quiet_s)
        if last_step is not None:
            try:
                state = page.evaluate(_STATE_JS)
            except PlaywrightError:  # the page is navigating or busy: ask again
                continue
            if state is None:
                continue
            started = True
            if isinstance(state, str):  # a viewer build without a readable state: the pictures decide
                last_step = None
            else:
                reached = loaded_step(bytes(state))
                if reached is None or reached < last_step:
                    last = None
                    continue
        try:
            now = page.screenshot(timeout=max(1.0, deadline - time.monotonic()) * 1000)
        except PlaywrightTimeout:
            continue
        if now == last:
            return None
        last = now
    if last_step is not None and not started:
        return f"the viewer had not started after {timeout_s:g} s"
    if last_step is not None and (reached is None or reached < last_step):
        return f"the viewer had loaded up to step {reached} of {last_step} after {timeout_s:g} s"
    return f"the picture was still changing after {timeout_s:g} s"


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
