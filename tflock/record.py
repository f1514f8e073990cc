"""Rerun recording for tflock: the only module that talks to Rerun.

The simulation hands a :class:`Recorder` plain NumPy arrays (a :class:`Frame` per drawn step and a mapping of
metric values); the recorder lays them out as described in DESIGN.md section 5, for a person to read at the
default view (docs/recordings.md shows and explains it):

* timelines ``step`` (sequence) and ``time`` (duration, ``step * dt`` seconds); ``log_time`` is disabled so a
  recording only depends on what was logged;
* ``world/agents`` (Points2D/3D, sizes in UI points so that agents show at any box size; hovering one shows its agent
  id), ``world/agents/headings`` (Arrows2D/3D, the velocity over the step just made, with the frame's
  ``arrow_length``, see :mod:`tflock.frame`), ``world/agents/trails`` (optional), ``world/edges`` (thin translucent
  LineStrips among the drawn agents), ``world/leader`` (+ ``world/leader/heading``), ``world/<marker>``,
  ``world/bounds`` (static), ``world/extent`` (open space, 2D: invisible points that frame the view, see
  :func:`view_corners`); in 2D ``world`` carries a transform that flips y, so that y points up as in the
  simulation's frame;
* the coarse-grained field of all agents (:mod:`tflock.field`): a SegmentationImage under the agents at
  ``world/field`` (2D), or three projections ``field/xy``, ``field/xz``, ``field/yz`` beside the 3D view;
* ``legend``: what the colours mean (heading wheel, speed ramp or categories; the field's colours);
* ``metrics/<name>``: one Scalars series per metric, plotted in groups (per-agent series in one plot, min / mean /
  max together, energies together; series constant over the run in one plot of their own, a strip under the last
  metrics tab), as lines, or as points for angles wrapped into [0, 2 pi) (a line would cross the plot at a wrap);
* ``profiles/<name>``: a BarChart per drawn frame for each 1D profile the model declares (e.g. the density along
  the mean heading, which shows travelling bands), each in a tab of its own;
* ``about`` (what is drawn, every metric's description), ``config`` (the resolved TOML) and ``meta`` (static);
* a default blueprint: the world view largest, the legend beside it, the plots and documents in tabs below it,
  side panels collapsed.

:func:`read_recording`, :func:`verify_recording` and :func:`open_viewer` serve ``tflock inspect`` /
``tflock view`` and the tests.
"""

from __future__ import annotations

import contextlib
import csv
import math
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Any
from urllib.parse import quote

import numpy as np
import pyarrow as pa
import rerun as rr
import rerun.blueprint as rrb
from rerun import encodings

from tflock.field import CLASSES, FieldImage, class_colors, class_labels, class_of
from tflock.frame import (
    BOUNDARIES,
    LEADER_COLOR,
    MIN_ARROW,
    RADIUS_EDGES,
    ColorLegend,
    Frame,
    Marker,
    WorldSpec,
    angle_colors,
    axis_bounds,
    drawn_arrows,
    heading_colors,
)
from tflock.frame_columns import GATHER_AGENTS, FrameColumns, Shape, line_strips, time_columns
from tflock.metric_log import MetricRows

__all__ = [
    "BOUNDARIES",
    "ColorLegend",
    "Frame",
    "Recorder",
    "RecordingSummary",
    "WorldSpec",
    "heading_colors",
    "metric_groups",
    "open_viewer",
    "read_recording",
    "rerun_executable",
    "verify_recording",
]

WORLD = "world"
AGENTS = "world/agents"
HEADINGS = "world/agents/headings"
TRAILS = "world/agents/trails"
EDGES = "world/edges"
LEADER = "world/leader"
LEADER_HEADING = "world/leader/heading"
BOUNDS = "world/bounds"
VIEW_EXTENT = "world/extent"
FIELD_2D = "world/field"
FIELD_3D = "field"
LEGEND = "legend"
ABOUT = "about"
CONFIG = "config"
META = "meta"
METRICS = "metrics"
PROFILES = "profiles"

SPAWN_PORT = 9876
#: seconds a viewer started by --spawn may take to listen (its first start on a machine loads its shaders)
SPAWN_TIMEOUT_S = 30.0
#: seconds a new viewer must keep running once it listens: it listens before it opens its window, and exits where
#: the graphics driver cannot draw what it needs (about 0.1 s later on this project's VM under Xvfb)
SPAWN_GRACE_S = 1.5
EDGE_COLOR = (200, 200, 200, 110)
#: the colours view's names of marks drawn in their own colours (notes, the field's levels and headings)
NAME_COLOR = (200, 200, 200)
#: a 3D box's camera, from the box's centre, in box sides: in front, to the right and above, far enough for the
#: whole box in the world view of the default layout
EYE_OFFSET = np.array([0.95, -1.5, 0.85])
#: the lines of a plot of several series, in this order (the "tab10" palette: ten hues far apart; the viewer's own
#: colours come from a hash of each entity path and may nearly repeat, as gnf_std's box L/8 and L/16 did)
SERIES_COLORS = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                 (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207))
BOUNDS_COLOR = (200, 200, 200)
#: draw order in the 2D world view: the field at the back, then edges, trails, arrows, agents, leader and markers
DRAW_FIELD, DRAW_EDGES, DRAW_TRAILS, DRAW_ARROWS, DRAW_AGENTS, DRAW_MARKERS = -20.0, 0.0, 5.0, 10.0, 20.0, 30.0
#: a marker's circle: 97 points round the unit circle, the last on the first
_UNIT_ANGLES = np.linspace(0.0, 2 * math.pi, 97, dtype=np.float32)
_UNIT_CIRCLE = np.stack([np.cos(_UNIT_ANGLES), np.sin(_UNIT_ANGLES)], axis=1)
#: screen pixels a unit of the colours view at the default layout (about 45 at 1280 x 800 and 1600 x 1000)
LEGEND_PX = 45.0
#: how far a legend's text label is raised above the row it names, in legend units: the viewer hangs a point's label
#: below the point (the label's top edge at the point, about 20 px high), so a label anchored 11 px up is level
#: with the swatches of its row
LABEL_RISE = 11.0 / LEGEND_PX
#: the height of the colours view's titles (their labels hang below it), clear of the wheel's 90° label
TITLE_Y = -2.05
#: half a legend dot's width (6 UI points of radius) and a little margin, in legend units
DOT_HALF_WIDTH = 8.0 / LEGEND_PX


def _label_width(text: str) -> float:
    """The width of a label in legend units (about 7 px a character and 10 px of padding): the viewer centres a
    label on its point, so a label's point goes half its width right of where its text should start."""
    return (7.0 * len(text) + 10.0) / LEGEND_PX


def _legend_row(k: float) -> float:
    """The height of row k of the colours view's columns of dots (the notes, the field's swatches)."""
    return -0.9 + 0.55 * k


def _legend_names(start: float, rows: Iterable[float], labels: list[str], colors: Any) -> rr.Points2D:
    """Names whose text starts at x = `start`, each level with the dots of its row (:data:`LABEL_RISE`)."""
    where = [(start + _label_width(label) / 2, y - LABEL_RISE) for label, y in zip(labels, rows, strict=True)]
    return rr.Points2D(np.array(where, np.float32), radii=0.0, labels=labels, colors=colors, show_labels=True)


#: metric rows are handed to Rerun as columns (one call per metric for many rows, where logging each value was one
#: call each: 35 metrics of a small swarm's run cost about 2 ms a row) once this many rows or seconds have gathered,
#: and whenever the recording is flushed or closed, so a live viewer lags by at most the seconds
METRIC_BATCH_ROWS, METRIC_BATCH_S = 256, 0.5
#: Rerun's batcher sends its pending rows on once they hold this many bytes (see :func:`batcher_config`)
FLUSH_NUM_BYTES = 256 * 1024
_METRIC_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")
_TOML_BLOCK = re.compile(r"^(`{3,})toml\n(.*?)\n\1[ \t]*$", re.DOTALL | re.MULTILINE)


def _packed_rgba(rgb: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 colours as Rerun's packed 0xRRGGBBAA uint32 (opaque). Rerun converts RGB rows itself, but
    element by element, which dominated the logging of a large frame."""
    c = rgb.astype(np.uint32)
    return (c[:, 0] << 24) | (c[:, 1] << 16) | (c[:, 2] << 8) | np.uint32(255)


def _f32(name: str, a: np.ndarray, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``a`` as a C-contiguous float32 array, checking its shape (None: any length)."""
    arr = np.ascontiguousarray(a, dtype=np.float32)
    if arr.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, arr.shape, strict=True)):
        want = "(" + ", ".join("M" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"Frame.{name} must have shape {want}, got {arr.shape}")
    return arr


def point_radius(drawn: int) -> float:
    """Radius of the drawn agents in UI points (screen pixels at 100 % zoom): about 2 for 2000 agents, from 4 for a
    handful down to 1.25 (2.5 px across) for tens of thousands, so that agents show at the default view at any
    box size while a dense sample does not merge into one blot."""
    return float(np.clip(90.0 / math.sqrt(max(drawn, 1)), 1.25, 4.0))


#: statistics suffixes and prefixes grouped into one plot (``valency_min``, ``mean_neighbors``, ...)
_STATS = ("min", "mean", "max")
_INDEXED = re.compile(r"^(.+)_(\d+)$")
#: what the number of an indexed series ``<base>_<i>`` is, where it is not an agent id: base -> series name
#: (``gnf_std_8``: the number fluctuations in boxes of side L/8, :mod:`tflock.observables`)
INDEX_NAMES = {"gnf_std": "box L/{}"}


#: the margin the open-space world view keeps around the drawn agents, as a fraction of their extent
VIEW_MARGIN = 0.06


