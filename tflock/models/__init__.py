"""The models. Each has a Taichi-free ``<name>_params.py`` that registers it with :mod:`tflock.config`, and a
module with its kernels, imported only when the model is built (the CLI validates configs without Taichi)."""

from importlib import import_module


def model_class(name: str) -> type:
    """The model class registered under `name`."""
    from tflock.config import MODEL_IMPLEMENTATIONS

    module, cls = MODEL_IMPLEMENTATIONS[name].split(":")
    return getattr(import_module(module), cls)
