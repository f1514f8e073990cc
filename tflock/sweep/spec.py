"""Sweep files: the pydantic schema, expansion into points, and up-front validation of every point's config.

A sweep file (TOML) names a model or a base config, fixed overrides, a grid and/or a list of points, and how many
replicas each point gets::

    name = "vicsek-noise"            # optional; default: the file's stem
    model = "vicsek"                 # and/or base = "../vicsek.toml" (relative to the sweep file)
    replicas = 5                     # realisations per point, >= 1
    seed = 0                         # replica r of every point runs with seed + r
    [set]                            # fixed for every point (dotted keys, as --set)
    steps = 300
    "params.n" = 400
    [grid]                           # cartesian product over these keys
    "params.noise" = [0.5, 2.0, 4.0]
    [[points]]                       # explicit points, after the grid's
    "params.noise" = 6.0

:func:`load_sweep` reads and checks it and resolves every point's config through :func:`tflock.config.load_config`
before anything runs; every mistake is a :class:`~tflock.config.ConfigError` with one line naming the key (and
the point). Taichi-free.
"""

import hashlib
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, StrictStr, ValidationError, field_validator

from tflock.config import (
    Config,
    ConfigError,
    Int,
    config_to_dict,
    config_to_toml,
    load_config,
    parse_override,
    tomllib,
    with_range,
)

__all__ = ["Point", "Sweep", "SweepSpec", "load_sweep", "value_text"]

ROW_FORMAT = 2
"""Version of the per-point rows; part of every point's hash, so a change of the row layout recomputes points
(2: the min_ and max_ columns over the whole run)."""

SEED_MAX = 2**32 - 1
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9._-]*$"
FIXED_BY_SWEEP = ("model", "seed")  # the sweep's own keys; a point may not change them
ENGINE_PREFIX = "engine."  # one Taichi per process: the engine is the same for every point


def _dotted(table: Mapping[str, Any]) -> dict[str, Any]:
    """``{"params": {"n": 3}}`` and ``{"params.n": 3}`` both as ``{"params.n": 3}`` (TOML's unquoted dotted keys
    are nested tables)."""
    flat: dict[str, Any] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, Mapping) and (value or not prefix):
            for key, item in value.items():
                walk(f"{prefix}.{key}" if prefix else str(key), item)
        else:
            flat[prefix] = value

    walk("", table)
    return flat


class SweepSpec(BaseModel):
    """The sweep file as written (keys of ``set``, ``grid`` and ``points`` flattened to dotted keys)."""

    model_config = ConfigDict(extra="forbid", populate_by_name=True)

    name: StrictStr | None = Field(None, pattern=NAME_PATTERN, description="sweep name; default: the file's stem")
    model: StrictStr | None = Field(None, description="model of every point")
    base: StrictStr | None = Field(None, description="base config file, relative to the sweep file")
    replicas: Int = Field(1, ge=1, description="realisations per point, >= 1")
    seed: Int | None = Field(None, ge=0, le=SEED_MAX, description="replica r runs with seed + r; default: base's")
    fixed: dict[str, Any] = Field(default_factory=dict, alias="set", description="fixed overrides (dotted keys)")
    grid: dict[str, list[Any]] = Field(default_factory=dict, description="cartesian product over these keys")
    points: list[dict[str, Any]] = Field(default_factory=list, description="explicit points (tables of keys)")

    @field_validator("fixed", mode="before")
    @classmethod
    def _flat_set(cls, value: Any) -> Any:
        return _dotted(value) if isinstance(value, Mapping) else value

    @field_validator("grid", mode="before")
    @classmethod
    def _flat_grid(cls, value: Any) -> Any:
        return _dotted(value) if isinstance(value, Mapping) else value

    @field_validator("points", mode="before")
    @classmethod
    def _flat_points(cls, value: Any) -> Any:
        if isinstance(value, list):
            return [_dotted(p) if isinstance(p, Mapping) else p for p in value]
        return value


@dataclass(frozen=True)
class Point:
    """One point of a sweep: its index, the swept values as written, its resolved config (seed = the sweep's
    seed) and ``key``, a short hash of all of that and the replica count (the name of its result file)."""

    index: int
    values: dict[str, Any]
    config: Config
    key: str

    @property
    def label(self) -> str:
        """``point 3 (params.noise = 0.5)``, for messages."""
        return _label(self.index, self.values)


