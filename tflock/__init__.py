"""tflock: large-N collective-motion (flocking) simulation on Taichi, recorded to Rerun.

    import tflock
    sim = tflock.Simulation(model="vicsek", params={"n": 2000, "box": 31.6, "noise": 0.3}, steps=100)
    sim.step(100)
    table = sim.metrics()

Names are imported lazily, so ``tflock.config`` (and the CLI's error path) loads without Taichi.
"""

import os
from importlib import import_module
from typing import Any

os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")  # must precede the first `import taichi`

__version__ = "0.1.0"
__all__ = ["MODELS", "Config", "ConfigError", "EngineError", "NumericalFaultError", "Simulation", "load_config"]

_LAZY = {
    "Simulation": ("tflock.simulation", "Simulation"),
    "Config": ("tflock.config", "Config"),
    "ConfigError": ("tflock.config", "ConfigError"),
    "load_config": ("tflock.config", "load_config"),
    "MODELS": ("tflock.config", "MODEL_DESCRIPTIONS"),
    "EngineError": ("tflock.engine", "EngineError"),
    "NumericalFaultError": ("tflock.simulation", "NumericalFaultError"),
}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        module, attr = _LAZY[name]
        return getattr(import_module(module), attr)
    raise AttributeError(f"module 'tflock' has no attribute {name!r}")


def __dir__() -> list[str]:
    """The public names too (imported lazily, so not yet in the module's namespace): tab completion offers them."""
    return sorted({*globals(), *__all__})
