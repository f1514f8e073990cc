"""What a model hands the recorder: the world's geometry, its colour legend and one drawn step, as plain NumPy data.

Kept apart from :mod:`tflock.record` (the only module that imports Rerun) so that models and runs without a
recording never load Rerun.

The arrow convention, the same for every model: an agent's arrow is its velocity over the step just made,
``(x(t) - x(t - 1)) / dt`` (up to a boundary's wrap or mirror), divided by the model's reference speed (Vicsek's and
Li-Wang's v0, Tanner's initial speed bound, the formation's |vout|) and drawn ``arrow_length`` scene units long
per unit of it: a full-speed agent's arrow has length ``arrow_length`` (see :func:`arrow_length`), and a slower
agent's at least :data:`MIN_ARROW` of that (:func:`drawn_arrows`: at a tenth of full speed an arrow of 2 px showed no
heading; the speed itself is in the metrics, and in `potential`'s colours), an agent at rest none. In a box the
length is fixed for the whole recording; in open space it follows the swarm's extent once the swarm has spread beyond
its initial square (the view zooms out with it), and each frame's length is logged with its arrows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from tflock.field import FieldImage

BOUNDARIES = ("periodic", "reflecting", "open")


@dataclass(frozen=True)
class WorldSpec:
    """Geometry of the simulated world as the recorder needs it."""

    dim: int  # 2 or 3
    boundary: str  # "periodic" | "reflecting" | "open"
    box: float  # side of the box (open space: side of the initial square)
    dt: float = 1.0  # simulated time per step; the `time` timeline is step * dt seconds
    # a periodic 2D world drawn rolled so that this point (named here, e.g. "the virtual agent") stays at the box's
    # centre: the frames' positions are wrap(x - c + box / 2) for the point c; "" = drawn as simulated
    centred_on: str = ""

    def __post_init__(self) -> None:
        if self.dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {self.dim}")
        if self.boundary not in BOUNDARIES:
            raise ValueError(f"boundary must be one of {', '.join(BOUNDARIES)}, got {self.boundary!r}")
        if not self.box > 0:
            raise ValueError(f"box must be positive, got {self.box}")
        if not self.dt > 0:
            raise ValueError(f"dt must be positive, got {self.dt}")
        if self.centred_on and (self.dim != 2 or self.boundary != "periodic"):
            raise ValueError("only a periodic 2D world is drawn centred on a point")

    @property
    def bounded(self) -> bool:
        """Whether the world has walls (periodic or reflecting box) worth drawing."""
        return self.boundary != "open"


@dataclass(frozen=True)
class ColorLegend:
    """What the agents' colours mean, drawn beside the world view: the hue wheel of headings (``wheel``), or named
    colours (a speed ramp's stops, a model's categories) as ``entries`` of (label, (r, g, b)); ``notes``, beside
    either, name marks that are not on the wheel or the ramp (the leader, agents dimmed by asynchrony) in the same
    (label, (r, g, b)) form."""

    title: str
    wheel: bool = False
    entries: tuple[tuple[str, tuple[int, int, int]], ...] = ()
    notes: tuple[tuple[str, tuple[int, int, int]], ...] = ()


#: the leader's colour in the world view (Vicsek's leader following)
LEADER_COLOR = (255, 255, 255)

#: what a frame's edges join, unless the model says otherwise (the recording's about text)
RADIUS_EDGES = "pairs within the interaction radius among the drawn agents"

#: the legend of agents coloured by the hue of their heading (Vicsek, adaptive)
HEADING_LEGEND = ColorLegend("agents: heading", wheel=True)


def axis_bounds(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row's smallest and largest value, for points given as (dim, m) rows (a (m, dim) array's transpose): a
    row at a time, since NumPy 2.4 reduces narrow 2-D arrays along their long axis slowly here (the min over axis 0 of
    50,000 positions took 1.3 ms, a row's 5 us)."""
    return np.array([row.min() for row in rows]), np.array([row.max() for row in rows])


def arrow_length(box: float, drawn: int, dim: int = 2, spread: np.ndarray | None = None) -> float:
    """Scene length of a full-speed agent's arrow: 0.6 of the spacing of the drawn agents in a cube of side L (so
    that arrows of neighbouring agents do not cover each other), at most L / 30 (about 30 px when the swarm fills a
    900 px view). L is the box; in open space pass the drawn agents' positions as ``spread``: L is then the larger of
    the box and their extent (the longest side of their bounding box), so that arrows stay legible while a swarm
    spreads far beyond its initial square and the viewer zooms out to show it."""
    side = box
    if spread is not None and len(spread):
        low, high = axis_bounds(np.asarray(spread, dtype=np.float64).T)
        side = max(side, float((high - low).max()))
    spacing = side / max(drawn, 1) ** (1.0 / dim)
    return float(min(0.6 * spacing, side / 30.0))


