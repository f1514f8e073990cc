"""Warnings for values that are legal but almost surely a mistake.

Each is a :class:`TflockWarning` (a ``UserWarning``) with a one-line message that names the key, the value and
what it means; ``tflock sim`` prints each as one ``warning: ...`` line on stderr and runs on. The list, with the
reasons, is in docs/errors.md.
"""

from __future__ import annotations

import math
import os
import warnings

from tflock.config import Config


class TflockWarning(UserWarning):
    """A legal value that is almost surely a mistake (the message is one line)."""


def _g(value: float) -> str:
    return f"{value:g}"


def mistakes(config: Config, *, checkpoint_every: int = 0, start_step: int = 0) -> list[str]:
    """One line for each legal but suspicious value of a run of `config` (checkpoints every `checkpoint_every`
    steps, starting at `start_step`)."""
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
                   f"the last step ({config.steps}), so no checkpoint will be written")
    return out


def warn_mistakes(config: Config, *, checkpoint_every: int = 0, start_step: int = 0) -> None:
    """Issue a :class:`TflockWarning` for each of :func:`mistakes`."""
    for line in mistakes(config, checkpoint_every=checkpoint_every, start_step=start_step):
        warnings.warn(line, TflockWarning, stacklevel=3)