def view_corners(pos: np.ndarray, vectors: np.ndarray) -> np.ndarray | None:
    """(2, dim) float32 points whose region of interest in the viewer is the box an open-space 2D view should show:
    the drawn agents and their arrows' tips, with :data:`VIEW_MARGIN` of their extent (at least one arrow's length)
    around them. The viewer frames a 2D view without set bounds on the union of its entities' regions of interest,
    each the mean +- 2 standard deviations of the entity's points per axis (Rerun's ``RobustBounds``; with 0.41 two
    points at +-h framed +-2h, seen in a screenshot): the agents' alone cut an agent at the swarm's edge in half.
    Two points at the box's centre +- a quarter of its sides have mean the centre and standard deviation half of
    each half-side, so their region is the box itself; they are logged invisible (``world/extent``). None where no
    drawn agent is finite (float32 frames of a float64 run far out)."""
    pos = np.array(pos.T, dtype=np.float64)  # (dim, m) rows: fast reductions; float64: no overflow below
    vectors = np.array(vectors.T, dtype=np.float64)
    with np.errstate(invalid="ignore"):  # inf - inf where a float32 frame overflowed
        tips = pos + vectors
    if not (np.isfinite(pos).all() and np.isfinite(tips).all()):
        finite = np.isfinite(pos).all(axis=0) & np.isfinite(tips).all(axis=0)
        if not finite.any():
            return None
        pos, vectors, tips = pos[:, finite], vectors[:, finite], tips[:, finite]
    (lo_pos, hi_pos), (lo_tips, hi_tips) = axis_bounds(pos), axis_bounds(tips)
    lo, hi = np.minimum(lo_pos, lo_tips), np.maximum(hi_pos, hi_tips)
    arrow = float(np.sqrt(sum(row * row for row in vectors).max()))
    pad = max(VIEW_MARGIN * float((hi - lo).max()), arrow, 1e-6)
    centre, half = (lo + hi) / 2, (hi - lo) / 2 + pad
    big = float(np.finfo(np.float32).max)
    return np.clip(np.stack([centre - half / 2, centre + half / 2]), -big, big).astype(np.float32)


def _series_color(k: int, members: Sequence[Any]) -> dict[str, tuple[int, int, int]]:
    """The colour of series k of a plot of `members`: :data:`SERIES_COLORS` for 2 to 10 series; none (the viewer's
    own) for one, or for more than the palette holds (the per-agent plots), which it would repeat."""
    return {"colors": SERIES_COLORS[k]} if 1 < len(members) <= len(SERIES_COLORS) else {}


def _profile_title(name: str) -> str:
    """A profile's name in words, as its tab and the about page show it ("band_profile" -> "band profile")."""
    return name.replace("_", " ")


def _markdown_text(text: str) -> str:
    """Plain text as Markdown shows it: its |, _, * and backslashes escaped (a description's |v_i| would otherwise
    be read as a table's cells or emphasis, a <N> as HTML)."""
    return re.sub(r"([\\|_*`<])", r"\\\1", text)


def metric_groups(names: list[str]) -> dict[str, list[tuple[str, str]]]:
    """Plots of related metrics: plot name -> [(metric, short series name)], in the order of first appearance.

    ``<base>_<i>`` (per-agent series, ``speed_3``: "agent 3"; other indices as :data:`INDEX_NAMES` names them,
    ``gnf_std_8``: "box L/8"), ``<base>_<stat>`` and ``<stat>_<base>`` (stat one of min / mean / max:
    ``valency_min``, ``mean_neighbors``) and ``<kind>_energy`` go to the plot ``<base>`` (or ``energy``) with the
    others of their base; every other metric has a plot of its own.
    """
    keyed: dict[str, str] = {}  # metric -> group
    label: dict[str, str] = {}
    for name in names:
        group, short = name, name
        indexed = _INDEXED.match(name)
        head, _, tail = name.partition("_")
        stem, _, last = name.rpartition("_")
        if indexed:
            group = indexed.group(1)
            short = INDEX_NAMES.get(group, "agent {}").format(indexed.group(2))
        elif last in _STATS and stem:
            group, short = stem, last
        elif head in _STATS and tail:
            group, short = tail, head
        elif last == "energy" and stem:
            group, short = "energy", stem
        keyed[name], label[name] = group, short
    members: dict[str, list[str]] = {}
    for name in names:
        members.setdefault(keyed[name], []).append(name)
    out: dict[str, list[tuple[str, str]]] = {}
    for group, names_in in members.items():
        if len(names_in) == 1:  # alone: named as itself
            out[names_in[0]] = [(names_in[0], names_in[0])]
        else:
            out[group] = [(n, label[n]) for n in names_in]
    return out


#: a series whose values span less than this share of its plot's y range is drawn nearly flat (under 11 px of a
#: plot of the default layout): the last layout gives it a plot apart (:func:`readable_groups`)
FLAT_SHARE = 0.1


