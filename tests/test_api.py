"""The Python API as docs/api.md shows it, with assertions on what it returns (tests/test_docs.py runs the page's
blocks as they are)."""

import numpy as np
import pytest


def test_readme_example(cpu_engine, tmp_path):
    import tflock

    sim = tflock.Simulation(model="vicsek", params={"n": 2000, "box": 31.6, "noise": 0.3}, steps=50,
                            engine={"precision": cpu_engine.precision}, record=tmp_path / "run.rrd")
    sim.step(10)                        # advance 10 steps
    state = sim.state()                 # {"x": (n, 2), "theta": (n,), "step": 10}
    sim.run()                           # up to the configured 50 steps
    sim.close()                         # finish the recording
    table = sim.metrics()               # columns: step, time, polarization, ..., largest_cluster

    assert state["x"].shape == (2000, 2) and state["step"] == 10
    assert list(table["step"]) == list(range(51))
    assert 0 <= table["polarization"][-1] <= 1
    assert (tmp_path / "run.rrd").stat().st_size > 0
    assert (tmp_path / "run.metrics.csv").read_text().count("\n") == 52


def test_config_sources_and_overrides(cpu_engine, tmp_path):
    from tflock import Simulation, load_config
    from tflock.config import ConfigError

    path = tmp_path / "run.toml"
    path.write_text(f'model = "vicsek"\nsteps = 5\n[engine]\nprecision = "{cpu_engine.precision}"\n'
                    '[params]\nn = 300\nbox = 10.0\n')
    a = Simulation(path, overrides=["params.noise=0.1"])
    b = Simulation(load_config(path, overrides={"params.noise": 0.1}))
    assert a.config == b.config and a.config.params.n == 300
    a.run()
    b.run()
    assert np.array_equal(a.state()["theta"], b.state()["theta"])
    with pytest.raises(ConfigError, match="params.n"):
        Simulation(path, params={"n": 0})


def test_the_package_names_its_errors_and_lists_its_names():
    """What api.md names is importable from the package, and dir() (tab completion) lists it though it loads
    lazily."""
    import tflock
    from tflock.engine import EngineError
    from tflock.simulation import NumericalFaultError

    assert tflock.EngineError is EngineError and issubclass(EngineError, RuntimeError)
    assert tflock.NumericalFaultError is NumericalFaultError
    assert set(tflock.__all__) <= set(dir(tflock))
    assert {"Simulation", "ConfigError", "EngineError", "load_config"} <= set(dir(tflock))
