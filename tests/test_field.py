"""The coarse-grained field kernels (tflock.field) against their NumPy reference, from the same agents."""

import math

import numpy as np
import pytest
import taichi as ti
from conftest import ARCH

import tflock.field as field_module
from tflock.field import (
    ANGLE_ROW,
    ANGLES,
    CLASSES,
    DENSITY_LEVELS,
    HUES,
    UNIT_VECTORS,
    VECTORS,
    Field,
    class_colors,
    class_labels,
    class_of,
    field_size,
    reference_field,
)
from tflock.neighbors import BOUNDED, CellGrid


def upload(a: np.ndarray, dtype=ti.f32) -> ti.Ndarray:
    arr = ti.ndarray(dtype, a.shape)
    arr.from_numpy(np.ascontiguousarray(a))
    return arr


def quantised_directions(rng: np.random.Generator, n: int, dim: int) -> np.ndarray:
    """Unit-ish directions whose fixed-point values are integers (no rounding ties between kernel and NumPy), half
    of them pointing into the positive quadrant so that some pixels are ordered."""
    d = rng.normal(size=(n, dim))
    d[: n // 2] = np.abs(d[: n // 2])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return (np.round(d * 1024) / 1024).astype(np.float32)


def clustered_positions(rng: np.random.Generator, n: int, dim: int, box: float) -> np.ndarray:
    """Uniform agents plus a dense blob (so that every density level occurs), as float32."""
    pos = rng.random((n, dim)) * box
    pos[: n // 3] = box * 0.3 + rng.random((n // 3, dim)) * box * 0.05
    return pos.astype(np.float32)


@pytest.mark.parametrize("chunks", [
    pytest.param(True, id="chunks", marks=pytest.mark.skipif(
        ARCH != "cpu", reason="the chunks in order are the CPU's binning (on lavapipe their additions were lost)")),
    pytest.param(False, id="each")])
@pytest.mark.parametrize(("dim", "mode"), [(2, VECTORS), (2, UNIT_VECTORS), (3, VECTORS), (3, UNIT_VECTORS)])
def test_binning_matches_reference(engine, dim: int, mode: int, chunks: bool) -> None:
    """Both binning kernels: chunks of agents in order (the CPU's) and an agent a thread (GPU arches')."""
    rng = np.random.default_rng(dim)
    n, box, size = 5000, 16.0, 32  # a power-of-two pixel: positions map to pixels exactly in float32 and float64
    pos = clustered_positions(rng, n, dim, box)
    d = quantised_directions(rng, n, dim)
    field = Field(n, dim, size)
    field._on_cpu = chunks
    images = field.compute(upload(pos.T), upload(d.T), box=box, bounded=True, mode=mode)
    classes, counts = reference_field(pos, d, np.zeros(dim), box / size, size, normalise=mode == VECTORS)
    assert [im.plane for im in images] == (["xy"] if dim == 2 else ["xy", "xz", "yz"])
    for k, im in enumerate(images):
        assert im.agents == n == counts[k].sum()
        assert im.pixel == box / size and im.origin == (0.0, 0.0)
        np.testing.assert_array_equal(im.classes, classes[k])
    levels = {(c - 1) // 2 % DENSITY_LEVELS for c in np.unique(images[0].classes) if c}
    assert levels == set(range(DENSITY_LEVELS))  # every level occurs: the test covers the thresholds


@pytest.mark.parametrize("chunks", [
    pytest.param(True, id="chunks", marks=pytest.mark.skipif(
        ARCH != "cpu", reason="the chunks in order are the CPU's binning (on lavapipe their additions were lost)")),
    pytest.param(False, id="each")])
def test_rolled_box_matches_reference_of_wrapped_positions(engine, chunks: bool) -> None:
    """A periodic box drawn from another corner (`rolled`, as formation draws its torus centred on the VA): the
    field of wrap(x - corner), with origin 0, whether the corner lies below the box's own (x - corner beyond the
    box wraps down), inside it (below it wraps up) or more than a side away; the grid of the model is not used."""
    rng = np.random.default_rng(8)
    n, box, size = 5000, 16.0, 32
    pos = clustered_positions(rng, n, 2, box)
    d = quantised_directions(rng, n, 2)
    for corner in (np.array([-5.5, 3.0]), np.array([7.25, -0.5]), np.array([21.25, -40.0])):  # dyadic: exact
        field = Field(n, 2, size)
        field._on_cpu = chunks
        (im,) = field.compute(upload(pos.T), upload(d.T), box=box, bounded=True, mode=VECTORS, rolled=corner)
        wrapped = np.mod(pos.astype(np.float64) - corner, box)
        classes, counts = reference_field(wrapped, d, np.zeros(2), box / size, size)
        assert im.origin == (0.0, 0.0) and im.pixel == box / size and im.agents == n
        np.testing.assert_array_equal(im.classes, classes[0])
        assert not np.array_equal(classes[0], reference_field(pos, d, np.zeros(2), box / size, size)[0])


def test_binning_angles_and_rows(engine) -> None:
    rng = np.random.default_rng(5)
    n, box, size = 4000, 8.0, 16
    pos = clustered_positions(rng, n, 2, box)
    theta = (rng.integers(0, 24, n) * (2 * math.pi / 24) + 0.1).astype(np.float32)
    field = Field(n, 2, size)
    classes, _ = reference_field(pos, theta, np.zeros(2), box / size, size)
    by_angle = field.compute(upload(pos.T), upload(theta), box=box, bounded=True, mode=ANGLES)
    rows = np.stack([np.zeros(n, np.float32), theta])
    by_row = field.compute(upload(pos.T), upload(rows), box=box, bounded=True, mode=ANGLE_ROW, row=1)
    np.testing.assert_array_equal(by_angle[0].classes, classes[0])
    np.testing.assert_array_equal(by_row[0].classes, classes[0])


def test_open_space_window_covers_every_agent(engine) -> None:
    rng = np.random.default_rng(2)
    n = 3000
    pos = (rng.normal(size=(n, 2)) * 40 - 500).astype(np.float32)
    d = quantised_directions(rng, n, 2)
    (im,) = Field(n, 2, 64).compute(upload(pos.T), upload(d.T), box=5.0, bounded=False)
    assert im.agents == n
    lo, side = np.array(im.origin), im.pixel * 64
    assert np.all(pos.min(axis=0) > lo) and np.all(pos.max(axis=0) < lo + side)
    assert side < 1.1 * float(np.max(pos.max(axis=0) - pos.min(axis=0)))
    # the same window in the reference: identical up to agents that float32 rounds into the next pixel
    classes, counts = reference_field(pos, d, lo, im.pixel, 64)
    assert np.mean(im.classes == classes[0]) > 0.99 and counts.sum() == n


@pytest.mark.parametrize(("dim", "boundary", "box", "size"), [(2, "periodic", 23.0, 5), (3, "reflecting", 9.0, 2),
                                                               (2, "open", 30.0, 4)])
def test_from_cells_matches_reference(engine, dim: int, boundary: str, box: float, size: int) -> None:
    """Pixels of whole cells from a built grid (k cells a side, fewer in the last row and column)."""
    rng = np.random.default_rng(11)
    n, radius = 6000, 1.0
    grid = CellGrid(n, dim, boundary, box, radius, engine.real, bounded=boundary == "open")
    raw = clustered_positions(rng, n, dim, box)
    if boundary == "open":
        raw -= np.float32(box / 2)  # cells at negative coordinates too
    # keep agents away from cell edges, where float32 and float64 might put them in different cells
    cell = radius if boundary == "open" else box / int(box // radius)
    pos = ((np.floor(raw / cell) + 0.25 + 0.5 * rng.random(raw.shape)) * cell).astype(np.float32)
    if boundary != "open":
        pos = np.clip(pos, 0, np.float32(box * (1 - 1e-6)))
    d = quantised_directions(rng, n, dim)
    grid.build(upload(pos.T, grid.pos_sorted.dtype), upload(np.arange(n, dtype=np.int32), ti.i32))
    g = grid.geometry
    assert (g.boundary == BOUNDED) == (boundary == "open")
    mode = UNIT_VECTORS if boundary == "periodic" else VECTORS
    images = Field(n, dim, size).compute(upload(pos.T), upload(d.T, grid.pos_sorted.dtype), box=box,
                                         bounded=boundary != "open", grid=grid, mode=mode)
    origin = grid.bounds.to_numpy()[0] * g.cell_size if boundary == "open" else np.zeros(dim)
    k = -(-g.cells_per_side // size)
    assert g.cells_per_side % k != 0  # partial pixels at the far edges
    classes, counts = reference_field(pos, d, origin, g.cell_size, g.cells_per_side, k, normalise=mode == VECTORS)
    for p, im in enumerate(images):
        assert im.agents == n
        assert im.pixel == pytest.approx(k * g.cell_size)
        np.testing.assert_array_equal(im.classes, classes[p])


@pytest.mark.parametrize("cells", [False, True], ids=["binned", "cells"])
def test_3d_projections_take_the_agents_hue(engine, cells: bool) -> None:
    """A polarised 3D flock heading up and to +y at 30 degrees of azimuth: every projection's pixels carry the hue of
    that azimuth, as the agents are coloured (tflock.frame.heading_colors), not the direction within the plane (xz:
    atan2(0.8, 0.52) = 57 degrees; yz: 66 degrees)."""
    rng = np.random.default_rng(5)
    n, box, size = 4000, 8.0, 4
    pos = (rng.random((n, 3)) * box).astype(np.float32)
    heading = np.array([0.6 * math.cos(math.pi / 6), 0.6 * math.sin(math.pi / 6), 0.8], np.float32)
    d = np.tile(heading, (n, 1))
    grid = None
    if cells:
        grid = CellGrid(n, 3, "periodic", box, 1.0, engine.real)
        grid.build(upload(pos.T, grid.pos_sorted.dtype), upload(np.arange(n, dtype=np.int32), ti.i32))
    images = Field(n, 3, size).compute(upload(pos.T), upload(d.T, ti.f32 if grid is None else grid.pos_sorted.dtype),
                                       box=box, bounded=True, grid=grid, mode=VECTORS)
    assert [im.plane for im in images] == ["xy", "xz", "yz"]
    hue = round(30 / (360 / HUES))
    for im in images:
        filled = im.classes[im.classes > 0].astype(int)
        assert filled.size > 0
        assert set(((filled - 1) // 2 // DENSITY_LEVELS).tolist()) == {hue}, im.plane
        assert np.all((filled - 1) % 2 == 1)  # ordered


def test_order_is_not_found_by_chance(engine) -> None:
    """A pixel is ordered only where its agents' directions are unlikely to line up by chance (Rayleigh's test,
    c R^2 >= 3, beside R >= 0.5): a gas of random headings at 6 agents a pixel (Poisson counts) has at most a few
    per cent of its pixels ordered (R >= 0.5 alone: about a quarter, in random hues: a pixel of one agent always,
    of two in two thirds), while a polarised flock (headings spread 0.3 rad) has every pixel of 5 agents or more
    ordered."""
    rng = np.random.default_rng(11)
    size, box = 32, 32.0
    n = 6 * size * size
    pos = (rng.random((n, 2)) * box).astype(np.float32)
    for spread, ordered_share in ((None, (0.0, 0.06)), (0.3, (0.75, 1.0))):
        angle = rng.uniform(0, 2 * math.pi, n) if spread is None else rng.normal(1.0, spread, n)
        d = np.stack([np.cos(angle), np.sin(angle)], axis=1).astype(np.float32)
        (image,) = Field(n, 2, size).compute(upload(pos.T), upload(d.T), box=box, bounded=True, mode=VECTORS)
        classes, counts = reference_field(pos, d, np.zeros(2), box / size, size, normalise=True)
        np.testing.assert_array_equal(image.classes, classes[0])
        filled = image.classes > 0
        ordered = filled & ((image.classes.astype(int) - 1) % 2 == 1)
        share = ordered.sum() / filled.sum()
        assert ordered_share[0] <= share <= ordered_share[1], (spread, share)
        assert not ordered[counts[0] <= 3].any()  # three directions or fewer: no evidence of order
        if spread is not None:
            assert ordered[counts[0] >= 5].all()


def test_classes_and_default_size() -> None:
    colors = class_colors()
    assert colors.shape == (CLASSES, 4) and CLASSES <= 256  # fits a uint8 image
    assert tuple(colors[0]) == (0, 0, 0, 0) and np.all(colors[1:, 3] == 255)
    labels = class_labels()
    assert len(labels) == CLASSES and labels[0] == "no agents"
    assert "mean heading 0 deg" in labels[class_of(0, 2, 1)] and "disordered" in labels[class_of(3, 0, 0)]
    # brighter with density, for every hue and order level
    value = colors[1:, :3].reshape(24, DENSITY_LEVELS, 2, 3).max(axis=3)
    assert np.all(np.diff(value.astype(int), axis=1) > 0)
    assert [field_size(n) for n in (12, 2e4, 1e5, 1e6, 1e8)] == [64, 64, 128, 256, 256]


@ti.kernel
def _hues(sums: ti.types.ndarray(), out: ti.types.ndarray()):
    for i in range(out.shape[0]):
        out[i] = field_module._hue(sums[i, 0], sums[i, 1])


def test_hue_is_the_rounded_angle(engine):
    """A pixel's hue, found without atan2 (Vulkan has no 64-bit one), is round(atan2(sy, sx) / 15 degrees) mod 24 as
    the reference computes it: every direction of a small integer square (the axes and diagonals included), large
    random sums, and sums a unit or two off each sector edge."""
    small = [(x, y) for x in range(-40, 41) for y in range(-40, 41) if x or y]
    rng = np.random.default_rng(4)
    large = rng.integers(-(2**40), 2**40, (4000, 2)).tolist()
    edges = []
    for k in range(HUES):
        angle = 2 * math.pi / HUES * (k + 0.5)
        for radius in (1e3, 1e6, 1e9):
            x, y = round(radius * math.cos(angle)), round(radius * math.sin(angle))
            edges += [(x + dx, y + dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]
    sums = np.array(small + large + edges, dtype=np.int64)
    out = ti.ndarray(ti.i32, len(sums))
    _hues(upload(sums.astype(np.float64), ti.f64), out)  # (exact: below 2^53)
    want = [math.floor(math.atan2(y, x) * (HUES / (2 * math.pi)) + 0.5) % HUES for x, y in sums.tolist()]
    np.testing.assert_array_equal(out.to_numpy(), want)