@dataclass(frozen=True)
class Sweep:
    """A validated sweep: every point resolved, ready to run with :func:`tflock.sweep.run_sweep`."""

    name: str
    model: str
    replicas: int
    seed: int
    keys: list[str]  # the swept keys, in order: the grid's, then those of the explicit points
    points: list[Point]


def load_sweep(
    source: str | Path | Mapping[str, Any],
    *,
    replicas: int | None = None,
    overrides: Sequence[str] | Mapping[str, Any] | None = None,
) -> Sweep:
    """Read, check and expand a sweep file (or a dict shaped like one) into its points.

    ``replicas`` replaces the file's count; ``overrides`` (``"key=value"`` strings, as ``--set``, or a mapping of
    dotted keys) are added to its ``[set]`` table and may not name a swept key. Every point's config is resolved and
    validated here. A dict source resolves ``base`` against the working directory. Raises
    :class:`~tflock.config.ConfigError` with one line naming the key and, for a bad value, the point.
    """
    if isinstance(source, Mapping):
        raw, where, stem = dict(source), Path.cwd(), "sweep"
    else:
        path = Path(source)
        raw, where, stem = _read_sweep_file(path), path.parent, path.stem
    try:
        spec = SweepSpec.model_validate(raw)
    except ValidationError as error:
        raise ConfigError(_spec_error_text(error)) from None
    if replicas is not None:
        if replicas < 1:
            raise ConfigError(f"--replicas: must be >= 1, got {replicas}")
        spec = spec.model_copy(update={"replicas": replicas})
    extra = dict(overrides.items() if isinstance(overrides, Mapping) else map(parse_override, overrides or ()))
    return _expand(spec, extra, where, spec.name or stem)


