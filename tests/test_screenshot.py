"""The recording as a person sees it: Rerun's web viewer in headless Chromium (tflock.screenshot), and
`tflock view --web` on free ports."""

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
    world = red[:, : int(1200 * 0.55)]  # the world view: the left three fifths
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
                                 stderr=subprocess.DEVNULL, text=True, env=env) for _ in range(2)]
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
                child.kill()


def test_loaded_step_reads_the_viewers_step_timeline() -> None:
    """The step the web viewer has reached, from its state (bytes taken from the viewer while a 10,000-step file
    streamed in: the step timeline at 1180, next to the time timeline in nanoseconds, which does not count)."""
    state = (b"\nKabout:recording?app_id=tflock\x121Recording:tflock:c56c\x1a\xbd\x01\n1Recording:tflock:c56c"
             b"\x12\x14\n\x06\n\x04step\x10\x01\x1a\x03\x10\x9c\t\"\x03\x08\x9c\t\x12\x12\n\x06\n\x04time\x10\x02"
             b"\x1a\x06\x10\x80\xec\xd6\xfa+\x1a\x0f\n\x06\n\x04step\x10\x01\x1a\x03\x08\x9c\t\"Kabout")
    assert loaded_step(state) == 1180
    assert loaded_step(state, "time") is None  # a duration timeline is no sequence
    assert loaded_step(b"\nKabout:recording?app_id=tflock") is None  # nothing loaded yet
