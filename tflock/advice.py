"""Warnings for values that are legal but almost surely a mistake.

Each is a :class:`TflockWarning` (a ``UserWarning``) with a one-line message that names the key, the value and
what it means; ``tflock sim`` prints each as one ``warning: ...`` line on stderr and runs on. The list, with the
reasons, is in docs/errors.md.
"""

from __future__ import annotations

import math
import os
import shutil
import warnings
from pathlib import Path

from tflock.config import Config

#: bytes a frame of a recording takes, per drawn agent, per edge drawn (at most log.max_edges) and per field pixel:
#: from recordings of the default Vicsek config on 2026-11-28 (2000 agents: 60 KB a frame at f32, 71 KB at f64; 4000
#: edges 43 KB more; the default run at 1e5, 2000 agents, a 112 x 112 field and few edges: 94 KB), an upper estimate
FRAME_BYTES_PER_AGENT, FRAME_BYTES_PER_EDGE, FRAME_BYTES_PER_PIXEL = 36, 11, 3
#: a recording estimated larger than this (or than the free space where it goes) gets a warning
LARGE_RECORDING_BYTES = 4 * 2**30


class TflockWarning(UserWarning):
    """A legal value that is almost surely a mistake (the message is one line)."""


def _g(value: float) -> str:
    return f"{value:g}"


def recording_bytes(config: Config, drawn: int, field: int, start_step: int = 0) -> float:
    """Upper estimate of the size of a recording of a run of `config` from `start_step`: its frames (every
    ``log.every`` steps) of `drawn` agents, ``log.max_edges`` edges and a `field` x `field` field."""
    every = config.log.every
    frames = config.steps // every - start_step // every + (1 if start_step == 0 else 0)
    per_frame = (FRAME_BYTES_PER_AGENT * drawn + FRAME_BYTES_PER_EDGE * config.log.max_edges
                 + FRAME_BYTES_PER_PIXEL * field * field)
    return max(0, frames) * per_frame


def _large_recording(config: Config, recording: Path, drawn: int, field: int, start_step: int) -> str | None:
    """The warning for a recording estimated larger than LARGE_RECORDING_BYTES or the free space where it goes."""
    size = recording_bytes(config, drawn, field, start_step)
    try:
        free = shutil.disk_usage(recording.parent).free
    except OSError:
        free = math.inf
    if size <= min(LARGE_RECORDING_BYTES, free):
        return None
    room = f", more than the {free / 1e9:.3g} GB free there" if size > free else ""
    every = "every step" if config.log.every == 1 else f"every {config.log.every} steps"
    return (f"log.every (= {config.log.every}): {recording} will hold a frame of {drawn:,} agents {every} to step "
            f"{config.steps:,}, up to about {size / 1e9:.3g} GB{room}; raise log.every (or lower log.max_agents, "
            "log.max_edges, log.field) to thin the frames")


def mistakes(config: Config, *, checkpoint_every: int = 0, start_step: int = 0, recording: Path | None = None,
             drawn: int = 0, field: int = 0) -> list[str]:
    """One line for each legal but suspicious value of a run of `config` (checkpoints every `checkpoint_every`
    steps, starting at `start_step`; a `recording` file with frames of `drawn` agents and a `field`-pixel field)."""
    p, out = config.params, []
    boundary, box, radius = getattr(p, "boundary", None), getattr(p, "box", None), getattr(p, "radius", None)
    dim = getattr(p, "dim", 2)
    if boundary == "periodic" and radius > box / 2:
        out.append(f"params.radius (= {_g(radius)}) > params.box / 2 (= {_g(box / 2)}) in a periodic box: an agent's "
                   "neighbourhood wraps around the box onto itself, so it is not a disc (neighbours are counted "
                   "once, at their nearest image)")
    elif boundary == "reflecting" and radius >= box * math.sqrt(dim):
        out.append(f"params.radius (= {_g(radius)}) >= the box's diagonal (= {_g(box * math.sqrt(dim))}): every "
                   "agent is a neighbour of every other at every step")
    cores = os.cpu_count() or 1
    if config.engine.arch == "cpu" and config.engine.threads > cores:
        out.append(f"engine.threads (= {config.engine.threads}) > the {cores} cores of this machine: the extra "
                   "threads only take turns on the same cores (0 = one per core)")
    bound, to_run = getattr(p, "async_bound", 1), config.steps - start_step
    if bound > 1 and bound > to_run:
        out.append(f"params.async_bound (= {bound}) > the steps to run (= {to_run}): an agent is only sure to "
                   f"update once in {bound} steps (with probability 1/{bound} at first), so many agents will not "
                   "update at all in this run")
    if checkpoint_every and config.steps // checkpoint_every == start_step // checkpoint_every:
        out.append(f"--checkpoint-every (= {checkpoint_every}): no multiple of it lies between step {start_step} and "
                   f"the last step ({config.steps}), so only a stop (Ctrl-C, SIGTERM) writes a checkpoint")
    large = None if recording is None else _large_recording(config, recording, drawn, field, start_step)
    if large is not None:
        out.append(large)
    return out


def warn_mistakes(config: Config, *, checkpoint_every: int = 0, start_step: int = 0, recording: Path | None = None,
                  drawn: int = 0, field: int = 0) -> None:
    """Issue a :class:`TflockWarning` for each of :func:`mistakes`."""
    for line in mistakes(config, checkpoint_every=checkpoint_every, start_step=start_step, recording=recording,
                         drawn=drawn, field=field):
        warnings.warn(line, TflockWarning, stacklevel=3)
