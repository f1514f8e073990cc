"""Observables of the flocking transition (Chate, Ginelli, Gregoire & Raynaud, PRE 77 046113, 2008; issue 29).

- **Binder cumulant** of the order parameter phi, G = 1 - <phi^4> / (3 <phi^2>^2), and the **susceptibility**
  chi = N (<phi^2> - <phi>^2), over samples of phi (the logged steps of the second half of a run, and the
  replicas of a sweep point): :func:`binder_cumulant`, :func:`susceptibility`, :func:`order_statistics`. G = 2/3
  for a perfectly ordered swarm; for N independent uniform headings G = (N + 1) / (3N) in 2D and (4N + 2) / (9N)
  in 3D (their means <|sum e|^4> = 2N^2 - N and N^2 + 2N(N - 1)/3). Near a discontinuous transition G dips below
  zero in large enough systems (coexisting ordered and disordered states give phi a two-peaked law).
- **Giant number fluctuations**: the agents are counted in the M^d boxes of side L / M of a periodic or
  reflecting box (:func:`box_counts`, a kernel over all agents counting in integers, so the counts do not depend
  on the thread count), for M = 4, 8, ... up to boxes that hold about one agent on average (at most 256 per side
  in 2D, 32 in 3D); boxes of side 2L / M are sums of 2^d boxes of side L / M. The standard deviation Delta N of
  the count against its mean <N> grows as <N>^a: a = 1/2 for independent agents, about 0.8 in the ordered phase
  of the 2D Vicsek model (Chate et al. 2008). :func:`number_fluctuations` gives Delta N per M and the fitted a.
- **Bands**: the density profile along the box axis nearest to the mean heading (:func:`axis_profile`, a 1D
  histogram in a kernel, L // R bins, 8 to PROFILE_BINS), smoothed over BAND_SMOOTHING bins; :func:`band_statistics`
  counts its peaks (runs of bins above BAND_THRESHOLD times the mean density; circular in a periodic box) and its
  contrast (largest minus smallest smoothed density, in units of the mean). Travelling bands near the threshold
  give one peak or more; a homogeneous state, ordered or not, gives none.

The kernels' NumPy references are in :mod:`tflock.reference.observables`.
"""

import itertools
import math
from collections.abc import Hashable, Mapping, Sequence

import numpy as np
import taichi as ti
from taichi.lang import impl

from tflock.cpu_tasks import TASK_STRIDE, task_at
from tflock.taichi_host import CPU_ARCHES, host_array, host_view, small_host_view

#: metrics that are order parameters: the sweep tables give their Binder cumulant and susceptibility
ORDER_PARAMETERS = ("polarization", "phi_theta")
#: number fluctuations: the coarsest boxes per side, and the finest at most, in 2D and 3D
GNF_COARSEST = 4
GNF_FINEST = {2: 256, 3: 32}
#: bands: profile bins at most, smoothing window (bins, odd), and the density (in units of the mean) above which a
#: bin belongs to a peak
PROFILE_BINS = 512
BAND_SMOOTHING = 5
BAND_THRESHOLD = 1.5
_SMOOTHING = np.ones(BAND_SMOOTHING) / BAND_SMOOTHING
#: per dimension, the slices that pick each of the 2^dim boxes of side 1/m inside the boxes of side 2/m
_CORNERS = {dim: [tuple(slice(o, None, 2) for o in corner) for corner in itertools.product((0, 1), repeat=dim)]
            for dim in (2, 3)}


# ---------------------------------------------------------------------------------------------------- statistics


def binder_cumulant(phi: np.ndarray) -> float:
    """G = 1 - <phi^4> / (3 <phi^2>^2) over the samples `phi` (NaN without samples, or all zero)."""
    phi = np.asarray(phi, dtype=np.float64).ravel()
    m2 = float(np.mean(phi**2)) if phi.size else 0.0
    return 1.0 - float(np.mean(phi**4)) / (3.0 * m2 * m2) if m2 > 0 else math.nan


