"""The transition's observables (tflock.observables): kernels against their NumPy references, the exact limits of
the Binder cumulant, the number-fluctuation exponent of known point patterns, band counting on known profiles, and
the sweep columns they feed."""

import math

import numpy as np
import pytest
import taichi as ti
from conftest import ARCH, PRECISION

from tflock.observables import (
    axis_profile,
    band_statistics,
    binder_cumulant,
    box_counts,
    gnf_levels,
    number_fluctuations,
    order_statistics,
    susceptibility,
)
from tflock.reference.observables import axis_profile_np, box_counts_np

REAL = np.float64 if PRECISION == "f64" else np.float32


def upload(x: np.ndarray):
    """Positions (n, d) as a component-major ndarray, and ids in a shuffled arrangement."""
    n, dim = x.shape
    perm = np.random.default_rng(0).permutation(n)
    pos = ti.ndarray(ti.f64 if PRECISION == "f64" else ti.f32, (dim, n))
    pos.from_numpy(np.ascontiguousarray(x[perm].T.astype(REAL)))
    ids = ti.ndarray(ti.i32, n)
    ids.from_numpy(perm.astype(np.int32))
    return pos, ids


#: partial tables are the CPU's: count_parts() is 0 on GPU arches, which count into one table with atomics
cpu_only = pytest.mark.skipif(ARCH != "cpu", reason="partial tables are the CPU's (count_parts() is 0 on GPU arches)")


@pytest.mark.parametrize("replicas", [1, 3])
@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("counted", ["kernel", pytest.param("kernel-1-part", marks=cpu_only),
                                     pytest.param("kernel-3-parts", marks=cpu_only), "kernel-atomics", "numpy"])
def test_box_counts_and_profiles_match_reference(engine, dim, counted, replicas, monkeypatch):
    """The kernels (in partial tables, one per CPU thread or as many as asked, or one table with atomics as on a
    GPU), and for small swarms on the CPU NumPy over the arrays' memory, count as the reference does."""
    import tflock.observables
    import tflock.taichi_host

    monkeypatch.setattr(tflock.taichi_host, "SMALL_SWARM_MAX", 0 if counted.startswith("kernel") else 10**6)
    parts = {"kernel-1-part": 1, "kernel-3-parts": 3, "kernel-atomics": 0}
    if counted in parts:
        monkeypatch.setattr(tflock.observables, "count_parts", lambda: parts[counted])
    box, n = 7.0, 600
    rng = np.random.default_rng(dim)
    systems = [rng.uniform(0, box, (n, dim)).astype(REAL) for _ in range(replicas)]
    systems[0][:5] = box  # on the far walls (a reflecting box holds x = L)
    systems[-1][5:8] = np.nextafter(REAL(0), REAL(-1))  # just below 0, truncated into the first box
    pos, ids = upload(np.concatenate(systems))
    axes = [dim - 1, 0, 1][:replicas]
    counts = box_counts(pos, ids, n, replicas, box, 8)
    profiles = axis_profile(pos, ids, n, axes, box, 20)
    for r, x in enumerate(systems):
        np.testing.assert_array_equal(counts[r], box_counts_np(x, box, 8))
        assert counts[r].sum() == n
        np.testing.assert_array_equal(profiles[r], axis_profile_np(x, axes[r], box, 20))


def test_binder_cumulant_of_independent_headings_is_n_plus_1_over_3n():
    """<|sum e|^4> = 2N^2 - N for N independent uniform unit vectors in the plane: G = (N + 1) / (3N)."""
    rng = np.random.default_rng(1)
    for n in (1, 4, 16):
        theta = rng.uniform(0, 2 * math.pi, (400_000, n))
        phi = np.hypot(np.cos(theta).sum(axis=1), np.sin(theta).sum(axis=1)) / n
        assert binder_cumulant(phi) == pytest.approx((n + 1) / (3 * n), abs=0.004), n
    assert binder_cumulant(np.ones(10)) == pytest.approx(2 / 3, abs=1e-15)  # perfect order
    assert math.isnan(binder_cumulant(np.zeros(3)))


def test_susceptibility_and_the_sweep_columns():
    phi = np.array([0.2, 0.4, 0.6])
    assert susceptibility(phi, 100) == pytest.approx(100 * np.var(phi))
    stats = order_statistics({"polarization": phi, "clusters": phi}, 100, suffix="_pooled")
    assert set(stats) == {"binder_polarization_pooled", "susceptibility_polarization_pooled"}


def test_number_fluctuations_of_independent_agents_grow_as_the_square_root():
    rng = np.random.default_rng(3)
    box, n = 64.0, 2 * 64**2
    exponents = []
    for _ in range(5):
        x = rng.uniform(0, box, (n, 2))
        levels = gnf_levels(n, 2, box)
        assert levels == [4, 8, 16, 32, 64]  # boxes down to about one agent each (64 x 64 boxes of 2 agents)
        std, a = number_fluctuations(box_counts_np(x, box, levels[-1]))
        assert std[64] == pytest.approx(math.sqrt(2), rel=0.05)  # Poisson: Delta N = sqrt(<N>)
        exponents.append(a)
    assert np.mean(exponents) == pytest.approx(0.5, abs=0.02)


