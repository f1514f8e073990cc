"""The interface every model implements, and helpers shared by the models' drawing code."""


from abc import ABC, abstractmethod
from collections.abc import Mapping

import numpy as np

from tflock.engine import EngineInfo
from tflock.record import Frame, WorldSpec


class Model(ABC):
    """A model owns its state arrays and kernels; it knows nothing of files, CLI or Rerun.

    The simulation loop calls :meth:`advance`, :meth:`metrics` and :meth:`frame`; tests and notebooks use
    :meth:`state` / :meth:`set_state` to compare kernels with the NumPy reference from the same state.
    """

    name: str
    dt: float = 1.0
    #: metric name -> one-line description, in the order the metrics table uses
    metric_descriptions: Mapping[str, str]

    def __init__(self, params, seed: int, engine: EngineInfo) -> None:
        self.params = params
        self.seed = seed
        self.engine = engine
        self.step_index = 0

    @abstractmethod
    def advance(self, steps: int) -> None:
        """Run `steps` steps."""

    @abstractmethod
    def state(self) -> dict[str, np.ndarray]:
        """A NumPy snapshot of the state (copies)."""

    @abstractmethod
    def set_state(self, state: Mapping[str, np.ndarray], step: int) -> None:
        """Replace the state (arrays shaped as :meth:`state` returns them) and the step counter."""

    @abstractmethod
    def metrics(self) -> dict[str, float]:
        """Metrics of the current state over all agents."""

    @abstractmethod
    def frame(self, selected: np.ndarray, max_edges: int) -> Frame:
        """What to draw now: the `selected` agents (sorted ids) and up to `max_edges` neighbour edges."""

    @abstractmethod
    def world(self) -> WorldSpec:
        """Geometry of the world for the recorder."""
