"""Ensembles and parameter sweeps: a grid (and lists) of config points x replicas, as one tidy table.

    from tflock.sweep import run_sweep
    table = run_sweep("configs/sweeps/vicsek-noise.toml")               # pandas.DataFrame, also on disk
    table.groupby("params.noise")["mean_polarization"].agg(["mean", "std"])

Modules: :mod:`~tflock.sweep.spec` (the sweep file and its points), :mod:`~tflock.sweep.point` (:func:`run_point`,
the replicas of one point as rows), :mod:`~tflock.sweep.execute` (in-process or Dask), :mod:`~tflock.sweep.table`
(point files and the table) and :mod:`~tflock.sweep.run` (:func:`run_sweep`, resumable).
"""

from tflock.sweep.execute import SweepError
from tflock.sweep.point import run_point
from tflock.sweep.run import default_out, run_sweep
from tflock.sweep.spec import Point, Sweep, load_sweep

__all__ = ["Point", "Sweep", "SweepError", "default_out", "load_sweep", "run_point", "run_sweep"]
