"""The coarse-grained field of all agents: local density and mean direction on a square grid of pixels.

A recording draws at most ``log.max_agents`` agents; at N = 1e6 such a sample cannot show the bands, clusters and
density waves of the whole swarm. The field bins every agent into ``size x size`` pixels over the box (open space:
the square around all agents) and gives each pixel one of :data:`CLASSES` colour classes (DESIGN.md section 5):

* hue: the direction of the pixel's summed unit directions (``HUES`` sectors of 15 degrees, sector 0 centred on
  +x), the same hue wheel the agents are coloured with (:func:`tflock.frame.angle_colors`);
* brightness: the pixel's agent count against the mean count ``N / size^2`` (``DENSITY_LEVELS`` levels: at most
  1/2 of the mean, 1, 2, 4 times the mean, more);
* saturation: ordered pixels are saturated, disordered ones greyish. A pixel is ordered when the length R of its c
  agents' mean unit direction is at least :data:`ORDERED` and at least sqrt(:data:`CHANCE_Z` / c): the second is
  Rayleigh's test, c R^2 >= 3, which c random directions pass in at most about 5 % of pixels (e^-3), where R >= 0.5
  alone passes a pixel of one agent always, of two in 2/3 and of six in 23 % (a disordered gas at a few agents a
  pixel looked ordered, in random hues). A pixel of three agents or fewer is never ordered.

Class 0 is an empty pixel. In 3D the field is three projections (planes xy, xz, yz) of the agents' positions; in
each the hue is the direction of the agents' headings projected onto the xy plane (their azimuth), as the agents
themselves are coloured (:func:`tflock.frame.heading_colors`), so one polarised flock has one hue in all three.
Sums are fixed-point integers (a unit direction's component in units of 1 / ``DIRECTION_SCALE``) added with integer
atomics: the image does not depend on the thread count or the order of the agents. :func:`reference_field` is the
plain NumPy version the tests compare the kernels with.
"""

import math
from dataclasses import dataclass

import numpy as np
import taichi as ti
from taichi.lang import impl

from tflock.fastmath import sin_cos
from tflock.neighbors import BOUNDED, LANES
from tflock.space import PERIODIC, REFLECTING
from tflock.taichi_host import CPU_ARCHES

