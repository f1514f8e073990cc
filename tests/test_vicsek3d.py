"""The 3D Vicsek model (tflock.models.vicsek3d) against its NumPy reference, and what its noises are by hand.

Step by step from a shared state (tolerance 1e-10 at f64, 3e-4 at f32), a free-running trajectory at f64, the
metrics; then the draws themselves: the angular noise fills the cap of half-angle eta/2 uniformly (cos of the polar
angle uniform), the vectorial noise adds a unit vector of weight eta, and the turn limit stops at alpha.
"""

import math

import numpy as np
import pytest
from conftest import PRECISION

from tflock.config import load_config
from tflock.models.vicsek import Vicsek
from tflock.models.vicsek3d import Vicsek3D
from tflock.reference import vicsek3d as ref3
from tflock.rng import Stream, uniform_np

F64 = PRECISION == "f64"
TOL = 1e-10 if F64 else 3e-4


def config(boundary="periodic", n=300, box=6.0, **extra):
    overrides = {"params.n": n, "params.box": box, "params.radius": 1.0, "params.speed": 0.3, "params.noise": 0.6,
                 "params.dim": 3, "params.boundary": boundary, "seed": 7, "engine.precision": PRECISION}
    overrides.update({f"params.{k}": v for k, v in extra.items()})
    return load_config(overrides=overrides)


def gap(a, b, box=None):
    d = np.abs(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))
    return float((np.minimum(d, box - d) if box else d).max())


def test_dim_3_builds_the_3d_model(engine):
    model = Vicsek(config().params, 7, engine)
    assert isinstance(model, Vicsek3D)
    assert model.state()["x"].shape == (300, 3) and model.world().dim == 3
    d = model.state()["d"].astype(np.float64)
    assert np.allclose(np.linalg.norm(d, axis=1), 1, atol=1e-6)


@pytest.mark.parametrize("boundary,extra", [
    ("periodic", {}),
    ("periodic", {"noise_type": "vectorial"}),
    ("periodic", {"neighbours": "topological", "noise_type": "vectorial"}),
    ("reflecting", {"max_turn_deg": 15.0}),
    ("open", {}),
    ("open", {"neighbours": "topological"}),
])
def test_step_matches_reference(engine, boundary, extra):
    cfg = config(boundary, **extra)
    box = cfg.params.box if boundary == "periodic" else None
    model = Vicsek(cfg.params, cfg.seed, engine)
    state = model.state()
    for t in range(15):
        x, d = ref3.vicsek3d_step(state["x"], state["d"], t, cfg.params, cfg.seed)
        model.set_state(state, t)
        model.advance(1)
        got = model.state()
        assert gap(got["d"], d) < TOL, f"d differs at step {t}"
        assert gap(got["x"], x, box) < TOL, f"x differs at step {t}"
        state = {"x": x, "d": d}


@pytest.mark.skipif(not F64, reason="long free-running horizons are compared at f64 only (f32 drifts chaotically)")
@pytest.mark.parametrize("extra", [{}, {"neighbours": "topological", "noise_type": "vectorial"}])
def test_trajectory_matches_reference(engine, extra):
    cfg = config(**extra)
    model = Vicsek(cfg.params, cfg.seed, engine)
    x, d = model.state()["x"], model.state()["d"]
    model.advance(60)
    for t in range(60):
        x, d = ref3.vicsek3d_step(x, d, t, cfg.params, cfg.seed)
    assert gap(model.state()["d"], d) < 1e-8
    assert gap(model.state()["x"], x, cfg.params.box) < 1e-8


@pytest.mark.parametrize("boundary", ["periodic", "open"])
def test_metrics_match_reference(engine, boundary):
    cfg = config(boundary, n=400)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.advance(9)
    previous = model.state()["d"]
    model.advance(1)
    state = model.state()
    got = model.metrics()
    expected = ref3.vicsek3d_metrics(state["x"], state["d"], previous, cfg.params)
    assert got.keys() == expected.keys()
    assert got["clusters"] == expected["clusters"] and got["max_neighbors"] == expected["max_neighbors"]
    for name in ("largest_cluster", "mean_neighbors", "polarization", "de_theta"):
        assert got[name] == pytest.approx(expected[name], rel=1e-5, abs=1e-6), name
    for name in got:
        if name.startswith(("gnf_", "band_")):  # integer box and slab counts
            assert got[name] == pytest.approx(expected[name], rel=1e-12), name


def lone_agents(engine, n=4000, **extra):
    """n agents too far apart to see each other (R tiny, v0 = 0): one step shows the noise alone."""
    cfg = config(n=n, box=100.0, radius=1e-6, speed=0.0, **extra)
    model = Vicsek(cfg.params, cfg.seed, engine)
    before = model.state()["d"].astype(np.float64)
    model.advance(1)
    return cfg, before, model.state()["d"].astype(np.float64)


def test_angular_noise_fills_the_cap_of_half_angle_eta_over_2(engine):
    eta = 2.0
    _, before, after = lone_agents(engine, noise=eta)
    cos_turn = (before * after).sum(axis=1)
    assert cos_turn.min() >= math.cos(eta / 2) - 1e-5  # never beyond the cap
    # cos of the polar angle is uniform in [cos(eta/2), 1]: mean and spread of a uniform law (4000 draws)
    lo = math.cos(eta / 2)
    assert cos_turn.mean() == pytest.approx((1 + lo) / 2, abs=0.01)
    assert cos_turn.std() == pytest.approx((1 - lo) / math.sqrt(12), abs=0.01)


def test_full_noise_randomises_the_headings(engine):
    """eta = 2 pi: every new direction is uniform on the sphere, so |mean d| is about 1 / sqrt(N)."""
    _, _, after = lone_agents(engine, noise=2 * math.pi)
    assert np.linalg.norm(after.mean(axis=0)) < 3 / math.sqrt(len(after))


def test_vectorial_noise_by_hand(engine):
    eta = 0.7
    cfg, before, after = lone_agents(engine, n=5, noise=eta, noise_type="vectorial")
    ids = np.arange(5)
    z = 1 - 2 * uniform_np(cfg.seed, 0, ids, Stream.NOISE)
    azimuth = 2 * math.pi * uniform_np(cfg.seed, 0, ids, Stream.NOISE_2)
    xi = np.stack([np.sqrt(1 - z * z) * np.cos(azimuth), np.sqrt(1 - z * z) * np.sin(azimuth), z], axis=1)
    m = before + eta * xi  # n_i = 0 neighbours: weight eta (1 + 0)
    assert gap(after, m / np.linalg.norm(m, axis=1)[:, None]) < 10 * TOL


def test_turn_limit_stops_at_alpha(engine):
    """Without noise a dense swarm's agents turn toward their neighbours' mean by at most alpha per step."""
    cfg = config(n=500, box=3.0, noise=0.0, max_turn_deg=5.0)
    model = Vicsek(cfg.params, cfg.seed, engine)
    model.advance(1)
    assert model.metrics()["de_theta"] <= math.radians(5.0) + 1e-6
    turned = model.turn.to_numpy()
    assert turned.max() == pytest.approx(math.radians(5.0), abs=1e-5)


def test_noise_free_swarm_orders(engine):
    """eta = 0 in a dense periodic box: the vector rule aligns the swarm (Vicsek's low-noise phase)."""
    cfg = config(n=500, box=4.0, noise=0.0)
    model = Vicsek(cfg.params, cfg.seed, engine)
    assert model.metrics()["polarization"] < 0.2
    model.advance(150)
    assert model.metrics()["polarization"] > 0.99