def test_number_fluctuations_of_a_density_wave_grow_as_the_mean():
    """A density modulated on the scale of the box (1 + 0.6 sin(2 pi x / L)): a box much smaller than the wave holds
    a count proportional to its area times the local density, so Delta N ~ <N> (a = 1), as in the ordered Vicsek
    phase's bands and density waves at their largest; Poisson noise only adds its square root."""
    rng = np.random.default_rng(4)
    box = 64.0
    x = rng.uniform(0, box, (400_000, 2))
    keep = rng.uniform(0, 1.6, len(x)) < 1 + 0.6 * np.sin(2 * np.pi * x[:, 0] / box)
    std, a = number_fluctuations(box_counts_np(x[keep], box, 32))
    assert a == pytest.approx(1.0, abs=0.1)


@pytest.mark.parametrize("dim,m", [(2, 256), (2, 16), (3, 32), (3, 4)])
def test_number_fluctuations_are_the_standard_deviations_of_the_counts(dim, m):
    """Each level's deviation (taken in integers) is NumPy's two-pass std of the summed counts, and the exponent
    the least-squares slope of their logs, for counts from empty boxes to thousands of agents a box."""
    rng = np.random.default_rng(dim * m)
    counts = rng.poisson(rng.uniform(0.05, 2000.0, (m,) * dim))
    std, a = number_fluctuations(counts)
    levels = [m >> k for k in range(int(math.log2(m // 4)) + 1)]
    assert list(std) == levels
    c, means = counts.astype(np.int64), []
    for level in levels:
        assert std[level] == pytest.approx(float(c.std()), rel=1e-13)
        means.append(counts.sum() / level**dim)
        c = c.reshape(sum(((level // 2, 2) for _ in range(dim)), ())).sum(axis=tuple(range(1, 2 * dim, 2)))
    if len(levels) > 1:
        slope = np.polyfit(np.log(means), np.log([std[level] for level in levels]), 1)[0]
        assert a == pytest.approx(slope, rel=1e-10)
    else:
        assert math.isnan(a)


def test_a_lattice_has_no_number_fluctuations():
    xs, ys = np.meshgrid(np.arange(32) + 0.5, np.arange(32) + 0.5)
    std, a = number_fluctuations(box_counts_np(np.stack([xs.ravel(), ys.ravel()], axis=1), 32.0, 16))
    assert all(v == 0 for v in std.values()) and math.isnan(a)


def test_band_counting():
    bins = np.arange(100)
    flat = np.full(100, 50)
    assert band_statistics(flat, periodic=True)[:2] == (0.0, 0.0)
    two = flat + 100 * ((np.abs(bins - 20) < 5) | (np.abs(bins - 70) < 5))
    peaks, contrast, smooth = band_statistics(two, periodic=True)
    assert peaks == 2 and contrast > 1 and len(smooth) == 100
    wrapped = flat + 100 * ((bins < 4) | (bins > 95))  # one band across the periodic edge
    assert band_statistics(wrapped, periodic=True)[0] == 1
    assert band_statistics(wrapped, periodic=False)[0] == 2  # walls: two half bands
    noisy = np.random.default_rng(5).poisson(50, 100)  # Poisson noise of a uniform gas is no band
    assert band_statistics(noisy, periodic=True)[0] == 0


def test_a_sweep_point_reaches_the_binder_limits(cpu_engine):
    """Through the whole chain (model, metrics every step, second half, replicas): eta = 2 pi redraws every heading
    uniformly at every step, so the pooled G is (N + 1) / (3N) (2000 samples: standard error 0.01); eta = 0 in a
    box where every agent sees every other aligns them all in one step, so G = 2/3."""
    from tflock.sweep.point import run_point

    base = {"model": "vicsek", "steps": 1000, "log": {"metrics_every": 1}, "engine": {"precision": PRECISION},
            "params": {"n": 8, "box": 1.0, "radius": 2.0, "speed": 0.1}}
    rows = run_point({**base, "params": {**base["params"], "noise": 2 * math.pi}}, replicas=4, seed=1)
    assert rows[0]["binder_polarization_pooled"] == pytest.approx(9 / 24, abs=0.04)
    assert rows[0]["binder_polarization_pooled"] == rows[3]["binder_polarization_pooled"]
    assert abs(rows[0]["binder_polarization"] - 9 / 24) < 0.08  # one replica alone: 500 samples
    assert rows[0]["susceptibility_polarization_pooled"] == pytest.approx(8 * (1 / 8 - (math.pi / 4) / 8), rel=0.1)
    rows = run_point({**base, "steps": 20, "params": {**base["params"], "noise": 0.0}}, replicas=2, seed=1)
    assert rows[1]["binder_polarization_pooled"] == pytest.approx(2 / 3, abs=1e-6)


def test_a_recording_carries_the_band_profile(cpu_engine, tmp_path):
    """A periodic Vicsek run logs the density profile as a bar chart per frame, in units of the mean density, and
    the band and number-fluctuation metrics as series; an open-space run has none of them."""
    from rerun.chunk import RrdReader

    import tflock
    from tflock.record import read_recording

    path = tmp_path / "bands.rrd"
    sim = tflock.Simulation(model="vicsek", params={"n": 500, "box": 16.0, "noise": 0.3}, steps=4,
                            engine={"precision": cpu_engine.precision}, record=path)
    sim.run()
    sim.close()
    summary = read_recording(path)
    assert "/profiles/band_profile" in summary.entities
    assert {"band_peaks", "band_contrast", "gnf_exponent", "gnf_std_4"} <= set(summary.final_metrics)
    charts, positions = [], []
    for chunk in RrdReader(path).stream():
        if chunk.entity_path == "/profiles/band_profile" and chunk.num_rows:
            batch = chunk.to_record_batch()
            if "BarChart:values" in batch.schema.names:
                charts += [np.asarray(v[0]["buffer"]) for v in batch.column("BarChart:values").to_pylist() if v]
            if "BarChart:abscissa" in batch.schema.names:
                positions += [np.asarray(v[0]["buffer"]) for v in batch.column("BarChart:abscissa").to_pylist() if v]
    assert len(charts) == summary.frames
    assert all(len(c) == 16 and c.mean() == pytest.approx(1.0, rel=1e-6) for c in charts)  # slabs of side R = 1
    # each bar drawn at its slab's centre in the box's coordinates (logged once, static)
    assert len(positions) == 1 and np.allclose(positions[0], np.arange(16) + 0.5)

    sim = tflock.Simulation(model="vicsek", params={"n": 50, "boundary": "open"}, steps=2,
                            engine={"precision": cpu_engine.precision})
    assert not any(name.startswith(("band_", "gnf_")) for name in sim.model.metric_descriptions)
    assert sim.model.profile_descriptions == {}


def test_a_frame_profiles_its_own_state(cpu_engine):
    """A frame drawn at a metrics step reuses that step's slab counts and mean heading; it still profiles the state
    it draws: the same bars as a frame of a model that took no metrics, along the axis nearest to the mean heading of
    the NumPy reference, and new bars for a state set at the same step."""
    from tflock.models.vicsek import Vicsek
    from tflock.simulation import Simulation

    config = {"model": "vicsek", "params": {"n": 400, "box": 10.0, "noise": 0.2}, "steps": 30,
              "engine": {"precision": cpu_engine.precision}}
    measured, plain = Simulation(config, record=False).model, Simulation(config, record=False).model
    selected = np.arange(10)
    for model in (measured, plain):
        model.advance(30)
    measured.metrics()
    bars = measured.frame(selected, 0).profiles["band_profile"]
    np.testing.assert_array_equal(bars, plain.frame(selected, 0).profiles["band_profile"])
    state = measured.state()
    theta = state["theta"].astype(np.float64)
    axis = int(np.argmax(np.abs([np.cos(theta).sum(), np.sin(theta).sum()])))
    expected = axis_profile_np(state["x"].astype(REAL), axis, 10.0, 10) * (10 / 400)
    np.testing.assert_allclose(bars, expected)

    moved = dict(state, x=np.ascontiguousarray(state["x"][:, ::-1]))  # the same step, the axes swapped
    measured.set_state(moved, measured.step_index)
    swapped = measured.frame(selected, 0).profiles["band_profile"]
    fresh = Vicsek(measured.params, measured.seed, measured.engine)
    fresh.set_state(moved, measured.step_index)
    np.testing.assert_array_equal(swapped, fresh.frame(selected, 0).profiles["band_profile"])
    assert not np.array_equal(swapped, bars)


def test_giant_number_fluctuations_of_the_ordered_vicsek_phase(cpu_engine):
    """Chate et al. (2008): deep in the ordered phase of the 2D Vicsek model (density 2, v0 = 0.5) the number
    fluctuations are giant, Delta N ~ <N>^0.8; a disordered swarm (eta = 2 pi) has Poisson ones, a = 1/2."""
    import tflock

    exponents = {}
    for noise in (0.3, 2 * math.pi):
        sim = tflock.Simulation(model="vicsek", params={"n": 2048, "box": 32.0, "noise": noise}, steps=600, seed=1,
                                log={"metrics_every": 50}, engine={"precision": cpu_engine.precision})
        sim.run()
        table = sim.metrics()
        exponents[noise] = float(np.mean(table["gnf_exponent"][-6:]))  # steps 350-600
        assert (table["polarization"][-1] > 0.9) == (noise < 1)
    assert exponents[0.3] == pytest.approx(0.8, abs=0.08)
    assert exponents[2 * math.pi] == pytest.approx(0.5, abs=0.06)