#: the shortest arrow drawn for a moving agent, as a fraction of a full-speed agent's arrow (see the module docstring)
MIN_ARROW = 1 / 3


def drawn_arrows(directions: np.ndarray, length: float) -> np.ndarray:
    """(M, dim) float32 vectors of the arrows of `directions` (velocities relative to the reference speed): `length`
    scene units per unit, at least ``MIN_ARROW * length`` long where the direction is not zero."""
    directions = np.asarray(directions, dtype=np.float32)
    # in units of the reference speed (no overflow); a product with ones: 0.03 ms for 50k rows, einsum's took 0.25
    norm2 = np.square(directions) @ np.ones(directions.shape[1], np.float32)
    short = (norm2 < np.float32(MIN_ARROW**2)) & (norm2 > 0)
    if short.any():  # rare where agents keep their speed (Vicsek): no copy then
        directions = directions.copy()
        directions[short] *= np.sqrt(np.float32(MIN_ARROW**2) / norm2[short])[:, None]
    return directions * np.float32(length)


@dataclass
class Marker:
    """A named object drawn on its own entity ``world/<name>``: a point, an optional arrow and an optional circle
    of radius ``circle`` around it (2D; e.g. the virtual agent and its interaction radius)."""

    name: str
    position: np.ndarray  # (dim,)
    direction: np.ndarray | None = None  # (dim,) arrow, scaled by the frame's arrow_length * 1.5
    circle: float | None = None  # radius of a circle drawn around the point (2D only)
    color: tuple[int, int, int] = (255, 255, 255)
    size: float = 2.5  # point radius, in multiples of the agents' point radius


@dataclass
class Frame:
    """What is drawn at one step (already subsampled by the caller). Arrays are converted to float32."""

    positions: np.ndarray  # (M, dim) float32
    directions: np.ndarray  # (M, dim) velocities over the step just made / the reference speed (module docstring)
    arrow_length: float  # scene length of a direction of length 1
    colors: np.ndarray | None = None  # (M, 3) uint8; None: hue of the heading angle atan2(y, x)
    edges: np.ndarray | None = None  # (E, 2, dim) neighbour pairs among the drawn agents, one LineStrips entity
    leader: np.ndarray | None = None  # (dim,) leader position, drawn bigger in white at world/leader
    leader_direction: np.ndarray | None = None  # (dim,) leader heading; drawn as an arrow when given
    markers: list[Marker] = field(default_factory=list)  # other objects, each at world/<name> (same set each frame)
    profiles: dict[str, np.ndarray] = field(default_factory=dict)  # 1D series of all agents, e.g. a density profile
    ids: np.ndarray | None = None  # (M,) agent ids of the rows, shown when hovering an agent
    fields: list[FieldImage] = field(default_factory=list)  # the coarse-grained field of all agents (tflock.field)


#: steps of the hue wheel: 256 per sixth, one per 8-bit colour level
_WHEEL = 1536


def _wheel() -> np.ndarray:
    hue6 = np.arange(_WHEEL) * (6.0 / _WHEEL)  # angle / (2 pi) * 6
    k = np.mod(np.array([5.0, 3.0, 1.0]) + hue6[:, None], 6.0)
    return np.rint((1.0 - np.clip(np.minimum(k, 4.0 - k), 0.0, 1.0)) * 255.0).astype(np.uint8)


def color_table(rgb: np.ndarray) -> np.ndarray:
    """(K, 3) uint8 colours as K opaque RGBA elements of 4 bytes each, for :func:`look_up`."""
    rgba = np.concatenate([rgb, np.full((len(rgb), 1), 255, np.uint8)], axis=1)
    return np.ascontiguousarray(rgba).view(np.uint32).ravel()


def look_up(table: np.ndarray, index: np.ndarray) -> np.ndarray:
    """The colours ``table[index]`` of a :func:`color_table` as an (M, 3) uint8 array (a view of M RGBA rows): one
    4-byte gather per colour, where indexing (K, 3) rows gathers them byte by byte."""
    return table.take(index).view(np.uint8).reshape(-1, 4)[:, :3]


_PALETTE = color_table(_wheel())


def angle_colors(angles: np.ndarray) -> np.ndarray:
    """Colour each planar angle (radians) on the HSV wheel (full saturation and value): an (M, 3) uint8 array;
    angle 0 is red, 2 pi / 3 green, 4 pi / 3 blue. A table of 1536 hues (one step per colour level), so colouring a
    frame is one gather."""
    steps = np.rint(np.asarray(angles, dtype=np.float32) * np.float32(_WHEEL / (2 * math.pi))).astype(np.int64)
    return look_up(_PALETTE, steps % _WHEEL)


def heading_colors(directions: np.ndarray) -> np.ndarray:
    """:func:`angle_colors` of each direction's planar angle ``atan2(y, x)``."""
    d = np.asarray(directions, dtype=np.float32)
    return angle_colors(np.arctan2(d[:, 1], d[:, 0]))