def susceptibility(phi: np.ndarray, n: int) -> float:
    """chi = N (<phi^2> - <phi>^2) over the samples `phi` of a system of N agents."""
    phi = np.asarray(phi, dtype=np.float64).ravel()
    return float(n * np.var(phi)) if phi.size else math.nan


def order_statistics(samples: Mapping[str, np.ndarray], n: int, suffix: str = "") -> dict[str, float]:
    """``binder_<m><suffix>`` and ``susceptibility_<m><suffix>`` of each order parameter m among `samples`."""
    out = {}
    for name in ORDER_PARAMETERS:
        if name in samples:
            out[f"binder_{name}{suffix}"] = binder_cumulant(samples[name])
            out[f"susceptibility_{name}{suffix}"] = susceptibility(samples[name], n)
    return out


# ---------------------------------------------------------------------------------------------------- kernels


def count_parts() -> int:
    """Partial tables a count kernel fills on the CPU: one per thread, each from its own share of the agents with
    plain increments, summed after (an atomic add per agent costs several times an increment); 0 on a GPU, whose
    kernels count into one table with atomics. Integer counts: the sum does not depend on the parts."""
    config = impl.current_cfg()
    return max(1, config.cpu_max_num_threads) if config.arch in CPU_ARCHES else 0


@ti.func
def _share(c, parts, n):
    """First agent of part c of `parts` even shares of n (64-bit products: n may be near 2^31)."""
    return ti.cast(ti.cast(c, ti.i64) * n // parts, ti.i32)


@ti.func
def _box_of(e, m, scale, dim: ti.template(), pos: ti.template()):
    """Box of agent e among m^dim boxes of side 1 / scale (coordinates truncated, clamped to the box)."""
    b = 0
    for a in ti.static(range(dim - 1, -1, -1)):  # row-major, the last axis slowest
        b = b * m + ti.math.clamp(ti.cast(pos[a, e] * scale, ti.i32), 0, m - 1)
    return b


@ti.func
def _slab_of(e, r, bins, scale, pos: ti.template(), axis: ti.template()):
    """Slab of agent e (of replica r) across axis[r], of `bins` of width 1 / scale."""
    return ti.math.clamp(ti.cast(pos[axis[r], e] * scale, ti.i32), 0, bins - 1)


@ti.func
def _replica_of(e, per_replica, batched: ti.template(), ids: ti.template()):
    """Replica of agent e: its id // per_replica in a batch, else 0 (no division: it costs more than the count)."""
    r = 0
    if ti.static(batched):
        r = ids[e] // per_replica
    return r


@ti.kernel
def _box_counts(n: ti.i32, per_replica: ti.i32, m: ti.i32, scale: float, bins: ti.i32, slab_scale: float,
                dim: ti.template(), parts: ti.template(), batched: ti.template(), slabs: ti.template(),
                pos: ti.types.ndarray(), ids: ti.types.ndarray(), counts: ti.types.ndarray(),
                axis: ti.types.ndarray(), hist: ti.types.ndarray()):
    """counts[c, r, b]: agents of part c of replica r in box b, `parts` of them (:func:`count_parts`; 0: one table
    filled with atomics); where `slabs`, also :func:`_axis_profile`'s slab counts in `hist`, in the same pass over
    the agents (one read of the positions for both tables)."""
    if ti.static(parts > 0):
        for t in range(parts * TASK_STRIDE):  # a part a task (tflock.cpu_tasks)
            c = task_at(t)
            if c >= 0:
                for e in range(_share(c, parts, n), _share(c + 1, parts, n)):
                    r = _replica_of(e, per_replica, batched, ids)
                    counts[c, r, _box_of(e, m, scale, dim, pos)] += 1
                    if ti.static(slabs):
                        hist[c, r, _slab_of(e, r, bins, slab_scale, pos, axis)] += 1
    else:
        for e in range(n):
            r = _replica_of(e, per_replica, batched, ids)
            ti.atomic_add(counts[0, r, _box_of(e, m, scale, dim, pos)], 1)
            if ti.static(slabs):
                ti.atomic_add(hist[0, r, _slab_of(e, r, bins, slab_scale, pos, axis)], 1)


@ti.kernel
def _axis_profile(n: ti.i32, per_replica: ti.i32, bins: ti.i32, scale: float, parts: ti.template(),
                  batched: ti.template(), pos: ti.types.ndarray(), ids: ti.types.ndarray(), axis: ti.types.ndarray(),
                  hist: ti.types.ndarray()):
    """hist[c, r, b]: agents of part c of replica r in slab b across axis[r] (`parts` as in :func:`_box_counts`)."""
    if ti.static(parts > 0):
        for t in range(parts * TASK_STRIDE):  # a part a task (tflock.cpu_tasks)
            c = task_at(t)
            if c >= 0:
                for e in range(_share(c, parts, n), _share(c + 1, parts, n)):
                    r = _replica_of(e, per_replica, batched, ids)
                    hist[c, r, _slab_of(e, r, bins, scale, pos, axis)] += 1
    else:
        for e in range(n):
            r = _replica_of(e, per_replica, batched, ids)
            ti.atomic_add(hist[0, r, _slab_of(e, r, bins, scale, pos, axis)], 1)


def _tables(parts: int, *shape: int) -> ti.Ndarray:
    """The i32 tables a count kernel fills: (max(parts, 1), *shape)."""
    return ti.ndarray(ti.i32, (max(parts, 1), *shape))


def _summed(tables: ti.Ndarray) -> np.ndarray:
    """The partial tables (parts, ...) of a count kernel, summed."""
    values = host_array(tables)
    return values[0].copy() if len(values) == 1 else values.sum(axis=0, dtype=values.dtype)


def _host_bins(pos: ti.Ndarray, ids: ti.Ndarray, per_replica: int, replicas: int, per_side: int, scale: float,
               axes: Sequence[int] | None) -> np.ndarray | None:
    """What :func:`box_counts` (`axes` None) or :func:`axis_profile` (bins along each replica's axis) count, with
    NumPy on the arrays' host memory, for a small swarm on the CPU (:func:`small_host_view`; None otherwise): the same
    integer counts as the kernels (each coordinate times `scale` in the arrays' precision, truncated, clamped), with
    no kernel launch, which costs more than counting a small swarm."""
    n = pos.shape[1]
    x = small_host_view(pos, n)
    if x is None:
        return None
    replica = host_view(ids)[:n] // per_replica if replicas > 1 else np.zeros(n, dtype=np.int64)
    with np.errstate(invalid="ignore"):  # a non-finite coordinate counts in the first box, as in the kernels
        cells = (x[:, :n] * x.dtype.type(scale)).astype(np.int64)  # truncated
    np.maximum(np.minimum(cells, per_side - 1, out=cells), 0, out=cells)  # clamped (np.clip's wrapper costs more)
    if axes is None:
        index = np.zeros(n, dtype=np.int64)
        for a in range(x.shape[0] - 1, -1, -1):  # row-major, the last axis slowest
            index = index * per_side + cells[a]
        size = per_side ** x.shape[0]
    else:
        index, size = cells[np.asarray(axes, dtype=np.int64)[replica], np.arange(n)], per_side
    return np.bincount(replica * size + index, minlength=replicas * size).reshape(replicas, size)


def box_counts(pos: ti.Ndarray, ids: ti.Ndarray, per_replica: int, replicas: int, box: float, m: int,
               counts: ti.Ndarray | None = None) -> np.ndarray:
    """Agents in each of the m^d boxes of side box / m, per replica: (replicas, m, ..., m) ints, the first box axis
    the last coordinate (row-major). `pos` (d, n) and `ids` in any arrangement of the agents. `counts`: i32 tables
    (parts, replicas, m^d) to count in, one part per CPU thread (:func:`count_parts`) or any number (a new one when
    None: making one costs about a millisecond)."""
    dim, n = pos.shape
    host = _host_bins(pos, ids, per_replica, replicas, m, m / box, None)
    if host is not None:
        return host.reshape((replicas,) + (m,) * dim)
    counts = _count_boxes(pos, ids, per_replica, replicas, box, m, counts)
    return _summed(counts).reshape((replicas,) + (m,) * dim)


def _count_boxes(pos: ti.Ndarray, ids: ti.Ndarray, per_replica: int, replicas: int, box: float, m: int,
                 counts: ti.Ndarray | None,
                 profile: tuple[Sequence[int], int, tuple[ti.Ndarray, ti.Ndarray]] | None = None) -> ti.Ndarray:
    """:func:`box_counts`' kernel: the partial tables, filled; with `profile` = (axes, bins, buffers), also
    :func:`axis_profile`'s in its buffers, in the same pass."""
    dim, n = pos.shape
    parts = count_parts()
    if counts is None:
        counts = _tables(parts, replicas, m**dim)
    elif parts:  # the tables given
        parts = counts.shape[0]
    counts.fill(0)
    axis, hist = counts, counts  # (unused without a profile)
    bins = 1
    if profile is not None:
        axes, bins, (axis, hist) = profile
        axis.from_numpy(np.asarray(axes, dtype=np.int32))
        hist.fill(0)
    _box_counts(n, per_replica, m, m / box, bins, bins / box, dim, parts, replicas > 1, profile is not None, pos, ids,
                counts, axis, hist)
    return counts


def axis_profile(pos: ti.Ndarray, ids: ti.Ndarray, per_replica: int, axes: Sequence[int], box: float,
                 bins: int, buffers: tuple[ti.Ndarray, ti.Ndarray] | None = None) -> np.ndarray:
    """Agents in each of `bins` slabs of width box / bins across axis ``axes[r]``, per replica r: (replicas, bins).
    `buffers`: i32 ndarrays (replicas,) for the axes and (parts, replicas, bins) to count in, as `counts` of
    :func:`box_counts` (new ones when None)."""
    n = pos.shape[1]
    replicas = len(axes)
    host = _host_bins(pos, ids, per_replica, replicas, bins, bins / box, axes)
    if host is not None:
        return host
    parts = count_parts()
    if buffers is None:
        buffers = (ti.ndarray(ti.i32, replicas), _tables(parts, replicas, bins))
    axis, hist = buffers
    if parts:  # the tables given
        parts = hist.shape[0]
    axis.from_numpy(np.asarray(axes, dtype=np.int32))
    hist.fill(0)
    _axis_profile(n, per_replica, bins, bins / box, parts, replicas > 1, pos, ids, axis, hist)
    return _summed(hist)


# ---------------------------------------------------------------------------------------------------- summaries


def gnf_levels(n: int, dim: int, box: float) -> list[int]:
    """Boxes per side M of the number fluctuations, coarsest first: 4, 8, ... while a box holds about one agent or
    more on average (n / M^dim >= 1, in integers: any box size, 1e300 included), at most GNF_FINEST[dim]; empty when
    even 4 per side would hold less. The levels depend on n and dim only (`box` is kept for the callers)."""
    levels = []
    m = GNF_COARSEST
    while m <= GNF_FINEST[dim] and m**dim <= n:
        levels.append(m)
        m *= 2
    return levels


def number_fluctuations(counts: np.ndarray) -> tuple[dict[int, float], float]:
    """From one system's finest box counts (m, ..., m): the standard deviation of the count for each M = m, m/2,
    ... >= GNF_COARSEST, and the exponent a of Delta N ~ <N>^a fitted (least squares, logs) over those M (NaN with
    fewer than two, or a zero deviation). Each deviation is exact but for its last rounding: the counts' sum of
    squares in integers, so the variance (K sum c^2 - (sum c)^2) / K^2 has no cancellation error."""
    dim, m = counts.ndim, counts.shape[0]
    c = np.asarray(counts, dtype=np.int64)
    total = int(c.sum())
    std = {}
    while m >= GNF_COARSEST:
        flat = c.reshape(-1)
        boxes = flat.size
        std[m] = math.sqrt(int(flat @ flat) * boxes - total * total) / boxes
        m //= 2
        c = sum(c[corner] for corner in _CORNERS[dim])  # the 2^dim boxes of each coarser box (strided views)
    if len(std) < 2 or min(std.values()) <= 0.0:
        return std, math.nan
    # least-squares slope of log std against log mean, in closed form over these few levels (NumPy's calls cost
    # more than the arithmetic: a small swarm takes this at every metrics step)
    x = [math.log(total / k**dim) for k in std]
    y = [math.log(v) for v in std.values()]
    x_mean, y_mean = sum(x) / len(x), sum(y) / len(y)
    dx = [v - x_mean for v in x]
    return std, sum(a * (b - y_mean) for a, b in zip(dx, y, strict=True)) / sum(a * a for a in dx)


def band_statistics(hist: np.ndarray, periodic: bool) -> tuple[float, float, np.ndarray]:
    """From one system's slab counts: the number of density peaks, the contrast, and the smoothed density profile
    in units of the mean (see the module)."""
    density = np.asarray(hist, dtype=np.float64) / max(float(np.mean(hist)), 1e-300)
    half = BAND_SMOOTHING // 2
    padded = np.empty(len(density) + 2 * half)  # wrapped round a periodic box, else the edge values repeated
    padded[half:-half] = density
    padded[:half] = density[-half:] if periodic else density[0]
    padded[-half:] = density[:half] if periodic else density[-1]
    smooth = np.convolve(padded, _SMOOTHING, mode="valid")
    high = smooth > BAND_THRESHOLD
    before = np.empty_like(high)  # each bin's left neighbour: the last bin in a periodic box, none at a wall
    before[1:] = high[:-1]
    before[0] = high[-1] and periodic
    starts = np.count_nonzero(high > before)  # a run of high bins starts where its left neighbour is not high
    peaks = starts if not (periodic and high.all()) else 0
    return float(peaks), float(smooth.max() - smooth.min()), smooth


def profile_bins(box: float, radius: float) -> int:
    """Slabs of the band profile: L // R (slabs of side about R), at most PROFILE_BINS, at least 8."""
    return int(min(PROFILE_BINS, max(8, box // radius)))


class TransitionObservables:
    """The number-fluctuation and band metrics of a model in a periodic or reflecting box (none in open space),
    for one system or a batch of replicas."""

    def __init__(self, n: int, dim: int, boundary: str, box: float, radius: float, replicas: int = 1) -> None:
        self.n, self.dim, self.box, self.replicas = n, dim, box, replicas
        self.periodic = boundary == "periodic"
        self.enabled = boundary != "open"
        self.levels = gnf_levels(n, dim, box) if self.enabled else []
        self.bins = profile_bins(box, radius)
        self.descriptions: dict[str, str] = {}
        self.profile_descriptions: dict[str, str] = {}
        if not self.enabled:
            return
        # the kernels' outputs, made once (small swarms observe every step or so)
        parts = count_parts()
        self._counts = _tables(parts, replicas, self.levels[-1] ** dim) if self.levels else None
        self._profile = (ti.ndarray(ti.i32, replicas), _tables(parts, replicas, self.bins))
        self._last_profile: tuple[Hashable, tuple[int, ...], np.ndarray] | None = None  # see profiles()
        self.profile_descriptions["band_profile"] = (f"density along the axis nearest to the mean heading, in "
                                                     f"{self.bins} slabs, / mean density")
        if len(self.levels) >= 2:
            self.descriptions["gnf_exponent"] = "giant number fluctuations: a in Delta N ~ <N>^a (0.5 uniform)"
        for m in self.levels:
            self.descriptions[f"gnf_std_{m}"] = (f"std of the agents in a box of side L/{m} (mean "
                                                 f"{n / m**dim:.4g})")
        self.descriptions["band_peaks"] = "density peaks (bands) along the axis nearest to the mean heading"
        self.descriptions["band_contrast"] = "band contrast: max - min smoothed density / mean density"

    def compute(self, pos: ti.Ndarray, ids: ti.Ndarray, mean_direction: np.ndarray,
                state: Hashable | None = None) -> dict[str, np.ndarray]:
        """The metrics of each replica (arrays of length ``replicas``); `mean_direction` (replicas, d) picks the
        profile's axis; `state`: see :meth:`profiles`."""
        if not self.enabled:
            return {}
        out: dict[str, np.ndarray] = {}
        hist = None
        if self.levels:
            counts, hist = self._finest_counts(pos, ids, mean_direction, state)
            fits = [number_fluctuations(c) for c in counts]
            if len(self.levels) >= 2:
                out["gnf_exponent"] = np.array([a for _, a in fits])
            for m in self.levels:
                out[f"gnf_std_{m}"] = np.array([std[m] for std, _ in fits])
        if hist is None:
            hist = self.profiles(pos, ids, mean_direction, state)
        bands = [band_statistics(h, self.periodic) for h in hist]
        out["band_peaks"] = np.array([b[0] for b in bands])
        out["band_contrast"] = np.array([b[1] for b in bands])
        return out

    def frame_profiles(self, pos: ti.Ndarray, ids: ti.Ndarray, mean_direction: np.ndarray,
                       state: Hashable | None = None) -> dict[str, np.ndarray]:
        """The profiles a frame of one system carries: the slab density along the axis nearest to its mean heading
        (`mean_direction`, (d,)), in units of the mean density (none in open space); `state`: see
        :meth:`profiles`."""
        if not self.enabled:
            return {}
        hist = self.profiles(pos, ids, np.asarray(mean_direction)[None], state)[0]
        return {"band_profile": hist * (self.bins / self.n)}

    def _finest_counts(self, pos: ti.Ndarray, ids: ti.Ndarray, mean_direction: np.ndarray,
                       state: Hashable | None) -> tuple[np.ndarray, np.ndarray | None]:
        """:func:`box_counts` at the finest level, and :meth:`profiles`' slab counts where a kernel counts them in
        the same pass (else None: a small swarm's NumPy counts)."""
        m = self.levels[-1]
        if small_host_view(pos, pos.shape[1]) is not None:
            return box_counts(pos, ids, self.n, self.replicas, self.box, m, self._counts), None
        axes = self._axes(mean_direction)
        _count_boxes(pos, ids, self.n, self.replicas, self.box, m, self._counts, (axes, self.bins, self._profile))
        hist = _summed(self._profile[1])
        self._last_profile = (state, axes, hist) if state is not None else None
        return _summed(self._counts).reshape((self.replicas,) + (m,) * self.dim), hist

    def _axes(self, mean_direction: np.ndarray) -> tuple[int, ...]:
        """Each replica's box axis nearest to its mean heading."""
        return tuple(np.argmax(np.abs(np.asarray(mean_direction).reshape(self.replicas, self.dim)), axis=1).tolist())

    def profiles(self, pos: ti.Ndarray, ids: ti.Ndarray, mean_direction: np.ndarray,
                 state: Hashable | None = None) -> np.ndarray:
        """Slab counts along each replica's axis nearest to its mean heading: (replicas, bins). `state`, when
        given, names the positions (e.g. the model's step and grid build): a second call for the same state and
        axes (a frame drawn at a metrics step) returns the counts of the first instead of counting again."""
        axes = self._axes(mean_direction)
        last = self._last_profile
        if state is not None and last is not None and last[0] == state and last[1] == axes:
            return last[2]
        hist = axis_profile(pos, ids, self.n, axes, self.box, self.bins, self._profile)
        self._last_profile = (state, axes, hist) if state is not None else None
        return hist