def _read_sweep_file(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as file:
            return tomllib.load(file)
    except FileNotFoundError:
        raise ConfigError(f"sweep file not found: {path}") from None
    except IsADirectoryError:
        raise ConfigError(f"sweep file is a directory: {path}") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot read: {error.strerror or error}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(" ".join(f"{path}: invalid TOML: {error}".split())) from None


def _expand(spec: SweepSpec, extra: dict[str, Any], where: Path, name: str) -> Sweep:
    """Check the keys, build the list of points (grid product, then explicit points) and resolve their configs;
    ``extra`` holds the ``--set`` overrides, added to the file's ``[set]``."""
    if spec.model is None and spec.base is None:
        raise ConfigError('model: required key is missing; give model = "<name>" and/or base = "<config.toml>"')
    for key, values in spec.grid.items():
        if not values:
            raise ConfigError(f"grid.{key}: expected a non-empty list of values, got []")
    swept = list(spec.grid)
    for point in spec.points:
        swept += [key for key in point if key not in swept]
    for key in swept:
        section = "grid" if key in spec.grid else "points"
        if key in FIXED_BY_SWEEP:
            raise ConfigError(f"{section}.{key}: cannot vary within a sweep; set the sweep's own {key!r}")
        if key.startswith(ENGINE_PREFIX):
            raise ConfigError(f"{section}.{key}: cannot vary within a sweep (one Taichi engine per process)")
    for section, table in (("set.", spec.fixed), ("--set ", extra)):
        for key in table:
            if key in FIXED_BY_SWEEP:
                raise ConfigError(f"{section}{key}: {key} is a key of the sweep itself (top level of the file), "
                                  "not of its points")
            if key in swept:
                raise ConfigError(f"{section}{key}: this key is swept by the grid or points; fix it or sweep it")
    base = _base_config(spec, where)
    fixed = {**spec.fixed, **extra}
    if spec.seed is not None:
        fixed["seed"] = spec.seed

    grid_points = [dict(zip(spec.grid, combo, strict=True)) for combo in itertools.product(*spec.grid.values())]
    given = ([grid_points] if spec.grid else []) + ([spec.points] if spec.points else [])
    written = [values for group in given for values in group] or [{}]  # no grid, no points: one point (an ensemble)
    points = []
    for index, values in enumerate(written):
        try:
            config = load_config(base, overrides={**fixed, **values})
        except ConfigError as error:
            raise ConfigError(f"{_label(index, values)}: {error}") from None
        columns = {key: values[key] if key in values else _resolved(config, key) for key in swept}
        points.append(Point(index, columns, config, _point_key(config, columns, spec.replicas)))
    seed = points[0].config.seed
    if seed + spec.replicas - 1 > SEED_MAX:
        raise ConfigError(f"replicas: seed + replicas - 1 must be <= {SEED_MAX}, got {seed + spec.replicas - 1}")
    return Sweep(name=name, model=points[0].config.model, replicas=spec.replicas, seed=seed, keys=swept,
                 points=points)


def _base_config(spec: SweepSpec, where: Path) -> dict[str, Any]:
    """The resolved base config as a dict: the ``base`` file's (checked against ``model``) or the model's
    defaults."""
    path = None if spec.base is None else where / spec.base  # an absolute base stays absolute
    try:
        return tomllib.loads(config_to_toml(load_config(path, model=spec.model)))
    except ConfigError as error:
        raise ConfigError(f"base: {error}" if path is not None else str(error)) from None


def _label(index: int, values: Mapping[str, Any]) -> str:
    text = ", ".join(f"{k} = {value_text(v)}" for k, v in values.items())
    return f"point {index}" + (f" ({text})" if text else "")


def _resolved(config: Config, key: str) -> Any:
    """The value of dotted ``key`` in the resolved config (None where unset)."""
    value: Any = config_to_dict(config)
    for part in key.split("."):
        value = value.get(part) if isinstance(value, Mapping) else None
    return value


def _point_key(config: Config, values: Mapping[str, Any], replicas: int) -> str:
    """Ten hex digits naming a point's result: its config, swept values, replica count and the row format."""
    blob = json.dumps({"config": config_to_toml(config), "values": {k: value_text(v) for k, v in values.items()},
                       "replicas": replicas, "format": ROW_FORMAT}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:10]


def value_text(value: Any) -> str:
    """A swept value as in the sweep file: ``0.5``, ``inf``, ``"open"``, ``true``, ``[1, 2]``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (list, tuple, str, dict)):
        return json.dumps(value)
    return repr(value)


_CONFIG_KEYS = frozenset(f.alias or n for n, f in Config.model_fields.items())
_SPEC_KEYS = frozenset(f.alias or n for n, f in SweepSpec.model_fields.items())
#: a run config's top-level keys that a sweep file does not have (one given to `tflock sweep` is named as such)
_RUN_KEYS = _CONFIG_KEYS - _SPEC_KEYS
#: the keys of a sweep file that a run config lacks (a sweep file given to `tflock sim --config` says so)
SWEEP_KEYS = _SPEC_KEYS - _CONFIG_KEYS


def _spec_error_text(error: ValidationError) -> str:
    """The first error of a sweep file as one line, ``<key>: <what is allowed>, got <value>``."""
    first = error.errors()[0]
    key = ".".join(str(part) for part in first["loc"]) or "sweep"
    kind, ctx, got = first["type"], first.get("ctx") or {}, first.get("input")
    if kind == "extra_forbidden":
        allowed = ", ".join(field.alias or name for name, field in SweepSpec.model_fields.items())
        text = f"{key}: unknown key; allowed: {allowed}"
        if key in _RUN_KEYS:  # a run config's keys: not a sweep file
            text += " (this looks like a run config, which `tflock sim --config` runs; a sweep file names its base "\
                    "config and the values to sweep)"
    elif kind == "missing":
        text = f"{key}: required key is missing"
    elif kind in ("greater_than_equal", "less_than_equal"):
        text = f"{key}: must be between 0 and {SEED_MAX}, got {value_text(got)}" if key == "seed" else (
            f"{key}: must be >= {ctx.get('ge')}, got {value_text(got)}")
    elif kind == "string_pattern_mismatch":
        text = f"{key}: must be letters, digits, '.', '_' or '-' (a folder name), got {value_text(got)}"
    elif kind == "list_type":
        text = f"{key}: expected a list of values, got {value_text(got)}"
    elif kind in ("dict_type", "model_type"):
        text = f"{key}: expected a table, got {value_text(got)}"
    else:
        expected = first["msg"][:1].lower() + first["msg"][1:]
        field = SweepSpec.model_fields.get(str(first["loc"][0])) if len(first["loc"]) == 1 else None
        if kind == "config_type" and field is not None:  # as a config's: "expected an integer >= 1"
            expected = with_range(expected, field)
        text = f"{key}: {expected}, got {value_text(got)}"
    more = len(error.errors()) - 1
    return " ".join(text.split()) + (f" (and {more} more)" if more else "")