def value_span(extents: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The smallest low and largest high of series of these (low, high) extents (at least one)."""
    return min(lo for lo, _ in extents), max(hi for _, hi in extents)


def plot_range(extents: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """The y range a plot of series of these (low, high) extents shows: :func:`labelled_range`'s, or the values'
    own (the viewer's fit, less its small margin)."""
    span = value_span(extents)
    return labelled_range(*span) or span


def readable_groups(groups: dict[str, list[tuple[str, str]]],
                    extent: Callable[[str], tuple[float, float] | None]) -> dict[str, list[tuple[str, str]]]:
    """:func:`metric_groups`' plots, each split where its series differ so much in size that some would be drawn
    flat: a series that changes but spans less than :data:`FLAT_SHARE` of its plot's y range (:func:`plot_range`
    of the series' `extent`, their (low, high) so far) moves to another plot, with the others so moved, and that
    plot is split in turn (Vicsek's mean beside its max neighbours, 6-94 on a 0-1000 axis; number fluctuations of
    1-6 agents beside 70-2900). Series with no values yet, or one value, stay. A plot left with one series is named
    after its metric; one of several ``<group> (<k> of <parts>)``, short enough for a plot's title bar (its legend
    names the series)."""
    out: dict[str, list[tuple[str, str]]] = {}
    for group, members in groups.items():
        parts, rest = [], members
        while rest:
            known = [e for e in (extent(m) for m, _ in rest) if e is not None]
            low, high = plot_range(known) if known else (0.0, 0.0)
            flat = [(m, s) for m, s in rest
                    if (e := extent(m)) is not None and 0 < e[1] - e[0] < FLAT_SHARE * (high - low)]
            if not flat or len(flat) == len(rest):  # all alike: split no further
                parts.append(rest)
                break
            parts.append([member for member in rest if member not in flat])
            rest = flat
        if len(parts) == 1:
            out[group] = members
            continue
        parts.sort(key=lambda part: members.index(part[0]))  # in the group's order
        for k, part in enumerate(parts, 1):
            out[part[0][0] if len(part) == 1 else f"{group} ({k} of {len(parts)})"] = part
    return out


#: seconds a live viewer's layout stays at least before the values' split of the plots changes it
#: (:meth:`Recorder._follow_split`)
LIVE_LAYOUT_S = 10.0


#: every plot's time axis spans the whole run, from its first step to its last. Left unset, the viewer derives a
#: plot's range from the data it holds while the file streams in, stores it in the layout and then keeps that range:
#: a 10,000-step Tanner recording opened in the web viewer showed steps 8900-10300 in every plot.
WHOLE_RUN = rrb.TimeAxis(view_range=rr.TimeRange(start=rr.TimeRangeBoundary.infinite(),
                                                 end=rr.TimeRangeBoundary.infinite()))
#: the colours view's spacing of the field's swatch columns (its own units: the wheel's radius is 1), wide enough for
#: a heading's name in degrees under every other column (a label of 4 characters is 38 px wide)
SWATCH_STEP = 0.45
#: plots in a tab at most (3 rows of 2; about 130 px a plot at 1280 x 800, :data:`PLOT_PX`, where 12 left about
#: 70 px, too little for their axis labels): more go to tabs "metrics 2", "metrics 3"
PLOTS_PER_TAB = 6
#: the height of the strip of constant series under a tab's grid, in rows of the grid
STRIP_ROWS = 0.75


def tab_pages(count: int) -> list[tuple[int, int, int]]:
    """The metric tabs' grids of `count` plots: (first plot, plots, columns) of each tab, at most
    :data:`PLOTS_PER_TAB` a tab, in two columns from 4 plots (four in one column under the colours view were 64 px
    high each at 1280 x 800: too low for a legend of two series, and their y axes went unlabelled)."""
    return [(first, on_page := min(PLOTS_PER_TAB, count - first), 2 if on_page >= 4 else 1)
            for first in range(0, count, PLOTS_PER_TAB)]


#: series a plot's legend names at most: six take 143 px (:data:`LEGEND_ROW_PX`), about a plot of the grid's height,
#: more would hide its lines; the title of a plot of more says how to find their names (hover a line)
LEGEND_MAX = 6
#: corners a plot's legend may take, in the order tried (ties go to the first)
LEGEND_CORNERS = ("RightTop", "LeftBottom", "RightBottom", "LeftTop")
#: a plot of the metrics grid in the default layout at 1280 x 800, in pixels (width, height; 3 rows of 2 under the
#: colours view), in which the legend's size below and the labels of :data:`DENSE_MARKS` were measured in the web
#: viewer; a larger window's plots are larger, where the legend takes less
PLOT_PX = (240.0, 130.0)
#: the metric tabs' area in the default layout at 1280 x 800, in pixels: its width, its height under the colours
#: view and without it; each plot of a tab's grid (:func:`plot_px`) loses TILE_MARGIN_PX to its title bar and axes
TABS_PX = (533.0, 520.0, 704.0)
TILE_MARGIN_PX = (26.0, 45.0)
#: a legend's height in pixels: a row of 23 px per series and 5 px between it and the plot's edge (two series: 47 px
#: of box, from 4 px below the plot's top, measured at 1280 x 800)
LEGEND_ROW_PX, LEGEND_EDGE_PX = 23.0, 5.0
#: a legend's width in pixels: 7 px a character of its longest name and 35 px for its dot, padding and margin
LEGEND_CHAR_PX, LEGEND_FRAME_PX = 7.0, 35.0
#: a plot whose legend would cover some of its points in every corner gets a y range with room for the legend above
#: (or below) its values, where that range spans at most this many times the values' (else the values would be
#: drawn too flat: the legend takes the corner where it covers the fewest points)
HEADROOM_MAX = 2.0
#: the margin a range with room for the legend leaves beyond the values at its other end, a fraction of their span
HEADROOM_MARGIN = 0.04


def plot_px(columns: int, rows: float, colours: bool = True) -> tuple[float, float]:
    """The size in pixels of one plot of a metric tab's grid of `columns` x `rows` (a strip counted as its share of a
    row) in the default layout at 1280 x 800, under the colours view or (`colours` False) without it."""
    width, under, alone = TABS_PX
    return width / columns - TILE_MARGIN_PX[0], (under if colours else alone) / rows - TILE_MARGIN_PX[1]


def place_legend(series: list[tuple[Sequence[float], Sequence[float]]], names: Sequence[str],
                 y_range: tuple[float, float] | None = None, headroom: bool = False,
                 size_px: tuple[float, float] = PLOT_PX) -> tuple[str, tuple[float, float] | None]:
    """Where a plot's legend goes: the corner of the plot (one of :data:`LEGEND_CORNERS`) where it covers the fewest
    of the series' points (steps, values), and the plot's y range (`y_range`, None for the viewer's fit). The legend
    of the series `names` is taken as large as measured in the viewer (its longest name's width and a row per
    series) on a plot of `size_px` (:func:`plot_px`), the plot spanning the points' steps and finite values as the
    viewer fits them, or `y_range` where the plot fixes it. With `headroom`, where every corner would cover some
    points, the y range returned is widened at the top (or the bottom) until the legend's corner is clear of them,
    the corner that needs the least widening, at most :data:`HEADROOM_MAX` times the span (only for a run's last
    layout: a fixed range would cut off the values still to come)."""
    steps = np.concatenate([np.asarray(s, np.float64) for s, _ in series]) if series else np.zeros(0)
    values = np.concatenate([np.asarray(v, np.float64) for _, v in series]) if series else np.zeros(0)
    keep = np.isfinite(values)
    steps, values = steps[keep], values[keep]
    if steps.size == 0:
        return LEGEND_CORNERS[0], y_range
    x = (steps - steps.min()) / max(np.ptp(steps), 1e-300)
    low, high = y_range if y_range is not None else (float(values.min()), float(values.max()))
    if not high > low:  # one value (constant series): at half height of a range of its size around it (the
        # viewer's fit of 0 is -1 to 1)
        half = max(1.0, abs(low))
        low, high = low - half, high + half
    y = (values - low) / (high - low)
    longest = max((len(name) for name in names), default=0)
    width = min(1.0, (LEGEND_FRAME_PX + LEGEND_CHAR_PX * longest) / size_px[0])
    height = min(1.0, (LEGEND_EDGE_PX + LEGEND_ROW_PX * len(series)) / size_px[1])
    left, right = x < width, x > 1 - width
    top, bottom = y > 1 - height, y < height
    covered = {"RightTop": right & top, "LeftBottom": left & bottom, "RightBottom": right & bottom,
               "LeftTop": left & top}
    counts = {corner: int(np.count_nonzero(under)) for corner, under in covered.items()}
    best = min(LEGEND_CORNERS, key=lambda corner: counts[corner])  # min keeps the first of equals
    clear = height + HEADROOM_MARGIN  # the legend and a gap under (or above) it
    if counts[best] == 0 or not headroom or clear >= 1:
        return best, y_range
    widened: dict[str, tuple[float, float]] = {}
    for corner in LEGEND_CORNERS:
        band = values[left if corner.startswith("Left") else right]
        if corner.endswith("Top"):  # the band's highest value just under the legend, the range's top moved up
            below = low - (HEADROOM_MARGIN * (high - low) if y_range is None else 0.0)
            widened[corner] = (below, below + (band.max() - below) / (1 - clear))
        else:
            above = high + (HEADROOM_MARGIN * (high - low) if y_range is None else 0.0)
            widened[corner] = (above - (above - band.min()) / (1 - clear), above)
        widened[corner] = (min(widened[corner][0], low), max(widened[corner][1], high))
    corner = min(LEGEND_CORNERS, key=lambda c: widened[c][1] - widened[c][0])
    if widened[corner][1] - widened[corner][0] > HEADROOM_MAX * (high - low):
        return best, y_range
    return corner, widened[corner]


#: decade marks across a plot's values above which Rerun labels none of them on a plot of the default layout at
#: 1280 x 800 (:data:`PLOT_PX`, 130 px high: a plot labels only decades, ... 0.01, 0.1, 1, 10 ..., and only marks
#: about 25 px apart or more): polarization in [0.003, 0.068] (6.5 marks of 0.01) had no labels. A plot of another
#: height labels proportionally as many (min_distance in [0.25, 0.6], 3.5 marks of 0.1, had none 64 px high)
DENSE_MARKS = 4
#: the margin, a fraction of the range, that :func:`labelled_range` leaves beyond its two labelled marks
LABEL_MARGIN = 0.08


def labelled_range(low: float, high: float, height_px: float = PLOT_PX[1]) -> tuple[float, float] | None:
    """A fixed y range for a plot of values in [low, high] that would otherwise have no labels on its axis: where
    the values span more marks of their decade than a plot `height_px` high labels (:data:`DENSE_MARKS` on one of
    the default grid's, 130 px) and lie between two neighbouring marks of the decade above (the next labelled ones),
    those two with a margin: the values then fill at least a third of the plot, between two labelled marks. Else
    None: the viewer's own fit, which labels the marks of the values' decade, or one mark of the decade above
    inside the values (see :func:`enclosing_marks`). A larger window's taller plots would label the finer marks too,
    but the range stays readable."""
    span = high - low
    if not (math.isfinite(span) and span > 0):
        return None
    decade = 10.0 ** math.floor(math.log10(span))
    if span / decade <= DENSE_MARKS * height_px / PLOT_PX[1]:
        return None
    step = 10 * decade
    bottom = math.floor(low / step + 1e-9) * step  # (0.3 / 0.1 is 2.9999999999999996)
    top = bottom + step
    if high > top + 1e-9 * step:
        return None
    margin = LABEL_MARGIN * step  # (a mark on the plot's edge is not labelled)
    return bottom - margin, top + margin


#: how far beyond its values, a fraction of their span, a mark still counts as on a plot the viewer fits to them
#: (Tanner's kinetic energy, 0.00001 to 1.3, was labelled at 0 and 1)
FIT_MARGIN = 0.02


def enclosing_marks(low: float, high: float) -> tuple[float, float] | None:
    """A fixed y range for values in [low, high] among which lies only one mark of their decade (Tanner's Q, -17.5 to
    -4.9, labelled only at -10; `potential`'s, -156,000 to -14,000, only at -100,000): the marks on either side of
    the values, with a margin, if that at most doubles the span: three labels, the values filling at least half the
    plot. Else None (two marks or more among the values, or too much room)."""
    span = high - low
    if not (math.isfinite(span) and span > 0):
        return None
    decade = 10.0 ** math.floor(math.log10(span))
    near = FIT_MARGIN * span  # a mark just beyond the values is in the viewer's fit, and labelled
    if math.floor((high + near) / decade + 1e-9) > math.ceil((low - near) / decade - 1e-9):
        return None
    bottom = math.floor(low / decade + 1e-9) * decade
    top = math.ceil(high / decade - 1e-9) * decade
    if top - bottom > 2 * span:
        return None
    margin = LABEL_MARGIN * (top - bottom)
    return bottom - margin, top + margin


def _has_display() -> bool:
    """Whether a native viewer window can open (always assumed off Linux)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def _check_writable(path: Path, what: str) -> Path:
    """Create ``path``'s parent and open the file for writing, turning failures into one clear OSError."""
    path = Path(path).expanduser()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb"):
            pass
    except OSError as e:
        reason = e.strerror or str(e)
        raise OSError(e.errno, f"cannot write the {what} to {path}: {reason}") from e
    return path


def batcher_config() -> rr.ChunkBatcherConfig | None:
    """Rerun's batching with :data:`FLUSH_NUM_BYTES` in place of its 2 MiB default, unless RERUN_FLUSH_NUM_BYTES is
    set (None: Rerun reads its environment). With the default, a frame of 50k agents (0.6 MB of points, 1 MB of
    arrows) waits for the next and the two are copied into one chunk, in fresh pages; sent on alone, each row is
    its own chunk, with no copy and far fewer page faults (see docs/performance.md, Logging).
    Rerun's other thresholds (its 200 ms tick, the RERUN_FLUSH_TICK_SECS it reads) still gather small rows."""
    if "RERUN_FLUSH_NUM_BYTES" in os.environ:
        return None
    return rr.ChunkBatcherConfig(flush_num_bytes=FLUSH_NUM_BYTES)


class Recorder:
    """Writes a tflock run to Rerun (file, native viewer and/or a running viewer) and a metrics CSV.

    Use as a context manager or call :meth:`close` in a ``finally:``; closing finalises the ``.rrd`` file (its
    footer) so that ``rerun rrd verify`` passes even after Ctrl-C or SIGTERM mapped to KeyboardInterrupt.
    With none of ``path`` / ``spawn`` / ``connect`` the Rerun side is disabled (``enabled`` is False) and only
    the metrics table is written.
    """

    def __init__(
        self,
        *,
        model: str,
        config_toml: str,
        world: WorldSpec,
        metrics: Mapping[str, str],
        profiles: Mapping[str, str] | None = None,
        angles: tuple[str, ...] = (),
        edges: str = RADIUS_EDGES,
        first_plots: tuple[str, ...] = (),
        path: Path | None = None,
        spawn: bool = False,
        connect: str | None = None,
        metrics_table: Path | None = None,
        application_id: str = "tflock",
        recording_id: str | None = None,
        legend: ColorLegend | None = None,
        field: bool = False,
        trail: int = 0,
        drawn: str = "",
    ) -> None:
        """``recording_id``: give a resumed run's new file the id of the first one, so that the viewer shows the
        segments (``rerun first.rrd resumed.rrd``) as one recording on the same timelines. ``legend``: what the
        agents' colours mean (default: no colour legend); ``field``: frames carry the field of all agents (its
        views and legend are laid out); ``trail``: draw each drawn agent's last `trail` positions; ``drawn``: one
        line on what is drawn (e.g. "2000 of 100000 agents"), for the about document; ``angles``: metrics that are
        angles wrapped into [0, 2 pi), plotted as points (a line would cross the plot where the angle wraps);
        ``edges``: what the frames' edges join, for the about document; ``first_plots``: metrics whose plots come
        first, in this order (the others follow in the metrics' order)."""
        for name in metrics:
            if not _METRIC_NAME.match(name):
                raise ValueError(f"metric name {name!r} must be letters, digits, '_' or '-'")
        if spawn and not _has_display():
            raise RuntimeError(
                "--spawn needs a display (no DISPLAY is set); watch the run in a browser instead: start "
                "`tflock view --live --web` and pass the URL it prints to --connect"
            )
        if spawn:  # before any file is made: a viewer that cannot start leaves none
            spawn_viewer(SPAWN_PORT)
        self.model = model
        self.config_toml = config_toml
        self.world = world
        self.metrics = dict(metrics)
        self.profiles = dict(profiles or {})  # name -> description of the frames' profiles (one bar chart each)
        self.angles = tuple(angles)
        self.first_plots = tuple(first_plots)
        self.edges = edges
        self.path = _check_writable(path, "recording") if path is not None else None
        self.metrics_table = _check_writable(metrics_table, "metrics table") if metrics_table else None
        self.legend = legend
        self.field = field
        self.trail = trail
        self.drawn = drawn
        self._closed = False
        self._edges_drawn = False
        self._leader_drawn = False
        self._leader_heading_drawn = False
        self._profile_axes: set[str] = set()  # profiles whose bars' positions are logged (static, see log_frame)
        self._ids: np.ndarray | None = None  # agent ids of the rows last logged
        self._arrow_length: float | None = None  # the arrow length last logged
        self._trail: list[np.ndarray] = []  # the drawn agents' last positions, oldest first
        self._rows = MetricRows(list(self.metrics))  # rows not yet handed to Rerun, where the legends go
        self._pending_since = time.monotonic()
        self._styles: float | None = None  # point radius of the styles logged for gathered frames
        self._shape_styles: dict[str, str] = {}  # the style logged for each of the gathered frames' other shapes
        self._shown: list[tuple[str, list[tuple[str, str]]]] = []  # the plots of the layout a live viewer shows
        self._shown_at = 0.0  # when that layout was sent (time.monotonic)

        sinks: list[rr.FileSink | rr.GrpcSink] = []
        if self.path is not None:
            sinks.append(rr.FileSink(self.path))
        if connect:
            sinks.append(rr.GrpcSink(connect))
        self.enabled = bool(sinks) or spawn
        self.live = bool(spawn or connect)  # a viewer watches the run as it goes
        self.rec = rr.RecordingStream(application_id, recording_id=recording_id, default_enabled=self.enabled,
                                      batcher_config=batcher_config())
        self.rec.set_log_time_enabled(False)
        self._frames = FrameColumns(self.rec, world.dim, world.dt, AGENTS, HEADINGS, EDGES, PROFILES)
        self._csv_file: IO[str] | None = None
        try:
            if self.metrics_table is not None:
                self._csv_file = open(self.metrics_table, "w", newline="", encoding="utf-8")
                self._csv = csv.writer(self._csv_file)
                self._csv.writerow(["step", "time", *self.metrics])
                self._csv_file.flush()
            if self.enabled:
                if spawn:
                    sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{SPAWN_PORT}/proxy"))
                # a file's layout is its default (the viewer keeps one the user made for tflock's recordings); a
                # viewer that watches gets this run's layout at once: it would else keep the layout an earlier run
                # streamed to it made active, with that run's plots, empty if this run's metrics differ
                self.rec.set_sinks(*sinks, default_blueprint=None if self.live else self.blueprint())
                if self.live:
                    self.rec.send_blueprint(self.blueprint(), make_active=True, make_default=True)
                    self._shown, self._shown_at = self._plot_split(), time.monotonic()
                self._log_static()
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ layout
    def blueprint(self, constant: tuple[str, ...] = (), final: bool = False) -> rrb.Blueprint:
        """The default layout: the world view largest on the left (in 3D above the field's three projections); on
        the right the colour legend above tabs of the metric plots (:meth:`_metric_tabs`; the `constant` series
        in one plot of their own, last), the profiles' bar charts, the about document and the
        config. Side panels collapsed, the time panel a single bar. `final`: the run's last layout, whose plots may
        fix their y ranges to make room for their legends (:meth:`_legend`)."""
        world = self.world
        if world.dim == 2:
            bounds = None
            if world.bounded:
                margin = 0.02 * world.box
                bounds = rrb.VisualBounds2D(x_range=[-margin, world.box + margin],
                                            y_range=[-world.box - margin, margin])  # the flipped y of `world`
            name = f"world, centred on {world.centred_on}" if world.centred_on else "world"
            world_view: rrb.View = rrb.Spatial2DView(name=name, origin="/", contents=[f"/{WORLD}/**"],
                                                     visual_bounds=bounds)
        else:
            eye = None
            if world.bounded:  # the whole box in view (the viewer's own fit cut its lower front edges)
                centre = np.full(3, world.box / 2)
                eye = rrb.EyeControls3D(position=centre + world.box * EYE_OFFSET, look_target=centre,
                                        eye_up=[0.0, 0.0, 1.0])
            world_view = rrb.Spatial3DView(name="world", origin=f"/{WORLD}", eye_controls=eye)
        left: rrb.Container | rrb.View = world_view
        if self.field and world.dim == 3:  # the projections in a row under the 3D view
            projections = [rrb.Spatial2DView(name=f"field {plane}", origin=f"/{FIELD_3D}",
                                             contents=[f"/{FIELD_3D}/{plane}/**"]) for plane in ("xy", "xz", "yz")]
            left = rrb.Vertical(world_view, rrb.Horizontal(*projections), row_shares=[3, 1])
        metrics = self._metric_tabs(constant, final)
        # named in words, no legend (its one entry would be the entity path); the about page says what the bars are
        profiles = [rrb.BarChartView(name=_profile_title(n), origin=f"/{PROFILES}/{n}",
                                     plot_legend=rrb.PlotLegend(visible=False)) for n in self.profiles]
        tabs = [*metrics, *profiles, rrb.TextDocumentView(name="about", origin=f"/{ABOUT}"),
                rrb.TextDocumentView(name="config", origin=f"/{CONFIG}")]
        right: rrb.Container | rrb.View = rrb.Tabs(*tabs, active_tab=0)
        if self._has_legend():
            right = rrb.Vertical(rrb.Spatial2DView(name="colours", origin=f"/{LEGEND}"), right, row_shares=[1, 3])
        return rrb.Blueprint(
            # the world about as wide as it is high at 1280 x 800 (a square box drawn no smaller than with a wider
            # view), the rest to the plots: at 3 : 2 a title of 22 characters was cut off in the plots' grid
            rrb.Horizontal(left, right, column_shares=[7, 5]),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", timeline="step"),
        )

    def _has_legend(self) -> bool:
        return self.legend is not None or self.field

    def _metric_tabs(self, constant: tuple[str, ...], final: bool = False) -> list[rrb.Container | rrb.View]:
        """The metric plots in tabs of at most :data:`PLOTS_PER_TAB` ("metrics", "metrics 2", ...), in two columns
        from 4 (:func:`tab_pages`); the plot of the `constant` series takes no place in a tab's grid: it is a strip
        under the last tab, three quarters of a row high, as a flat line needs little height (Vicsek's 12 plots and
        its constant one in two tabs, where a third tab held that one plot alone)."""
        plots = self._plots(constant, final)
        strip = plots.pop() if constant and len(plots) > 1 else None
        pages = tab_pages(len(plots))
        tabs: list[rrb.Container | rrb.View] = []
        for k, (first, on_page, columns) in enumerate(pages):
            name = "metrics" if k == 0 else f"metrics {k + 1}"
            page = plots[first:first + on_page]
            tab: rrb.Container | rrb.View = rrb.Grid(*page, grid_columns=columns, name=name) if on_page > 1 \
                else page[0]
            if strip is not None and k == len(pages) - 1:
                tab = rrb.Vertical(tab, strip, row_shares=[-(-on_page // columns), STRIP_ROWS], name=name)
            tabs.append(tab)
        return tabs

    def _plot_sizes(self, count: int, strip: bool) -> list[tuple[float, float]]:
        """The size in pixels (:func:`plot_px`) of each of `count` plots as :meth:`_metric_tabs` lays them out in
        the default layout at 1280 x 800, the last of them the strip of constant series where `strip`."""
        colours = self._has_legend()
        sizes: list[tuple[float, float]] = []
        pages = tab_pages(count - 1 if strip else count)
        rows = 1.0
        for k, (_, on_page, columns) in enumerate(pages):
            last = strip and k == len(pages) - 1  # the strip: under the last tab's grid
            rows = -(-on_page // columns) + (STRIP_ROWS if last else 0.0)
            sizes += [plot_px(columns, rows, colours)] * on_page
        if strip:  # its share of the last tab's rows
            sizes.append(plot_px(1, rows / STRIP_ROWS, colours))
        return sizes

    def _plots(self, constant: tuple[str, ...], final: bool = False) -> list[rrb.TimeSeriesView]:
        """One plot per group of related metrics (:func:`metric_groups`, split where their sizes differ too much:
        :func:`readable_groups`), the groups of ``first_plots`` first, constant series in one plot, last; `final`:
        the run's last layout (:meth:`_legend`)."""
        varying = [n for n in self.metrics if n not in constant]
        groups = readable_groups(metric_groups(varying), self._rows.extent)
        first = [g for m in self.first_plots for g, members in groups.items() if m in dict(members)]
        order = list(dict.fromkeys([*first, *groups]))  # the first plots', then the rest in the metrics' order
        count = len(order) + (1 if constant else 0)
        sizes = self._plot_sizes(count, bool(constant) and count > 1)
        views = []
        for group, size in zip(order, sizes[:len(order)], strict=True):
            members = groups[group]
            names = [m for m, _ in members]
            title = group if len(names) <= LEGEND_MAX else f"{group} (hover names)"
            legend, y_range = self._legend(members, self._y_range(names, size, final), final, size)
            views.append(rrb.TimeSeriesView(
                name=title, origin=f"/{METRICS}", contents=[f"/{METRICS}/{m}" for m in names],
                plot_legend=legend, axis_x=WHOLE_RUN,
                axis_y=None if y_range is None else rrb.ScalarAxis(range=y_range)))
        if constant:  # one: named in the title; more: named in the legend (a long title is cut off), by their full
            # names: a series' short name is that of its group's plot ("min" of valency_min); too many for a legend:
            # the title says how to find them
            title = "constant" + (f": {constant[0]}" if len(constant) == 1 else "")
            if len(constant) > LEGEND_MAX:
                title = f"constant: {len(constant)} series (hover a line for its name)"
            legend, y_range = self._legend([(m, m) for m in constant], None, final, sizes[-1])
            views.append(rrb.TimeSeriesView(
                name=title, origin=f"/{METRICS}", contents=[f"/{METRICS}/{m}" for m in constant], plot_legend=legend,
                axis_x=WHOLE_RUN, axis_y=None if y_range is None else rrb.ScalarAxis(range=y_range),
                overrides={f"/{METRICS}/{m}": rr.SeriesLines(names=m, **_series_color(k, constant))
                           for k, m in enumerate(constant)}))
        return views

    def _y_range(self, members: list[str], size: tuple[float, float] = PLOT_PX,
                 final: bool = False) -> tuple[float, float] | None:
        """A plot's fixed y range: :func:`labelled_range` of its series' values so far on a plot of `size` pixels, or
        in a run's `final` layout :func:`enclosing_marks`' (while a run goes on, its values may still outgrow a
        range fixed around those so far), or None (the viewer's fit)."""
        extents = [e for e in (self._rows.extent(m) for m in members) if e is not None]
        if not extents:
            return None
        low, high = value_span(extents)
        return labelled_range(low, high, size[1]) or (enclosing_marks(low, high) if final else None)

    def _legend(self, members: list[tuple[str, str]], y_range: tuple[float, float] | None = None,
                final: bool = False, size: tuple[float, float] = PLOT_PX
                ) -> tuple[rrb.PlotLegend, tuple[float, float] | None]:
        """A plot's legend of its (metric, name in the legend) `members` and its y range (`y_range`, None: the
        viewer's fit), on a plot of `size` pixels: the legend shown for 2 to LEGEND_MAX series, in the corner where it
        covers the fewest of their points so far; in a run's `final` layout, the range widened for it where it would
        cover some in every corner (:func:`place_legend`)."""
        if not 1 < len(members) <= LEGEND_MAX:
            return rrb.PlotLegend(visible=False), y_range
        corner, y_range = place_legend([self._rows.series(m) for m, _ in members], [name for _, name in members],
                                       y_range, headroom=final, size_px=size)
        return rrb.PlotLegend(getattr(rrb.components.Corner2D, corner), visible=True), y_range

    def _about(self) -> str:
        """Markdown: what the world view draws and every metric's description, by plot as the layout groups them
        (:func:`readable_groups` of the values so far: none at the start, so no group is split there)."""
        world = self.world
        lines = ["# What the views show", ""]
        lines.append(f"**world**: {self.drawn or 'the agents'}; {world.dim}D, {world.boundary} boundary, box "
                     f"{world.box:g}" + (", y up" if world.dim == 2 else "") + ". Hover an agent for its id.")
        if world.centred_on:
            lines.append("")
            lines.append(f"The periodic box is drawn centred on {world.centred_on}: a point x of the world is drawn "
                         f"at wrap(x - c + {world.box:g} / 2), c being {world.centred_on}'s position: the view follows "
                         f"it, and the agents around it are never cut apart by the box's edge. Drawn coordinates are "
                         f"relative to it (it is drawn at the box's centre); the metrics table and checkpoints hold "
                         f"the world's own.")
        lines.append("")
        lines.append("- **arrows**: each agent's velocity over the step just made, relative to the model's reference "
                     "speed (a full-speed agent's arrow has the same length in every frame); a slower agent's arrow is "
                     f"at least {MIN_ARROW:.2g} of a full-speed one, so that its heading stays readable.")
        lines.append(f"- **edges**: {self.edges} (the graph induced on the first drawn agents, as many as the edge "
                     "cap allows).")
        if self.field:
            if world.dim == 2:
                where, hue = "under the agents", "the pixel's mean heading"
            else:  # each projection's pixels take the agents' hue: their headings' direction in the xy plane
                where = "in the three projection views"
                hue = ("the pixel's mean heading in the xy plane (its azimuth), in every projection, as the agents are "
                       "coloured")
            lines.append(f"- **field** ({where}): all agents binned into pixels; hue = {hue}, brighter = denser "
                         "(relative to the mean density), greyish = disordered. Hover a pixel.")
        if self.trail:
            lines.append(f"- **trails**: the last {self.trail} positions of each drawn agent.")
        if self.legend is not None:
            lines.append(f"- **{self.legend.title}**: see the colours view.")
        for name, description in self.profiles.items():
            lines.append(f"- **{_profile_title(name)}** (bar chart, a tab of its own): {description}; each bar at "
                         "its slab's position along that axis, in the box's coordinates")
        # a list, not a table: the viewer does not wrap a table's cells (descriptions were cut at the view's edge)
        lines += ["", "# Metrics", "", "Each plot, and the metrics it draws (`name` in the metrics table):", ""]
        for group, members in self._plot_split():
            if len(members) == 1:
                name = members[0][0]
                lines.append(f"- **{group}** (`{name}`): {_markdown_text(self.metrics[name])}")
                continue
            lines.append(f"- **{group}**, {len(members)} series:")
            lines += [f"  - {short} (`{name}`): {_markdown_text(self.metrics[name])}" for name, short in members]
        return "\n".join(lines) + "\n"

    def _log_about(self) -> None:
        """The about page (static: the last one logged wins, so it can follow the layout's split)."""
        self.rec.log(ABOUT, rr.TextDocument(self._about(), media_type=rr.MediaType.MARKDOWN), static=True)

    def _log_static(self) -> None:
        """Log everything that does not change over the run, once."""
        rec, world = self.rec, self.world
        toml_text = self.config_toml.rstrip("\n")
        fence = "```"
        while fence in toml_text:
            fence += "`"
        doc = (
            f"# tflock run: `{self.model}`\n\n"
            f"{world.dim}D, {world.boundary} boundary, box {world.box:g}, dt {world.dt:g}\n\n"
            f"Resolved configuration:\n\n{fence}toml\n{toml_text}\n{fence}\n"
        )
        rec.log(CONFIG, rr.TextDocument(doc, media_type=rr.MediaType.MARKDOWN), static=True)
        self._log_about()
        rec.log(
            META,
            rr.AnyValues(
                model=self.model,
                dim=world.dim,
                boundary=world.boundary,
                box=float(world.box),
                dt=float(world.dt),
                **({"centred_on": world.centred_on} if world.centred_on else {}),
                metrics=list(self.metrics),
                metric_descriptions=list(self.metrics.values()),
            ),
            static=True,
        )
        for members in metric_groups(list(self.metrics)).values():
            for k, (name, short) in enumerate(members):
                color = _series_color(k, members)
                style = rr.SeriesPoints(names=short, marker_sizes=1.5, **color) if name in self.angles else \
                    rr.SeriesLines(names=short, widths=1.5, **color)
                rec.log(f"{METRICS}/{name}", style, static=True)
        if world.dim == 2:  # y up: the 2D view draws y downwards
            rec.log(WORLD, rr.Transform3D(scale=[1.0, -1.0, 1.0]), static=True)
        else:
            rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        if self.field:
            colors = class_colors()
            context = rr.AnnotationContext([rr.AnnotationInfo(id=k, label=label, color=tuple(int(c) for c in colors[k]))
                                            for k, label in enumerate(class_labels())])
            rec.log(FIELD_2D if world.dim == 2 else FIELD_3D, context, static=True)
        if self._has_legend():
            self._log_legend()
        if world.bounded:
            L = float(world.box)
            edge = rr.Radius.ui_points(1.0)
            if world.dim == 2:
                outline = np.array([[[0, 0], [L, 0], [L, L], [0, L], [0, 0]]], dtype=np.float32)
                rec.log(BOUNDS, rr.LineStrips2D(outline, colors=BOUNDS_COLOR, radii=edge), static=True)
            else:
                rec.log(
                    BOUNDS,
                    rr.Boxes3D(mins=[0.0, 0.0, 0.0], sizes=[L, L, L], colors=BOUNDS_COLOR, radii=edge,
                               fill_mode=rr.components.FillMode.MajorWireframe),
                    static=True,
                )

    def _log_legend(self) -> None:
        """The colours view (static, its own picture, y down as a 2D view draws it): the hue wheel of headings as 24
        arrows, or a column of named colours, and right of either the legend's notes; to their right the field's
        colours (a sweep of headings, named in degrees, at three densities, and disordered)."""
        rec, legend = self.rec, self.legend
        x = 0.0
        title = {"radii": 0.0, "show_labels": True, "colors": [(230, 230, 230)]}
        if legend is not None:
            rec.log(f"{LEGEND}/title", rr.Points2D([[0.0, TITLE_Y]], labels=legend.title, **title), static=True)
            # an invisible point left of everything drawn: the view fits its points, so where the legend is wide
            # enough to fill the view's width (categories beside the field) the centred title's left half and the
            # dots' left halves would fall outside it (the mirror of the field's end point)
            left = -_label_width(legend.title) / 2
            left = min(left, -1.3 - _label_width("180°") / 2 if legend.wheel else -0.8 - DOT_HALF_WIDTH)
            rec.log(f"{LEGEND}/start", rr.Points2D([[left - DOT_HALF_WIDTH, 0.0]], radii=0.0), static=True)
            if legend.wheel:
                angle = np.arange(24) * (2 * math.pi / 24)
                vectors = np.stack([np.cos(angle), -np.sin(angle)], axis=1).astype(np.float32)
                rec.log(f"{LEGEND}/wheel", rr.Arrows2D(origins=np.zeros_like(vectors), vectors=vectors,
                                                       colors=angle_colors(angle), radii=rr.Radius.ui_points(1.5)),
                        static=True)
                quarter = np.arange(4) * (math.pi / 2)
                # each centred on its spot 1.3 radii out (raised by LABEL_RISE: the 90° label hung over the arrows)
                where = (1.3 * np.stack([np.cos(quarter), -np.sin(quarter)], axis=1) - [0.0, LABEL_RISE]).astype(
                    np.float32)
                rec.log(f"{LEGEND}/wheel/angles", rr.Points2D(where, radii=0.0, show_labels=True,
                                                              labels=["0°", "90°", "180°", "270°"],
                                                              colors=angle_colors(quarter)), static=True)
                x = 2.2
            else:
                k = len(legend.entries)
                labels, colors = [label for label, _ in legend.entries], [c for _, c in legend.entries]
                where = np.stack([np.full(k, -0.8), np.linspace(-1.0, 1.0, k) if k > 1 else np.zeros(1)], axis=1)
                entries = rr.Points2D(where.astype(np.float32), colors=colors, labels=labels, show_labels=False,
                                      radii=rr.Radius.ui_points(6.0))
                rec.log(f"{LEGEND}/entries", entries, static=True)
                # each name right of its dot, level with it
                rec.log(f"{LEGEND}/entries/names", _legend_names(-0.55, where[:, 1], labels, colors), static=True)
                x = -0.55 + max(_label_width(label) for label in labels) + 0.6
            if legend.notes:  # right of the wheel or the entries, a dot and its name each, in rows as the field's
                labels, colors = [label for label, _ in legend.notes], [c for _, c in legend.notes]
                dot, rows = x - 0.3, [_legend_row(k) for k in range(len(labels))]
                rec.log(f"{LEGEND}/notes", rr.Points2D(np.array([(dot, y) for y in rows], np.float32), colors=colors,
                                                       radii=rr.Radius.ui_points(6.0)), static=True)
                rec.log(f"{LEGEND}/notes/names", _legend_names(dot + 0.25, rows, labels, [NAME_COLOR] * len(labels)),
                        static=True)
                x = dot + 0.25 + max(_label_width(label) for label in labels) + 0.6
        if self.field:
            colors = class_colors()[:, :3]
            hues = np.arange(0, 24, 3)
            swatches, swatch_colors = [], []
            for row, (level, ordered) in enumerate([(4, 1), (2, 1), (0, 1), (2, 0)]):
                for col, h in enumerate(hues):
                    swatches.append((x + SWATCH_STEP * col, _legend_row(row)))
                    swatch_colors.append(colors[class_of(int(h), level, ordered)])
            rec.log(f"{LEGEND}/field", rr.Points2D(np.array(swatches, np.float32), colors=np.array(swatch_colors),
                                                   radii=rr.Radius.ui_points(6.0)), static=True)
            notes = ["dense", "mean density", "sparse", "disordered"]
            # the names start right of the last swatch, level with its row
            start = x + SWATCH_STEP * (len(hues) - 1) + 0.4
            rec.log(f"{LEGEND}/field/levels", _legend_names(start, [_legend_row(r) for r in range(len(notes))], notes,
                                                            [NAME_COLOR] * len(notes)), static=True)
            # an invisible point where the longest name ends: the view fits its points, and a label is centred on
            # its point, so without it the names' right halves fall outside a wide legend (wheel, notes and field)
            rec.log(f"{LEGEND}/field/end", rr.Points2D([[start + max(_label_width(n) for n in notes), 0.0]],
                                                       radii=0.0), static=True)
            # the headings of the swatch columns, named under the last row (hues as on the agents' wheel; the agents
            # themselves may be coloured by something else, as potential's by speed)
            columns = [0, 2, 4, 6]
            where = np.array([(x + SWATCH_STEP * c, _legend_row(3) + 10.0 / LEGEND_PX) for c in columns], np.float32)
            rec.log(f"{LEGEND}/field/headings", rr.Points2D(where, radii=0.0, show_labels=True,
                                                            labels=[f"{15 * int(hues[c])}°" for c in columns],
                                                            colors=[NAME_COLOR] * len(columns)), static=True)
            rec.log(f"{LEGEND}/field/title", rr.Points2D([[x + 3.5 * SWATCH_STEP, TITLE_Y]],
                                                         labels="field: heading, density", **title), static=True)

    # ------------------------------------------------------------------ logging
    def _set_time(self, step: int) -> None:
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        self.rec.set_time("step", sequence=int(step))
        self.rec.set_time("time", duration=float(step) * self.world.dt)

    def log_frame(self, step: int, frame: Frame) -> None:
        """Draw the agents (points + velocity arrows), neighbour edges, leader, markers, trails and the field at
        ``step``."""
        if not self.enabled:
            return
        dim = self.world.dim
        pos = _f32("positions", frame.positions, (None, dim))
        dirs = _f32("directions", frame.directions, (pos.shape[0], dim))
        if frame.colors is None:
            colors = heading_colors(dirs)
        else:
            colors = np.ascontiguousarray(frame.colors, dtype=np.uint8)
            if colors.shape != (pos.shape[0], 3):
                raise ValueError(f"Frame.colors must have shape ({pos.shape[0]}, 3), got {colors.shape}")
        edges = None if frame.edges is None else _f32("edges", frame.edges, (None, 2, dim))
        colors = _packed_rgba(colors)

        if dim == 2:
            Points, Arrows, Strips = rr.Points2D, rr.Arrows2D, rr.LineStrips2D
            order = {"draw_order": DRAW_AGENTS}
        else:
            Points, Arrows, Strips = rr.Points3D, rr.Arrows3D, rr.LineStrips3D
            order = {}
        radius = point_radius(pos.shape[0])
        rec = self.rec
        self._set_time(step)
        self._log_ids(frame.ids, pos.shape[0])
        vectors = drawn_arrows(dirs, frame.arrow_length)
        agent_style = {"radii": rr.Radius.ui_points(radius), **order}
        arrow_style = {"radii": rr.Radius.ui_points(max(0.5, 0.4 * radius)),
                       **({"draw_order": DRAW_ARROWS} if dim == 2 else {})}
        edge_style = {"colors": EDGE_COLOR, "radii": rr.Radius.ui_points(0.5),
                      **({"draw_order": DRAW_EDGES} if dim == 2 else {})}
        draw_edges = edges is not None or self._edges_drawn  # an empty batch clears edges drawn at earlier steps
        if draw_edges and edges is None:
            edges = np.zeros((0, 2, dim), dtype=np.float32)
        gather = pos.shape[0] <= GATHER_AGENTS
        if gather:  # the per-step parts wait in self._frames; the styles are logged here when they change
            if self._styles != radius:
                rec.log(AGENTS, Points.from_fields(**agent_style))
                rec.log(HEADINGS, Arrows.from_fields(**arrow_style))
                self._styles = radius
            if draw_edges and not self._edges_drawn:
                rec.log(EDGES, Strips.from_fields(**edge_style))
        else:
            self._frames.send()
            self._styles = None
            rec.log(AGENTS, Points(pos, colors=colors, **agent_style))
            rec.log(HEADINGS, Arrows(origins=pos, vectors=vectors, colors=colors, **arrow_style))
            if draw_edges:
                rec.log(EDGES, Strips(line_strips(edges), **edge_style))
        self._edges_drawn = draw_edges
        if frame.arrow_length != self._arrow_length:  # scene length of a full-speed arrow, logged when it changes
            rec.log(HEADINGS, rr.AnyValues(arrow_length=float(frame.arrow_length)))
            self._arrow_length = frame.arrow_length
        if self.trail:
            self._log_trail(pos, colors, Strips)
        markers = {"draw_order": DRAW_MARKERS} if dim == 2 else {}
        shapes: dict[str, Shape] | None = {} if gather else None
        if frame.leader is not None or self._leader_drawn:
            lead = np.zeros((0, dim), np.float32)
            if frame.leader is not None:
                lead = _f32("leader", np.reshape(frame.leader, (1, -1)), (1, dim))
            self._draw(shapes, LEADER, Points, {"positions": lead},
                       {"colors": LEADER_COLOR, "radii": rr.Radius.ui_points(2.5 * radius), "labels": "leader",
                        **markers})
            self._leader_drawn = True
            has_heading = frame.leader is not None and frame.leader_direction is not None
            if has_heading or self._leader_heading_drawn:
                vec = np.zeros((0, dim), np.float32)
                if has_heading:
                    d = _f32("leader_direction", np.reshape(frame.leader_direction, (1, -1)), (1, dim))
                    vec = d * np.float32(1.5 * frame.arrow_length)
                self._draw(shapes, LEADER_HEADING, Arrows, {"origins": lead[: len(vec)], "vectors": vec},
                           {"colors": LEADER_COLOR, "radii": rr.Radius.ui_points(max(1.0, 0.8 * radius)), **markers})
                self._leader_heading_drawn = True
        for marker in frame.markers:
            self._log_marker(shapes, marker, Points, Arrows, Strips, radius, frame.arrow_length)
        corners = view_corners(pos, vectors) if dim == 2 and not self.world.bounded and len(pos) else None
        if corners is not None:
            self._draw(shapes, VIEW_EXTENT, Points, {"positions": corners}, {"colors": (0, 0, 0, 0), "radii": 0.0})
        for image in frame.fields:
            self._log_field(image)
        for name, values in frame.profiles.items():
            if name not in self._profile_axes:
                self._log_profile_axis(name, len(values))
        if shapes is not None:
            self._frames.add(step, pos, colors, vectors, edges if draw_edges else None, frame.profiles, shapes)
        else:
            for name, values in frame.profiles.items():
                rec.log(f"{PROFILES}/{name}", rr.BarChart(np.asarray(values, dtype=np.float32)))

    def _log_ids(self, ids: np.ndarray | None, m: int) -> None:
        """The agent id of each row as its label (shown when hovering it), logged when the drawn agents change."""
        if ids is None:
            return
        ids = np.asarray(ids)
        if ids.shape != (m,):
            raise ValueError(f"Frame.ids must have shape ({m},), got {ids.shape}")
        if self._ids is not None and np.array_equal(self._ids, ids):
            return
        self._ids = ids.copy()
        self._trail = []
        fields = rr.Points2D.from_fields if self.world.dim == 2 else rr.Points3D.from_fields
        self.rec.log(AGENTS, fields(labels=[f"agent {i}" for i in ids.tolist()], show_labels=False))

    def _log_trail(self, pos: np.ndarray, colors: np.ndarray, Strips: type) -> None:
        """Each drawn agent's last positions as one line strip, unwrapped across a periodic box's edges (drawn from
        the agent's current position, so a trail may leave the box where the agent crossed its edge)."""
        if self._trail and self._trail[-1].shape != pos.shape:
            self._trail = []
        self._trail = [*self._trail[-(self.trail - 1):], pos] if self.trail > 1 else [pos]
        if len(self._trail) < 2:
            return
        points = np.stack(self._trail, axis=1)  # (M, K, dim), oldest first
        if self.world.boundary == "periodic":
            box = np.float32(self.world.box)
            step = np.diff(points, axis=1)
            step -= box * np.round(step / box)
            points = points[:, -1:, :] - np.flip(np.cumsum(np.flip(step, axis=1), axis=1), axis=1)
            points = np.concatenate([points, pos[:, None, :]], axis=1)
        faded = (colors & np.uint32(0xFFFFFF00)) | np.uint32(110)
        self.rec.log(TRAILS, Strips(line_strips(np.ascontiguousarray(points, dtype=np.float32)), colors=faded,
                                    radii=rr.Radius.ui_points(0.6),
                                    **({"draw_order": DRAW_TRAILS} if self.world.dim == 2 else {})))

    def _log_profile_axis(self, name: str, bins: int) -> None:
        """A profile's bars placed at their slabs' centres in the box's coordinates, `bins` slabs across the box:
        logged once, static, beside the frames' values (component batches: BarChart.from_fields without values
        fails in rerun-sdk 0.41's converter)."""
        side = self.world.box / bins
        centres = encodings.TensorData(array=(np.arange(bins, dtype=np.float32) + 0.5) * np.float32(side))
        self.rec.log(f"{PROFILES}/{name}", [
            rr.components.TensorDataBatch(centres).described(rr.BarChart.descriptor_abscissa()),
            rr.components.LengthBatch(np.full(bins, side, np.float32)).described(rr.BarChart.descriptor_widths())],
            static=True)
        self._profile_axes.add(name)

    def _log_field(self, image: FieldImage) -> None:
        """One projection of the field: the class image, placed on the world's (2D) or the plane's axes (3D, y up)
        by a transform, with the number of agents it binned."""
        classes = np.ascontiguousarray(image.classes)
        if classes.dtype != np.uint8 or CLASSES > 256:
            raise ValueError("a field image holds uint8 classes")
        ox, oy = image.origin
        px = float(image.pixel)
        if self.world.dim == 2:
            entity = FIELD_2D
            transform = rr.Transform3D(translation=[ox, oy, 0.0], scale=[px, px, 1.0])
            seg = rr.SegmentationImage(classes, draw_order=DRAW_FIELD, opacity=1.0)
        else:
            entity = f"{FIELD_3D}/{image.plane}"
            transform = rr.Transform3D(translation=[ox, -oy, 0.0], scale=[px, -px, 1.0])
            seg = rr.SegmentationImage(classes, opacity=1.0)
        self.rec.log(entity, seg, transform, rr.AnyValues(agents=int(image.agents)))

    def _draw(self, shapes: dict[str, Shape] | None, entity: str, archetype: type, data: dict[str, np.ndarray],
              style: dict[str, Any]) -> None:
        """Draw one of a frame's other shapes (a leader, a marker's point, arrow or circle): `data` its per-step
        components, `style` the rest. A gathered frame keeps the data in `shapes` and logs the style only when it
        changes; else both are logged now."""
        if shapes is None:
            self.rec.log(entity, archetype(**data, **style))
            self._shape_styles.pop(entity, None)
            return
        key = repr(sorted(style.items()))
        if self._shape_styles.get(entity) != key:
            self.rec.log(entity, archetype.from_fields(**style))
            self._shape_styles[entity] = key
        shapes[entity] = Shape(archetype, data)

    def _log_marker(self, shapes: dict[str, Shape] | None, marker: Marker, Points: type, Arrows: type, Strips: type,
                    radius: float, arrow_length: float) -> None:
        dim = self.world.dim
        entity = f"world/{marker.name}"
        order = {"draw_order": DRAW_MARKERS} if dim == 2 else {}
        where = _f32(marker.name, np.reshape(marker.position, (1, -1)), (1, dim))
        self._draw(shapes, entity, Points, {"positions": where},
                   {"colors": marker.color, "radii": rr.Radius.ui_points(marker.size * radius),
                    "labels": marker.name.replace("_", " "), **order})
        if marker.direction is not None:
            vec = _f32(marker.name, np.reshape(marker.direction, (1, -1)), (1, dim)) * np.float32(1.5 * arrow_length)
            self._draw(shapes, f"{entity}/heading", Arrows, {"origins": where, "vectors": vec},
                       {"colors": marker.color, "radii": rr.Radius.ui_points(max(1.0, 0.8 * radius)), **order})
        if marker.circle is not None and dim == 2:
            ring = where[0] + np.float32(marker.circle) * _UNIT_CIRCLE
            self._draw(shapes, f"{entity}/range", Strips, {"strips": ring[None].astype(np.float32)},
                       {"colors": (*marker.color, 140), "radii": rr.Radius.ui_points(1.0), **order})

    def log_metrics(self, step: int, values: Mapping[str, float]) -> None:
        """Log one value per metric at ``step`` and append a row to the metrics table.

        Metrics missing from ``values`` are skipped (an empty CSV cell); unknown names raise ValueError.
        """
        row, present = self._rows.row(values)  # checks the names
        if step < 0:
            raise ValueError(f"step must be >= 0, got {step}")
        self._rows.add(int(step), row, present)
        if self._csv_file is not None:  # the csv module writes a float as its repr: every digit kept
            cells = row.tolist()
            if present is not None:
                cells = [cell if here else "" for cell, here in zip(cells, present.tolist(), strict=True)]
            self._csv.writerow([int(step), int(step) * self.world.dt, *cells])
            self._csv_file.flush()
        if (self._rows.pending() >= METRIC_BATCH_ROWS
                or time.monotonic() - self._pending_since >= METRIC_BATCH_S):
            self._send_metrics()

    def _send_metrics(self) -> None:
        """Hand the gathered metric rows to Rerun, one column of (step, time, value) per metric."""
        for name, steps, values in self._rows.take_pending():
            self.rec.send_columns(f"{METRICS}/{name}", indexes=time_columns(steps, self.world.dt),
                                  columns=rr.Scalars.columns(scalars=values))
        self._pending_since = time.monotonic()
        if self.live and not self._closed:
            self._follow_split()

    def _plot_split(self) -> list[tuple[str, list[tuple[str, str]]]]:
        """The metric plots as the values so far split their groups (:func:`readable_groups`), every series counted
        as varying: what the about page names."""
        return list(readable_groups(metric_groups(list(self.metrics)), self._rows.extent).items())

    def _follow_split(self) -> None:
        """A live viewer's layout sent again, and the about page with it, when the values so far split the metric
        plots otherwise than the layout it shows: a long run would else show a series drawn flat under a larger one
        until its end, when :meth:`close` sends the last layout. It replaces a layout the user changed, as the last
        one does, so at most once every :data:`LIVE_LAYOUT_S` (near the split's threshold a group can split and join
        again while the values' ranges grow)."""
        if time.monotonic() - self._shown_at < LIVE_LAYOUT_S:
            return
        split = self._plot_split()
        if split == self._shown:
            return
        self._shown, self._shown_at = split, time.monotonic()
        self.rec.send_blueprint(self.blueprint(), make_active=True, make_default=True)
        self._log_about()

    def constant_metrics(self) -> tuple[str, ...]:
        """The metrics logged with one value at every step after step 0 so far (none before two rows of any metric).
        Step 0, the initial state, does not count: a series of the step just made (``updated``, the fraction of
        agents that moved) is 0 there and constant after."""
        return self._rows.constant()

    # ------------------------------------------------------------------ lifecycle
    def flush(self) -> None:
        """Wait until everything logged so far has gone through Rerun's batcher to the sinks (its encoding and
        writing run on background threads)."""
        self._frames.send()
        self._send_metrics()
        self.rec.flush()

    def close(self) -> None:
        """Flush and finalise the recording (writes the .rrd footer) and close the CSV. Idempotent.

        The layout is sent again once the run has more than one row of metrics: series that never changed share one
        plot, out of the way of the others, each legend goes where it covers the fewest points (where it would cover
        some wherever it went, the plot's y range leaves room for it), and a plot that would
        show no numbers on its y axis gets a labelled range (:func:`labelled_range`; the viewer opens a file with the
        last layout it holds); a group of series too different in size is split (:func:`readable_groups`), and the
        about page is written again to name the plots so."""
        if self._closed:
            return
        self._closed = True
        try:
            self._frames.send()
            self._send_metrics()
            constant = self.constant_metrics()
            if len(constant) == len(self.metrics):  # nothing changed: no plot stands apart
                constant = ()
            if self.enabled and self._rows.rows > 1:
                self.rec.send_blueprint(self.blueprint(constant, final=True), make_active=True, make_default=True)
                self._log_about()  # naming the plots as this layout splits them
            self.rec.disconnect()
        finally:
            if self._csv_file is not None:
                self._csv_file.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


# ---------------------------------------------------------------------- read-back
@dataclass
class RecordingSummary:
    """What ``tflock inspect`` shows about a recording."""

    model: str
    config_toml: str  # the fenced TOML block of the config document, ending with a newline
    frames: int  # steps with a row of world/agents positions (a step logged twice is one frame, as in the viewer)
    steps: list[int]  # step of each frame, ascending
    metric_rows: int  # rows of the longest metric series
    final_metrics: dict[str, float]  # value at the last step of each metric
    entities: list[str]  # recorded entity paths ("/world/agents", ...), sorted
    metric_descriptions: dict[str, str] = field(default_factory=dict)  # metric name -> description

    @property
    def last_step(self) -> int | None:
        """The step of the last frame, or None without frames."""
        return self.steps[-1] if self.steps else None


def _column(batch: pa.RecordBatch, name: str) -> list:
    """One column of a chunk's record batch as Python values (only small columns are read this way)."""
    return batch.column(name).to_pylist()


def _first(column: list) -> object:
    """First scalar of a list<...> record-batch cell (AnyValues and components are lists per row)."""
    value = column[0]
    return value[0] if isinstance(value, list) and len(value) == 1 else value


def read_recording(path: Path) -> RecordingSummary:
    """Summarise a tflock ``.rrd`` file; also works on a file without footer (interrupted run).

    Raises ValueError if the file cannot be read or is not a tflock recording.
    """
    from rerun.chunk import RrdReader

    path = Path(path)
    entities: set[str] = set()
    steps: list[int] = []
    metric_points: dict[str, list[tuple[int, float]]] = {}
    descriptions: dict[str, str] = {}
    model: str | None = None
    doc: str | None = None
    prefix = f"/{METRICS}/"
    try:
        with warnings.catch_warnings():  # a file without footer (interrupted run) is read by a full scan
            warnings.filterwarnings("ignore", message="RRD file has no footer")
            reader = RrdReader(path)
        for chunk in reader.stream():
            entity = chunk.entity_path
            if entity.startswith("/__"):
                continue
            entities.add(entity)
            if chunk.num_rows == 0:
                continue
            batch = chunk.to_record_batch()
            names = set(batch.schema.names)

            if entity == f"/{META}" and "model" in names:
                model = str(_first(_column(batch, "model")))
                if "metric_descriptions" in names:
                    descriptions = dict(zip(_column(batch, "metrics")[0], _column(batch, "metric_descriptions")[0],
                                            strict=True))
            elif entity == f"/{CONFIG}" and "TextDocument:text" in names:
                doc = str(_first(_column(batch, "TextDocument:text")))
            elif entity == f"/{AGENTS}" and "step" in names:  # frames: rows with positions (not the ids' labels)
                column = next((c for c in names if c.endswith(":positions")), None)
                if column is not None:
                    steps.extend(s for s, p in zip(_column(batch, "step"), batch.column(column).is_valid().to_pylist(),
                                                   strict=True) if p)
            elif entity.startswith(prefix):
                name = entity[len(prefix):]
                if "Scalars:scalars" in names and "step" in names:
                    pts = metric_points.setdefault(name, [])
                    rows = zip(_column(batch, "step"), _column(batch, "Scalars:scalars"), strict=True)
                    pts.extend((s, float(v[0])) for s, v in rows if v)
    except (OSError, RuntimeError, ValueError) as e:
        raise ValueError(f"cannot read {path} as a Rerun recording: {e}") from e
    if model is None or doc is None:
        raise ValueError(f"{path} is not a tflock recording (no /{META} model or /{CONFIG} document)")
    match = _TOML_BLOCK.search(doc)
    if match is None:
        raise ValueError(f"{path}: the /{CONFIG} document has no ```toml block")
    final = {}
    for name, pts in metric_points.items():
        pts.sort(key=lambda p: p[0])  # stable: the last logged value wins on equal steps
        final[name] = pts[-1][1]
    return RecordingSummary(
        model=model,
        config_toml=match.group(2) + "\n",
        frames=len(set(steps)),
        steps=sorted(set(steps)),
        metric_rows=max((len(p) for p in metric_points.values()), default=0),
        final_metrics=final,
        entities=sorted(entities),
        metric_descriptions=descriptions,
    )


def rerun_executable() -> list[str]:
    """Command prefix that runs the ``rerun`` CLI installed with rerun-sdk.

    The binary itself where it can be found: the ``rerun`` console script is a Python wrapper that runs it as a
    child, and terminating the wrapper would leave the viewer or web server running.
    """
    exe = "rerun.exe" if sys.platform == "win32" else "rerun"
    try:
        import rerun_cli

        binary = Path(rerun_cli.__file__).parent / exe
        if binary.is_file():
            return [str(binary)]
    except ImportError:
        pass
    beside = Path(sys.executable).parent / exe
    if beside.is_file():
        return [str(beside)]
    found = shutil.which("rerun")
    if found:
        return [found]
    return [sys.executable, "-m", "rerun_cli"]


def verify_recording(path: Path) -> bool:
    """Run ``rerun rrd verify`` (footer included) on ``path``; True when the file is complete and valid.

    ``rerun rrd verify`` exits 0 on a file that is not an RRD at all ("0 files verified"), so its report
    must name exactly one verified file as well.
    """
    result = subprocess.run(
        [*rerun_executable(), "rrd", "verify", str(path)],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        check=False,
    )
    return result.returncode == 0 and re.search(r"\b1 file verified without error", result.stderr) is not None


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now (the system's choice)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_for_port(port: int, proc: subprocess.Popen, timeout: float) -> None:
    """Wait until something accepts connections on `port` (RuntimeError if `proc` exits or `timeout` passes)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the Rerun web viewer exited (code {proc.returncode}) before serving port {port}")
        if _listening(port):
            return
        time.sleep(0.1)
    raise RuntimeError(f"the Rerun web viewer did not serve port {port} within {timeout:g} s")


def _listening(port: int) -> bool:
    """Whether something accepts connections on 127.0.0.1:`port`."""
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


def _viewer_env() -> dict[str, str]:
    """The environment of a viewer tflock starts: Rerun's own log at warnings and above (unless RUST_LOG says
    otherwise), as its info lines, with colour codes and a second address of its own, buried the address tflock
    prints."""
    return {**os.environ, "RUST_LOG": os.environ.get("RUST_LOG", "warn")}


def _exit_reason(log: str, code: int) -> str:
    """Why a Rerun viewer exited, from its log: its last error line (without colour codes), else its exit code."""
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in log.splitlines()]
    errors = [line for line in lines if line.startswith("Error:") or " ERROR " in f" {line} "]
    return errors[-1].removeprefix("Error:").strip().rstrip(".") if errors else f"exit code {code}"


def spawn_viewer(port: int = SPAWN_PORT, timeout: float = SPAWN_TIMEOUT_S) -> Path | None:
    """A native viewer that listens on 127.0.0.1:`port` for a run to stream to: the one already there (None), or a
    new one, started in a session of its own (it stays open after the run, and a Ctrl-C that stops the run leaves
    it), whose log file it returns (a new temporary file each time: another user's viewer may have left one).
    RuntimeError, naming the viewer's own error, where it exits before it listens (a graphics driver it cannot draw
    with, as over ``ssh -X`` or with a software rasteriser: else the run would be streamed to nobody, and Rerun
    would say so only at its end; it listens first, so it must also keep running for :data:`SPAWN_GRACE_S`) or
    does not listen within `timeout` seconds."""
    if _listening(port):
        return None
    with tempfile.NamedTemporaryFile("w", prefix="tflock-viewer-", suffix=".log", delete=False) as out:
        proc = subprocess.Popen([*rerun_executable(), "--port", str(port), "--bind", "127.0.0.1", "--memory-limit",
                                 "75%", "--expect-data-soon"],  # the flags of Rerun's own spawn()
                                stdin=subprocess.DEVNULL, stdout=out, stderr=out, env=_viewer_env(),
                                start_new_session=True)
    log = Path(out.name)
    deadline, settled = time.monotonic() + timeout, None
    while settled is None or time.monotonic() < settled:  # listening, and still running SPAWN_GRACE_S later
        if proc.poll() is not None:
            reason = _exit_reason(log.read_text(errors="replace"), proc.returncode)
            log.unlink(missing_ok=True)
            raise RuntimeError(f"--spawn: the viewer exited at start: {reason}; watch the run in a browser instead: "
                               "start `tflock view --live --web` and pass the URL it prints to --connect")
        if settled is None and _listening(port):
            settled = time.monotonic() + SPAWN_GRACE_S
        if settled is None and time.monotonic() > deadline:
            _stop(proc)
            raise RuntimeError(f"--spawn: the viewer did not listen on port {port} within {timeout:g} s (its log: "
                               f"{log})")
        time.sleep(0.05)
    return log


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _web_command(path: Path | None, port: int | None, grpc_port: int | None) -> tuple[list[str], int, str, str]:
    """The command serving `path` in the web viewer (None: no recording, the runs that stream to it), its HTTP
    port, the address to open and the URL runs stream to (free ports where None is given: several viewers can run
    at once). Both servers listen on 127.0.0.1 only (Rerun's default is every interface): a remote machine's viewer
    is reached through an ssh tunnel (docs/recordings.md)."""
    port = free_port() if port is None else port
    grpc_port = free_port() if grpc_port is None else grpc_port
    cmd = [*rerun_executable(), "--serve-web", *([] if path is None else [str(path)]), "--web-viewer-port", str(port),
           "--port", str(grpc_port), "--bind", "127.0.0.1"]
    stream_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    return cmd, port, f"http://127.0.0.1:{port}/?url={quote(stream_url, safe='')}", stream_url


@contextlib.contextmanager
def serve_web(path: Path, port: int | None = None, grpc_port: int | None = None,
              timeout: float = 30.0) -> Iterator[str]:
    """Serve a recording in Rerun's web viewer for the ``with`` block, which gets the address to open; the server
    stops at its end. Ports as in :func:`open_viewer`."""
    cmd, port, url, _ = _web_command(Path(path), port, grpc_port)
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_for_port(port, proc, timeout)
        yield url
    finally:
        _stop(proc)


def open_viewer(path: Path | None, web: bool = False, port: int | None = None,
                grpc_port: int | None = None) -> None:
    """Open a recording in the Rerun viewer; blocks until the viewer closes (native) or Ctrl-C (web).

    ``web=True`` serves the web viewer over HTTP on ``port`` (the data over gRPC on ``grpc_port``) and prints the
    address to open; this works without a display. Ports left None are free ones the system picks, so several
    viewers can run at once. The native viewer needs a display (RuntimeError otherwise). With `path` None, the
    viewer opens empty and shows the runs that stream to it (``tflock sim --connect URL``, the URL printed) as they
    go.
    """
    if path is not None and not Path(path).is_file():
        raise FileNotFoundError(f"no recording at {path}")
    if web:
        cmd, _, url, stream_url = _web_command(path, port, grpc_port)
        print(f"Web viewer: {url}  (Ctrl-C to stop)", flush=True)
    else:
        if not _has_display():
            raise RuntimeError(
                "the native viewer needs a display (no DISPLAY is set); use `tflock view --web`"
            )
        if path is None:  # a viewer that listens for runs, on a port of 127.0.0.1
            grpc_port = free_port() if grpc_port is None else grpc_port
            stream_url = f"rerun+http://127.0.0.1:{grpc_port}/proxy"
            cmd = [*rerun_executable(), "--port", str(grpc_port), "--bind", "127.0.0.1"]
        else:
            cmd = [*rerun_executable(), str(path)]
    if path is None:
        print(f"Stream a run to it: tflock sim --connect {stream_url}", flush=True)
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, env=_viewer_env())
    try:
        code = proc.wait()
    except KeyboardInterrupt:
        _stop(proc)
        return
    if code != 0 and not web:  # its own log, above, says why (a graphics driver it cannot draw with, often)
        raise RuntimeError(f"the viewer exited with code {code} (its log above says why); where it cannot open a "
                           f"window, `tflock view {'--live ' if path is None else ''}--web` serves the web viewer "
                           "instead")
