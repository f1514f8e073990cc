"""A sweep's results on disk: one Parquet file per finished point, and the tidy table of all of them.

``<out>/points/<index>-<key>.parquet`` holds a point's rows; ``key`` hashes the point's config, swept values and
replica count, so a changed sweep never picks up a stale file. Files are written to a temporary name and renamed,
so an interrupted sweep leaves only complete files. ``<out>/table.parquet`` and ``<out>/table.csv`` are the table:
one row per point and replica.
"""

import os
from collections.abc import Iterable, Sequence
from numbers import Real
from pathlib import Path
from typing import Any

import pandas as pd

from tflock.sweep.spec import Point, value_text

__all__ = ["assemble", "point_frame", "point_path", "read_point", "write_point", "write_table"]

LEADING = ("point", "replica", "seed")
TRAILING = ("wall_s", "config")


def point_path(points_dir: Path, point: Point) -> Path:
    """Where a point's rows are stored."""
    return points_dir / f"{point.index:05d}-{point.key}.parquet"


def point_frame(point: Point, rows: Sequence[dict[str, Any]]) -> pd.DataFrame:
    """A point's rows with its index and swept values as columns (a list or table value as its TOML-like text)."""
    columns = {"point": point.index}
    columns.update({key: value if _scalar(value) else value_text(value) for key, value in point.values.items()})
    return pd.DataFrame([{**columns, **row} for row in rows])


def write_point(path: Path, frame: pd.DataFrame) -> None:
    """Write a point's rows atomically."""
    atomic_write(path, lambda tmp: frame.to_parquet(tmp, index=False))


def read_point(path: Path) -> pd.DataFrame:
    """A point's rows as written by :func:`write_point`."""
    return pd.read_parquet(path)


def assemble(frames: Iterable[pd.DataFrame], keys: Sequence[str]) -> pd.DataFrame:
    """The tidy table: rows sorted by point and replica; columns ``point``, ``replica``, ``seed``, the swept
    ``keys``, ``steps``, the metric columns, ``wall_s`` and ``config``. A swept column whose values mix kinds
    (``1.0`` and ``"inf"``) holds them as text, so the table stays writable as Parquet."""
    table = pd.concat(list(frames), ignore_index=True)
    for key in keys:
        table[key] = _one_kind(table[key])
    middle = [c for c in table.columns if c not in (*LEADING, *keys, *TRAILING, "steps")]
    table = table[[*LEADING, *keys, "steps", *middle, *TRAILING]]
    return table.sort_values(["point", "replica"], kind="stable", ignore_index=True)


def write_table(table: pd.DataFrame, out: Path) -> list[Path]:
    """Write ``table.parquet`` and ``table.csv`` into ``out`` (each atomically); the paths written."""
    paths = [out / "table.parquet", out / "table.csv"]
    atomic_write(paths[0], lambda tmp: table.to_parquet(tmp, index=False))
    atomic_write(paths[1], lambda tmp: table.to_csv(tmp, index=False))
    return paths


def atomic_write(path: Path, write: Any) -> None:
    """``write(tmp)`` to a temporary file beside `path`, then rename it to `path`: never a half-written file."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, (bool, int, float, str))


def _one_kind(column: pd.Series) -> pd.Series:
    """``column`` unchanged when its values are of one kind (numbers, text or booleans), else as text."""
    if column.dtype != object:
        return column
    given = column.dropna()
    if all(isinstance(v, Real) and not isinstance(v, bool) for v in given):
        return column.astype(float)
    if all(isinstance(v, str) for v in given) or all(isinstance(v, bool) for v in given):
        return column
    return column.map(lambda v: v if v is None or isinstance(v, str) else value_text(v))
