"""What a reproduction is: the runs it needs (sweeps and single time series) and the report it makes of them."""

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

#: a single run's metrics table: columns ``step``, ``time`` and one per metric (Simulation.metrics())
Series = dict[str, np.ndarray]


@dataclass
class Results:
    """What the runs of an experiment gave: each sweep's table (one row per point and replica, see
    :func:`tflock.sweep.run_sweep`) and each single run's metrics table, by the names the experiment chose."""

    sweeps: dict[str, pd.DataFrame] = field(default_factory=dict)
    series: dict[str, Series] = field(default_factory=dict)


@dataclass
class Report:
    """An experiment's outcome: matplotlib figures (file stem -> Figure), the table of the numbers they plot,
    and a short markdown comparison of those numbers with what the paper reports."""

    figures: dict[str, Any]
    table: pd.DataFrame
    comparison: str


class Experiment(ABC):
    """One published experiment (or a group of figures from one paper), at a quick size for CI and at the
    paper's size by default.

    Subclasses name themselves and their source, and return plain sweep specs (dicts shaped like a sweep file;
    see :mod:`tflock.sweep.spec`) and single-run configs (dicts shaped like a config file); the runner runs them
    (resumably, on Dask when asked) and hands the results to :meth:`report`.
    """

    name: str
    title: str
    #: the paper, by file name in papers/, and the figures reproduced
    source: str
    #: the report's words for the full size (not --quick): where the paper has no simulations of its own, or its
    #: sizes are not in papers/, an experiment says whose sizes it runs
    full_size: str = "the paper's size"

    def sweeps(self, quick: bool) -> dict[str, dict[str, Any]]:
        """Sweep specs by name (``name``, ``replicas``, ``seed``, ``set``, ``grid``, ``points``, ``model``)."""
        return {}

    def series(self, quick: bool) -> dict[str, dict[str, Any]]:
        """Single runs whose whole metrics tables the report needs, as config dicts by name."""
        return {}

    @abstractmethod
    def report(self, results: Results, quick: bool) -> Report:
        """Figures, table and comparison from the results."""
