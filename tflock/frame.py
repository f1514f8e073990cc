"""What a model hands the recorder: the world's geometry and one drawn step, as plain NumPy data.

Kept apart from :mod:`tflock.record` (the only module that imports Rerun) so that models and runs without a
recording never load Rerun.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

BOUNDARIES = ("periodic", "reflecting", "open")


@dataclass(frozen=True)
class WorldSpec:
    """Geometry of the simulated world as the recorder needs it."""

    dim: int  # 2 or 3
    boundary: str  # "periodic" | "reflecting" | "open"
    box: float  # side of the box (open space: side of the initial square)
    dt: float = 1.0  # simulated time per step; the `time` timeline is step * dt seconds

    def __post_init__(self) -> None:
        if self.dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {self.dim}")
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"boundary must be one of {', '.join(BOUNDARIES)}, got {self.boundary!r}")
        if not self.box > 0:
            raise ValueError(f"box must be positive, got {self.box}")
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt}")

    @property
    def bounded(self) -> bool:
        """Whether the world has walls (periodic or reflecting box) worth drawing."""
        return self.boundary != "open"


@dataclass
class Marker:
    """A named object drawn on its own entity ``world/<name>``: a point, an optional arrow and an optional circle
    of radius ``circle`` around it (2D; e.g. the virtual agent and its interaction radius)."""

    name: str
    position: np.ndarray  # (dim,)
    direction: np.ndarray | None = None  # (dim,) arrow, scaled by the frame's arrow_length * 1.5
    circle: float | None = None  # radius of a circle drawn around the point (2D only)
    color: tuple[int, int, int] = (255, 255, 255)
    size: float = 2.5  # point radius, in multiples of the frame's agent radius


@dataclass
class Frame:
    """What is drawn at one step (already subsampled by the caller). Arrays are converted to float32."""

    positions: np.ndarray  # (M, dim) float32
    directions: np.ndarray  # (M, dim) heading unit vectors (or velocities)
    arrow_length: float  # scene units the unit direction is scaled to
    colors: np.ndarray | None = None  # (M, 3) uint8; None: hue of the heading angle atan2(y, x)
    edges: np.ndarray | None = None  # (E, 2, dim) neighbour pairs, one LineStrips entity
    leader: np.ndarray | None = None  # (dim,) leader position, drawn bigger in white at world/leader
    radius: float = 0.3  # point radius in scene units
    leader_direction: np.ndarray | None = None  # (dim,) leader heading; drawn as an arrow when given
    markers: list[Marker] = field(default_factory=list)  # other objects, each at world/<name> (same set each frame)


def heading_colors(directions: np.ndarray) -> np.ndarray:
    """Colour each direction by its planar angle ``atan2(y, x)`` on the HSV wheel (full saturation and value).

    Returns an (M, 3) uint8 array; angle 0 is red, 2 pi / 3 green, 4 pi / 3 blue.
    """
    d = np.asarray(directions, dtype=np.float32)
    hue = np.arctan2(d[:, 1], d[:, 0]) * np.float32(3.0 / math.pi)  # angle / (2 pi) * 6, in [-3, 3]
    h6 = np.mod(hue, np.float32(6.0))[:, None]
    k = np.mod(np.array([5.0, 3.0, 1.0], dtype=np.float32) + h6, np.float32(6.0))
    rgb = 1.0 - np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)
    return np.rint(rgb * 255.0).astype(np.uint8)
