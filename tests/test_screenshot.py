"""The recording as a person sees it: Rerun's web viewer in headless Chromium (tflock.screenshot), and
`tflock view --web` on free ports."""

import contextlib
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tflock.frame import HEADING_LEGEND, Frame, WorldSpec
from tflock.record import Recorder
from tflock.screenshot import loaded_step, missing_requirement, take_screenshots

REPO = Path(__file__).resolve().parents[1]
BOX = 100.0


def upper_half_recording(path: Path) -> None:
    """Three frames of 400 agents heading along +x (red on the hue wheel), all in the upper half of the box."""
    rng = np.random.default_rng(0)
    pos = np.stack([rng.random(400) * BOX, BOX / 2 + rng.random(400) * BOX / 2 * 0.95], axis=1).astype(np.float32)
    right = np.tile(np.array([[1.0, 0.0]], np.float32), (400, 1))
    with Recorder(model="vicsek", config_toml="", world=WorldSpec(2, "periodic", BOX),
                  metrics={"order": "polarisation"}, path=path, legend=HEADING_LEGEND) as rec:
        for step in range(3):
            rec.log_frame(step, Frame(pos + np.float32(step), right, arrow_length=3.0, ids=np.arange(400)))
            rec.log_metrics(step, {"order": 0.5 + 0.1 * step})


@pytest.mark.skipif(missing_requirement() is not None, reason=f"no screenshots here: {missing_requirement()}")
def test_screenshot_shows_agents_y_up_and_the_legend(tmp_path: Path) -> None:
    from PIL import Image

    path = tmp_path / "up.rrd"
    upper_half_recording(path)
    (shot,) = take_screenshots(path, [tmp_path / "up.png"], width=1200, height=750, timeout_s=240)
    image = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert image.shape == (750, 1200, 3)
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    red = (r > 200) & (g < 60) & (b < 60)
    world = red[:, : int(1200 * 0.55)]  # the world view: the left 7 of 12 parts
    rows = np.nonzero(world.any(axis=1))[0]
    assert world.sum() > 400, "no agents drawn in the world view"
    # y up: the agents of the upper half of the box are drawn in the upper half of the view (the view spans the
    # page's height below the top bar, from about row 60 to row 720)
    assert np.median(np.nonzero(world)[0]) < 0.5 * (60 + 720), f"agents drawn low: rows {rows.min()}-{rows.max()}"
    legend = image[60:260, int(1200 * 0.6):]  # the colours view, top right: the hue wheel's green and blue
    green = (legend[..., 1] > 200) & (legend[..., 0] < 80) & (legend[..., 2] < 80)
    blue = (legend[..., 2] > 200) & (legend[..., 0] < 80) & (legend[..., 1] < 80)
    assert green.any() and blue.any(), "no colour legend"
    console = shot.with_suffix(".console.txt").read_text()
    assert "Data source failed" not in console


def test_view_web_picks_free_ports_and_prints_the_address(tmp_path: Path) -> None:
    """Two `tflock view --web` at once, each on ports of its own, each printing the address to open."""
    path = tmp_path / "view.rrd"
    upper_half_recording(path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    code = ("import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler)\n"
            "from tflock.cli import app\napp()\n")
    children = [subprocess.Popen([sys.executable, "-c", code, "view", str(path), "--web"], stdout=subprocess.PIPE,
                                 stderr=subprocess.DEVNULL, text=True, env=env, start_new_session=True)
                for _ in range(2)]  # each in a process group of its own, with the viewer it starts
    try:
        urls = []
        for child in children:
            assert child.stdout is not None
            line = child.stdout.readline()
            match = re.search(r"http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1%3A(\d+)%2Fproxy",
                              line)
            assert match, line
            urls.append(match.groups())
        ports = [int(p) for pair in urls for p in pair]
        assert len(set(ports)) == 4  # no two viewers share a port
        for child in children:
            assert child.poll() is None  # both serve at once
    finally:
        for child in children:
            child.send_signal(signal.SIGINT)
        for child in children:
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
            with contextlib.suppress(ProcessLookupError):  # the viewer too, had `tflock view` not stopped it
                os.killpg(child.pid, signal.SIGKILL)
            child.wait()


def test_loaded_step_reads_the_viewers_step_timeline() -> None:
    """The step the web viewer has reached, from its state (bytes taken from the viewer while a 10,000-step file
    streamed in: the step timeline at 1180, next to the time timeline in nanoseconds, which does not count)."""
    state = (b"\nKabout:recording?app_id=tflock\x121Recording:tflock:c56c\x1a\xbd\x01\n1Recording:tflock:c56c"
             b"\x12\x14\n\x06\n\x04step\x10\x01\x1a\x03\x10\x9c\t\"\x03\x08\x9c\t\x12\x12\n\x06\n\x04time\x10\x02"
             b"\x1a\x06\x10\x80\xec\xd6\xfa+\x1a\x0f\n\x06\n\x04step\x10\x01\x1a\x03\x08\x9c\t\"Kabout")
    assert loaded_step(state) == 1180
    assert loaded_step(state, "time") is None  # a duration timeline is no sequence
    assert loaded_step(b"\nKabout:recording?app_id=tflock") is None  # nothing loaded yet


class _FakePage:
    """A page whose viewer starts after `start` polls and streams one step per poll up to `last`; its picture
    stays the same throughout (the loading screen, then a stalled half-loaded run on a busy machine)."""

    def __init__(self, start: int, last: int) -> None:
        self.polls, self.start, self.last = 0, start, last
        self.picture = b"the same picture"

    def evaluate(self, script: str) -> object:
        self.polls += 1
        if self.polls <= self.start:
            return None
        step = min(self.polls - self.start, self.last)
        return list(b"\n\x06\n\x04step\x10\x01\x1a\x02\x08" + bytes([step]))

    def screenshot(self, timeout: float) -> bytes:
        return self.picture


def test_wait_until_loaded_does_not_take_a_still_picture_for_a_loaded_run() -> None:
    """Identical pictures count only once the viewer has started and its step timeline has reached the last frame:
    a loading screen or a stalled half-loaded run is not reported as loaded."""
    from tflock.screenshot import _wait_until_loaded

    page = _FakePage(start=3, last=5)
    assert _wait_until_loaded(page, timeout_s=5.0, last_step=5, quiet_s=0.001) is None
    assert page.polls >= 3 + 5 + 1  # waited for the start, every step, then two equal pictures at the last step
    stuck = _FakePage(start=3, last=2)  # the viewer stops at step 2 of 5
    why = _wait_until_loaded(stuck, timeout_s=0.2, last_step=5, quiet_s=0.001)
    assert why is not None and "step 2 of 5" in why
    never = _FakePage(start=10**9, last=0)
    assert "not started" in _wait_until_loaded(never, timeout_s=0.1, last_step=5, quiet_s=0.001)