HUES = 24
#: the tangents of the hue sectors' edges inside the first octant (7.5, 22.5 and 37.5 degrees: HUES sectors of 15
#: degrees centred on multiples of 15), which :func:`_hue` compares against
_OCTANT_EDGES = tuple(math.tan(math.radians(360 / HUES * (k + 0.5))) for k in range(HUES // 8))
DENSITY_LEVELS = 5
ORDER_LEVELS = 2
#: colour classes of a pixel: 0 (empty) and one per (hue, density level, order level)
CLASSES = 1 + HUES * DENSITY_LEVELS * ORDER_LEVELS
#: a pixel is ordered when the length of its agents' mean unit direction is at least this ...
ORDERED = 0.5
#: ... and its c agents' Rayleigh statistic c R^2 at least this: random directions pass in about e^-3 = 5 % of pixels
CHANCE_Z = 3.0
#: fixed-point units of a unit direction's component in the pixel sums
DIRECTION_SCALE = 1024
#: the planes of a 3D field (axes of each projection); a 2D field has the first only
PLANES = ((0, 1), (0, 2), (1, 2))
PLANE_NAMES = ("xy", "xz", "yz")
#: direction arrays the kernels take: (dim, n) vectors of any length, (dim, n) unit vectors (their 2D field skips
#: the normalisation), (n,) angles, or one row of a (rows, n) array of angles
VECTORS, UNIT_VECTORS, ANGLES, ANGLE_ROW = 0, 1, 2, 3
#: upper bounds of the density levels but the last, as multiples of the mean count (num / 2)
_DENSITY_HALVES = (1, 2, 4, 8)


def field_size(n: int) -> int:
    """Default pixels per side for n agents: about 4 agents a pixel at the mean density, a power of two from 64
    to 256 (at N = 1e5: 128, 6 agents a pixel; at 1e6: 256, 15 a pixel)."""
    side = math.sqrt(max(n, 1) / 4.0)
    return int(min(256, max(64, 2 ** round(math.log2(max(side, 1.0))))))


def class_of(hue: int, density: int, ordered: int) -> int:
    """The colour class of a pixel with hue sector, density level and order level (0 or 1)."""
    return 1 + (hue * DENSITY_LEVELS + density) * ORDER_LEVELS + ordered


def class_colors() -> np.ndarray:
    """(CLASSES, 4) uint8 RGBA of every class (class 0, empty, is transparent): the hue wheel's colour of the
    sector, darker where sparse, greyer where disordered. At most half the agents' brightness, so that the drawn
    agents stand out on it."""
    from tflock.frame import angle_colors

    out = np.zeros((CLASSES, 4), np.uint8)
    wheel = angle_colors(np.arange(HUES) * (2 * math.pi / HUES)).astype(np.float64)
    value = np.linspace(0.14, 0.5, DENSITY_LEVELS)
    for h in range(HUES):
        for d in range(DENSITY_LEVELS):
            for o in range(ORDER_LEVELS):
                saturation = 0.8 if o else 0.15
                rgb = value[d] * (saturation * wheel[h] + (1 - saturation) * 255.0)
                out[class_of(h, d, o)] = (*np.rint(rgb).astype(np.uint8), 255)
    return out


def class_labels() -> list[str]:
    """What each class means, as the viewer shows it on hover."""
    sector = 360 / HUES
    dens = ["<= 1/2 x mean density", "1/2-1 x mean density", "1-2 x mean density", "2-4 x mean density",
            "> 4 x mean density"]
    labels = ["no agents"]
    for h in range(HUES):
        for d in range(DENSITY_LEVELS):
            for o in range(ORDER_LEVELS):
                order = "ordered" if o else "disordered"
                labels.append(f"mean heading {h * sector:g} deg (+-{sector / 2:g}), {dens[d]}, {order}")
    return labels


@dataclass
class FieldImage:
    """One projection of the field: ``classes[row, col]`` is the pixel whose lower corner is at ``origin + (col, row)
    * pixel`` on the plane's axes (row 0 at the lowest second coordinate)."""

    plane: str  # "xy", "xz" or "yz"
    classes: np.ndarray  # (rows, cols) uint8
    origin: tuple[float, float]  # plane coordinates of pixel (0, 0)'s lower corner
    pixel: float  # side of a pixel, scene units
    agents: int  # agents binned (the sum of the pixels' counts: every agent, when positions are finite)


@ti.func
def _fixed_unit(ua, ub, normalise: ti.template()):
    """(ua, ub) in fixed point (units of 1 / DIRECTION_SCALE, rounded half up), made unit first when `normalise`
    (a zero vector stays zero)."""
    scale = ua * 0.0 + DIRECTION_SCALE
    if ti.static(normalise):
        norm2 = ua * ua + ub * ub
        scale = ti.select(norm2 > 0, DIRECTION_SCALE / ti.sqrt(ti.select(norm2 > 0, norm2, 1.0)), 0.0)
    return ti.cast(ti.floor(ua * scale + 0.5), ti.i32), ti.cast(ti.floor(ub * scale + 0.5), ti.i32)


@ti.func
def _direction(dirs: ti.template(), e, row, mode: ti.template(), normalise: ti.template()):
    """Fixed-point unit direction of element e in the xy plane: from vectors (3D: projected, then made unit), or an
    angle."""
    ua = 0.0
    ub = 0.0
    if ti.static(mode == VECTORS or mode == UNIT_VECTORS):
        ua = ti.cast(dirs[0, e], ti.f32)
        ub = ti.cast(dirs[1, e], ti.f32)
    elif ti.static(mode == ANGLES):
        ub, ua = sin_cos(ti.cast(dirs[e], ti.f32))
    else:
        ub, ua = sin_cos(ti.cast(dirs[row, e], ti.f32))
    return _fixed_unit(ua, ub, normalise)


@ti.func
def _pixel_index(x, lo, inv, size, wrap: ti.template()):
    """Pixel of coordinate x (scalar or vector) in a window of `size` pixels of side 1 / inv from `lo`: clamped to
    the window, or with `wrap` (the window is a periodic box's side, x and lo in the box: x - lo lies within a side
    of the window) wrapped into it."""
    i = ti.cast(ti.floor((x - lo) * inv), ti.i32)
    if ti.static(wrap):
        i = ti.select(i < 0, i + size, ti.select(i >= size, i - size, i))
    return ti.math.clamp(i, 0, size - 1)


#: agents a chunk of :func:`_bin` takes, one after the other
CHUNK = 4096


@ti.func
def _add(count: ti.template(), sums: ti.template(), k, pixel, size, c, sx, sy):
    if pixel >= 0:
        j = pixel // size
        i = pixel - j * size
        ti.atomic_add(count[k, j, i], c)
        ti.atomic_add(sums[k, 0, j, i], sx)
        ti.atomic_add(sums[k, 1, j, i], sy)


@ti.func
def _lane_row(arr: ti.template(), row, i0, last, mode: ti.template()):
    """LANES elements from i0 (indices clamped to `last`) of row `row` of a 2D array, or of a 1D one (mode ANGLES)."""
    out = ti.Vector([0.0] * LANES)
    for k in ti.static(range(LANES)):
        if ti.static(mode == ANGLES):
            out[k] = ti.cast(arr[ti.min(i0 + k, last)], ti.f32)
        else:
            out[k] = ti.cast(arr[row, ti.min(i0 + k, last)], ti.f32)
    return out


@ti.kernel
def _bin(n: ti.i32, mode: ti.template(), normalise: ti.template(), plane: ti.template(), wrap: ti.template(),
         pos: ti.types.ndarray(), dirs: ti.types.ndarray(), row: ti.i32, lo: ti.types.ndarray(), inv_pixel: ti.f64,
         size: ti.i32, count: ti.types.ndarray(), sums: ti.types.ndarray()):
    """Add every agent to its pixel of projection `plane`: one to the count, its unit direction (in 3D projected onto
    the xy plane, then made unit again: the module says why) in fixed point to the sums; positions outside the
    window go to the edge pixels, or with `wrap` (a periodic box drawn from the corner `lo`) to the pixels they wrap
    into (:func:`_pixel_index`).

    Chunks of agents in parallel, each in order, LANES agents at a time (pixels and fixed-point directions computed
    as vectors, which LLVM vectorises); a run of agents in one pixel is added with one atomic per array (the models
    keep their state in about the cell order of their grid, so runs are long: ~6 agents at 1e6, 128 pixels)."""
    a, b = ti.static(PLANES[plane])
    for chunk in range((n + CHUNK - 1) // CHUNK):
        lo_a = ti.cast(lo[a], ti.f32)
        lo_b = ti.cast(lo[b], ti.f32)
        inv = ti.cast(inv_pixel, ti.f32)
        current = -1
        c = 0
        sx = ti.cast(0, ti.i64)
        sy = ti.cast(0, ti.i64)
        end = ti.min(n, (chunk + 1) * CHUNK)
        for block in range((end - chunk * CHUNK + LANES - 1) // LANES):
            i0 = chunk * CHUNK + block * LANES
            ua = ti.Vector([0.0] * LANES)
            ub = ti.Vector([0.0] * LANES)
            if ti.static(mode == VECTORS or mode == UNIT_VECTORS):
                ua = _lane_row(dirs, 0, i0, end - 1, mode)
                ub = _lane_row(dirs, 1, i0, end - 1, mode)
            else:
                ub, ua = sin_cos(_lane_row(dirs, row, i0, end - 1, mode))
            fx, fy = _fixed_unit(ua, ub, normalise)
            i = _pixel_index(_lane_row(pos, a, i0, end - 1, VECTORS), lo_a, inv, size, wrap)
            j = _pixel_index(_lane_row(pos, b, i0, end - 1, VECTORS), lo_b, inv, size, wrap)
            pixel = j * size + i
            for k in ti.static(range(LANES)):
                if i0 + k < end:
                    if pixel[k] != current:
                        _add(count, sums, plane, current, size, c, sx, sy)
                        current = pixel[k]
                        c = 0
                        sx = ti.cast(0, ti.i64)
                        sy = ti.cast(0, ti.i64)
                    c += 1
                    sx += fx[k]
                    sy += fy[k]
        _add(count, sums, plane, current, size, c, sx, sy)


@ti.kernel
def _bin_each(n: ti.i32, mode: ti.template(), normalise: ti.template(), plane: ti.template(), wrap: ti.template(),
              pos: ti.types.ndarray(), dirs: ti.types.ndarray(), row: ti.i32, lo: ti.types.ndarray(),
              inv_pixel: ti.f64, size: ti.i32, count: ti.types.ndarray(), sums: ti.types.ndarray()):
    """:func:`_bin` on GPU arches: an agent a thread, added with one atomic per array (the same integer sums). The
    chunks of agents in order suit a CPU's few threads, not a GPU's, and on Vulkan (Mesa's lavapipe) most of their
    additions were lost (18 of 5000 agents counted)."""
    a, b = ti.static(PLANES[plane])
    for e in range(n):
        fx, fy = _direction(dirs, e, row, mode, normalise)
        inv = ti.cast(inv_pixel, ti.f32)
        i = _pixel_index(ti.cast(pos[a, e], ti.f32), ti.cast(lo[a], ti.f32), inv, size, wrap)
        j = _pixel_index(ti.cast(pos[b, e], ti.f32), ti.cast(lo[b], ti.f32), inv, size, wrap)
        _add(count, sums, plane, j * size + i, size, 1, ti.cast(fx, ti.i64), ti.cast(fy, ti.i64))


@ti.func
def _classify_pixel(c, sx, sy, n_agents, units, pixel_units):
    """The colour class of a pixel with count c and direction sums (sx, sy): n_agents lie in `units` grid units
    (cells, or pixels), `pixel_units` of them in this pixel (fewer at the edge of a grid of cells)."""
    out = 0
    if c > 0:
        level = DENSITY_LEVELS - 1
        scaled = 2 * ti.cast(c, ti.i64) * units  # 2 x count / mean count, times n_agents x pixel_units
        for q in ti.static(range(DENSITY_LEVELS - 2, -1, -1)):
            if scaled <= _DENSITY_HALVES[q] * n_agents * pixel_units:
                level = q
        fx = ti.cast(sx, ti.f64)
        fy = ti.cast(sy, ti.f64)
        length = ti.sqrt(fx * fx + fy * fy) / (ti.cast(c, ti.f64) * DIRECTION_SCALE)
        ordered = ti.select(length >= ti.max(ORDERED, ti.sqrt(CHANCE_Z / ti.cast(c, ti.f64))), 1, 0)
        hue = 0
        if fx != 0 or fy != 0:
            hue = _hue(fx, fy)
        out = 1 + (hue * DENSITY_LEVELS + level) * ORDER_LEVELS + ordered
    return out


@ti.func
def _hue(fx, fy):
    """round(atan2(fy, fx) / (2 pi / HUES)) mod HUES for a direction (fx, fy) != 0 in float64, without atan2 (Vulkan's
    shaders have none in 64 bits): the angle from the nearer axis, in [0, 45] degrees, against the sectors' edges
    there (:data:`_OCTANT_EDGES`), then the quadrant. An edge's tangent is irrational, so the integer sums never lie
    on one and the rounding direction there does not arise."""
    ax, ay = ti.abs(fx), ti.abs(fy)
    near, far = ti.min(ax, ay), ti.max(ax, ay)
    past = 0  # edges between the nearer axis and the direction
    for e in ti.static(_OCTANT_EDGES):
        past += ti.select(near >= far * ti.f64(e), 1, 0)  # (ti.f64: a float64 constant at any precision)
    quarter = HUES // 4
    q = ti.select(ax >= ay, past, quarter - past)  # sectors from the +x side of the direction's quadrant
    hue = q
    if fx < 0:
        hue = ti.select(fy >= 0, 2 * quarter - q, 2 * quarter + q)
    elif fy < 0:
        hue = (HUES - q) % HUES
    return hue


@ti.kernel
def _classify(plane: ti.template(), size: ti.i32, n_agents: ti.i64, count: ti.types.ndarray(),
              sums: ti.types.ndarray(), classes: ti.types.ndarray(), counts: ti.types.ndarray()):
    """Each pixel's class and count from :func:`_bin`'s arrays, which are cleared for the next frame."""
    for j, i in ti.ndrange(size, size):
        c = count[plane, j, i]
        classes[j, i] = ti.cast(_classify_pixel(c, sums[plane, 0, j, i], sums[plane, 1, j, i], n_agents,
                                                ti.cast(size, ti.i64) * size, 1), ti.u8)
        counts[j, i] = c
        count[plane, j, i] = 0
        sums[plane, 0, j, i] = 0
        sums[plane, 1, j, i] = 0


@ti.kernel
def _from_cells(plane: ti.template(), dim: ti.template(), mode: ti.template(), normalise: ti.template(), nc: ti.i32,
                k: ti.i32,
                size: ti.i32, n_agents: ti.i64, start: ti.types.ndarray(), order: ti.types.ndarray(),
                dirs: ti.types.ndarray(), row: ti.i32, classes: ti.types.ndarray(), counts: ti.types.ndarray()):
    """The field straight from a grid of cells (row-major buckets, x fastest): each pixel is k x k cells of the
    plane (the last row and column fewer where k does not divide nc; in 3D all cells along the projected axis),
    whose agents lie in a few contiguous runs of slots. Parallel over pixels: no atomics, sequential reads."""
    a, b = ti.static(PLANES[plane])
    for pj, pi in ti.ndrange(size, size):
        lo = ti.Vector([0, 0, 0])
        hi = ti.Vector([nc, nc, nc])
        if ti.static(dim == 2):
            hi[2] = 1
        lo[a] = pi * k
        hi[a] = ti.min(nc, (pi + 1) * k)
        lo[b] = pj * k
        hi[b] = ti.min(nc, (pj + 1) * k)
        c = 0
        sx = ti.cast(0, ti.i64)
        sy = ti.cast(0, ti.i64)
        for cz in range(lo[2], hi[2]):
            for cy in range(lo[1], hi[1]):
                first = (cz * nc + cy) * nc
                for s in range(start[first + lo[0]], start[first + hi[0]]):
                    fx, fy = _direction(dirs, order[s], row, mode, normalise)
                    c += 1
                    sx += fx
                    sy += fy
        units = ti.cast(nc, ti.i64) * nc
        if ti.static(dim == 3):
            units *= nc
        pixel_units = ti.cast((hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]), ti.i64)
        classes[pj, pi] = ti.cast(_classify_pixel(c, sx, sy, n_agents, units, pixel_units), ti.u8)
        counts[pj, pi] = c


@ti.kernel
def _bounds(n: ti.i32, dim: ti.template(), pos: ti.types.ndarray(), out: ti.types.ndarray()):
    """out[0] = lowest, out[1] = highest finite coordinate of each axis (blocks of agents, then atomics)."""
    for blk in range((n + CHUNK - 1) // CHUNK):
        lo = ti.Vector([ti.math.inf] * dim, dt=ti.f64)
        hi = ti.Vector([-ti.math.inf] * dim, dt=ti.f64)
        for e in range(blk * CHUNK, ti.min(n, (blk + 1) * CHUNK)):
            for d in ti.static(range(dim)):
                x = ti.cast(pos[d, e], ti.f64)
                if ti.abs(x) < ti.math.inf:  # false for nan too
                    lo[d] = ti.min(lo[d], x)
                    hi[d] = ti.max(hi[d], x)
        for d in ti.static(range(dim)):
            ti.atomic_min(out[0, d], lo[d])
            ti.atomic_max(out[1, d], hi[d])


class Field:
    """The field of n agents in `dim` dimensions, at most ``size`` pixels a side (one image in 2D, three projections
    in 3D). From the model's cell grid where its buckets are rows of cells (a box, or a bounded open-space grid):
    pixels of whole cells; otherwise (hashed cells, a periodic window, batches) by binning the agents' positions
    over the box or, in open space, the square around all agents."""

    def __init__(self, n: int, dim: int, size: int) -> None:
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim}")
        if size < 1:
            raise ValueError(f"size must be positive, got {size}")
        self.n, self.dim, self.size = n, dim, size
        self.planes = 1 if dim == 2 else 3
        self._binned: tuple[ti.Ndarray, ti.Ndarray] | None = None  # count and sums of the binning path
        self._on_cpu = impl.current_cfg().arch in CPU_ARCHES  # binning: chunks in order (CPU), or an agent a thread

    def compute(self, pos: ti.Ndarray, dirs: ti.Ndarray, *, box: float, bounded: bool, grid=None,
                mode: int = VECTORS, row: int = 0, rolled: np.ndarray | None = None) -> list[FieldImage]:
        """The field of the agents at `pos` (component-major (dim, n)) with directions `dirs` in the same order
        (:data:`VECTORS` or :data:`UNIT_VECTORS` (dim, n), :data:`ANGLES` (n,), or row `row` of a (rows, n) array
        with :data:`ANGLE_ROW`). `grid`: the model's :class:`~tflock.neighbors.CellGrid`, built for these positions.
        `rolled`: a periodic box drawn from this corner (any point) instead of from 0, as a frame whose positions
        are wrap(x - rolled) draws it: each agent is binned there, and the images keep origin 0."""
        if rolled is not None:  # the corner taken into the box: x - corner then lies within a side of it
            corner = np.mod(np.asarray(rolled, np.float64), float(box))
            return self._from_agents(pos, dirs, corner, float(box), mode, row, wrap=True)
        if grid is not None and cell_layout(grid):
            return self._from_cells(grid, dirs, mode, row)
        if bounded:
            lo, side = np.zeros(self.dim), float(box)
        else:
            lo, side = window(*bounds(self.n, self.dim, pos), box)
        return self._from_agents(pos, dirs, lo, side, mode, row)

    def _normalise(self, mode: int) -> bool:
        """Whether directions must be made unit: any vectors, and 3D projections."""
        return mode == VECTORS or self.dim == 3

    def _from_cells(self, grid, dirs: ti.Ndarray, mode: int, row: int) -> list[FieldImage]:
        g = grid.geometry
        nc = g.cells_per_side
        k = -(-nc // self.size)
        size = -(-nc // k)
        corner = grid.bounds.to_numpy()[0] * g.cell_size if g.boundary == BOUNDED else np.zeros(self.dim)
        images = []
        for plane in range(self.planes):
            classes = np.zeros((size, size), np.uint8)  # written in place on the CPU
            counts = np.zeros((size, size), np.int32)
            _from_cells(plane, self.dim, mode, self._normalise(mode), nc, k, size, self.n, grid.start, grid.order,
                        dirs, row, classes, counts)
            a, b = PLANES[plane]
            images.append(FieldImage(PLANE_NAMES[plane], classes, (float(corner[a]), float(corner[b])),
                                     k * g.cell_size, int(counts.sum())))
        return images

    def _from_agents(self, pos: ti.Ndarray, dirs: ti.Ndarray, lo: np.ndarray, side: float, mode: int,
                     row: int, wrap: bool = False) -> list[FieldImage]:
        size = self.size
        if self._binned is None:
            self._binned = (ti.ndarray(ti.i32, (self.planes, size, size)),
                            ti.ndarray(ti.i64, (self.planes, 2, size, size)))
            for arr in self._binned:
                arr.fill(0)
        count, sums = self._binned
        lo64 = np.ascontiguousarray(lo, dtype=np.float64)
        images = []
        binning = _bin if self._on_cpu else _bin_each
        for plane in range(self.planes):
            binning(self.n, mode, self._normalise(mode), plane, wrap, pos, dirs, row, lo64, size / side, size, count,
                    sums)
            classes = np.zeros((size, size), np.uint8)
            counts = np.zeros((size, size), np.int32)
            _classify(plane, size, self.n, count, sums, classes, counts)
            a, b = PLANES[plane]
            origin = (0.0, 0.0) if wrap else (float(lo64[a]), float(lo64[b]))
            images.append(FieldImage(PLANE_NAMES[plane], classes, origin, side / size, int(counts.sum())))
        return images


def cell_layout(grid) -> bool:
    """Whether a grid's buckets are rows of cells the field can take pixels from (a box or a bounded open-space
    layout, one replica)."""
    return grid.replicas == 1 and grid.geometry.boundary in (PERIODIC, REFLECTING, BOUNDED)


def window(lo: np.ndarray, hi: np.ndarray, box: float) -> tuple[np.ndarray, float]:
    """Open space: the square (cube) around the bounds ``lo``..``hi`` of all agents with a margin of 2 % on each
    side (at least 1e-6 of `box`), as ``(lower corner, side)``."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    side = max(float(np.max(hi - lo)) * 1.04, 1e-6 * box)
    return (lo + hi) / 2 - side / 2, side


def bounds(n: int, dim: int, pos: ti.Ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest finite coordinates of the agents at `pos` (component-major (dim, n)); zeros and ones
    when no coordinate is finite."""
    out = np.array([[np.inf] * dim, [-np.inf] * dim], dtype=np.float64)
    _bounds(n, dim, pos, out)
    if not np.all(np.isfinite(out)):
        return np.zeros(dim), np.ones(dim)
    return out[0], out[1]


def reference_field(pos: np.ndarray, dirs: np.ndarray, origin: np.ndarray, cell: float, nc: int, k: int = 1,
                    normalise: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """NumPy reference of :class:`Field`: (classes, counts), each (planes, size, size), of agents at `pos` (n, dim)
    with directions `dirs` ((n, dim) vectors or (n,) angles) on a grid of nc cells a side of side `cell` from
    `origin`, k x k cells a pixel (the binning path: nc = size pixels, k = 1); `normalise` False: 2D unit vectors
    taken as they are (:data:`UNIT_VECTORS`)."""
    pos = np.asarray(pos, np.float64)
    n, dim = pos.shape
    d = np.asarray(dirs, np.float64)
    if d.ndim == 1:
        d = np.stack([np.cos(d), np.sin(d)], axis=1)
    size = -(-nc // k)
    planes = 1 if dim == 2 else 3
    cells = np.clip(np.floor((pos - np.asarray(origin, np.float64)) / cell), 0, nc - 1).astype(np.int64)
    classes = np.zeros((planes, size, size), np.uint8)
    counts = np.zeros((planes, size, size), np.int64)
    units = nc**dim
    for p in range(planes):
        a, b = PLANES[p]
        i, j = cells[:, a] // k, cells[:, b] // k
        u = d[:, :2].astype(np.float32)  # every plane's hue: the xy projection's direction
        norm = np.sqrt((u * u).sum(axis=1, dtype=np.float32)) if normalise or dim == 3 else np.ones(n, np.float32)
        scale = np.divide(np.float32(DIRECTION_SCALE), norm, out=np.zeros_like(norm), where=norm > 0)
        fixed = np.floor(u * scale[:, None] + np.float32(0.5)).astype(np.int64)
        sums = np.zeros((2, size, size), np.int64)
        np.add.at(counts[p], (j, i), 1)
        for c in range(2):
            np.add.at(sums[c], (j, i), fixed[:, c])
        for jj, ii in zip(*np.nonzero(counts[p]), strict=True):
            width = min(nc, (ii + 1) * k) - ii * k
            height = min(nc, (jj + 1) * k) - jj * k
            pixel_units = width * height * (nc if dim == 3 else 1)
            classes[p, jj, ii] = _reference_class(int(counts[p, jj, ii]), int(sums[0, jj, ii]), int(sums[1, jj, ii]),
                                                  n, units, pixel_units)
    return classes, counts


def _reference_class(c: int, sx: int, sy: int, n_agents: int, units: int, pixel_units: int) -> int:
    level = DENSITY_LEVELS - 1
    for q in range(DENSITY_LEVELS - 2, -1, -1):
        if 2 * c * units <= _DENSITY_HALVES[q] * n_agents * pixel_units:
            level = q
    ordered = int(math.hypot(sx, sy) / (c * DIRECTION_SCALE) >= max(ORDERED, math.sqrt(CHANCE_Z / c)))
    hue = 0
    if sx or sy:
        hue = math.floor(math.atan2(sy, sx) * (HUES / (2 * math.pi)) + 0.5) % HUES
    return class_of(hue, level, ordered)
