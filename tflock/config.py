"""Run configuration: pydantic schemas, TOML loading, ``key=value`` overrides and one-line errors.

A run config is a TOML file (or a nested dict of the same shape)::

    model = "vicsek"
    seed = 0
    steps = 200
    [engine]        # EngineConfig
    [params]        # the model's own schema, PARAMS_SCHEMAS[model]
    [params.leader]
    [log]           # LogConfig

``load_config`` reads it, applies overrides (the CLI's repeatable ``--set key=value``) and validates it; every
mistake becomes a :class:`ConfigError` with one line naming the key, what is allowed and what was given.
A new model adds its params schema and description with :func:`register_model` (from its own params module,
imported at the end of this one), nothing else.
"""

from __future__ import annotations

import copy
import math
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Annotated, Any, Literal, get_args, get_origin

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    SerializeAsAny,
    StrictBool,
    StrictStr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.fields import FieldInfo
from pydantic_core import ErrorDetails, PydanticCustomError

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

__all__ = [
    "MODEL_DESCRIPTIONS",
    "PARAMS_SCHEMAS",
    "Config",
    "ConfigError",
    "EngineConfig",
    "LeaderConfig",
    "LogConfig",
    "VicsekParams",
    "config_to_dict",
    "config_to_toml",
    "default_config_toml",
    "load_config",
    "parse_override",
]

DEFAULT_MODEL = "vicsek"
#: the most steps a run can take: the kernels' step counter (and the random keys) are 32-bit integers
MAX_STEPS = 2**31 - 1
TWO_PI = 2.0 * math.pi
_FLOAT_MAX = sys.float_info.max


class ConfigError(ValueError):
    """A bad config, override or config file; the message is one line, e.g.
    ``params.noise: must be between 0 and 6.283 (2 pi), got -1``."""


# ----------------------------------------------------------------------------------------------------------
# Value types: numbers from TOML, without pydantic's string-to-number coercion.


def _integer(value: Any) -> Any:
    """Accept an int, or an integral float such as ``1e5`` (TOML's way to write 100000); reject the rest."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise PydanticCustomError("config_type", "expected an integer")
    return value


def _number(value: Any) -> Any:
    """Accept a finite int or float (pydantic makes it a float); reject strings, booleans, inf and nan."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise PydanticCustomError("config_type", "expected a number")
    if not (-_FLOAT_MAX <= value <= _FLOAT_MAX):  # False for nan too
        raise PydanticCustomError("config_type", "expected a finite number")
    return value


def _optional_number(value: Any) -> Any:
    """Like :func:`_number`, but ``None`` (unset) passes through."""
    return None if value is None else _number(value)


Int = Annotated[int, BeforeValidator(_integer)]
Float = Annotated[float, BeforeValidator(_number)]
OptionalFloat = Annotated[float | None, BeforeValidator(_optional_number)]


def _rule_error(allowed: str, got: Any, key: str | None = None) -> PydanticCustomError:
    """An error for a rule pydantic's field constraints can't say: ``allowed`` is the text after ``<key>: ``.

    ``key`` names the field, relative to where the validator runs, when that is not the error's location (a
    model validator reports at the model)."""
    context = {"got": got} if key is None else {"got": got, "key": key}
    return PydanticCustomError("config_rule", allowed, context)


# ----------------------------------------------------------------------------------------------------------
# Schemas.


class EngineConfig(BaseModel):
    """Where and how the Taichi kernels run."""

    model_config = ConfigDict(extra="forbid")

    arch: Literal["cpu", "cuda", "vulkan", "auto"] = Field(
        "cpu", description="Taichi backend: cpu, cuda, vulkan or auto (the best available)"
    )
    threads: Int = Field(0, ge=0, description="CPU threads for the cpu backend, >= 0; 0 = all cores")
    precision: Literal["f32", "f64"] = Field(
        "f32", description="floating-point precision of the fields: f32 or f64"
    )

    @model_validator(mode="after")
    def _precision_on_arch(self) -> EngineConfig:
        if self.arch == "vulkan" and self.precision == "f64":
            raise _rule_error("must be f32 on vulkan (its shaders have no 64-bit sin, cos, atan2 or pow); "
                              "f64 runs on cpu or cuda", self.precision, key="precision")
        return self


class LogConfig(BaseModel):
    """What goes into the Rerun recording, and how often."""

    model_config = ConfigDict(extra="forbid")

    out: StrictStr = Field(
        "", description='Rerun recording file (.rrd); "" = recordings/<model>-<YYYYmmdd-HHMMSS>.rrd'
    )
    every: Int = Field(1, ge=1, description="log a frame every k steps, k >= 1")
    max_agents: Int = Field(
        2000,
        ge=0,
        description="agents drawn per frame, >= 0: the same seeded subset every frame; "
        "metrics always use all agents",
    )
    max_edges: Int = Field(4000, ge=0, description="neighbour edges drawn per frame (among the drawn agents), >= 0")
    field: Int = Field(-1, ge=-1, le=1024, description="pixels a side of the field of all agents drawn with each "
                       "frame when not all agents are drawn, in [-1, 1024]; -1 = by N (64 to 256), 0 = none")
    trail: Int = Field(0, ge=0, le=1000, description="positions of each drawn agent's trail, in [0, 1000]; "
                       "0 = no trails")
    metrics_every: Int = Field(1, ge=1, description="compute and log the metrics every k steps, k >= 1")

    @field_validator("out")
    @classmethod
    def _rrd_file(cls, value: str) -> str:
        if value and not value.endswith(".rrd"):
            raise _rule_error('must be "" or a path ending in .rrd', value)
        return value


class LeaderConfig(BaseModel):
    """An optional leader (Jadbabaie section 3): agent 0 keeps a fixed heading and is never updated."""

    model_config = ConfigDict(extra="forbid")

    enabled: StrictBool = Field(False, description="true = agent 0 is a leader with a fixed heading")
    heading_deg: Float = Field(0.0, description="fixed heading theta0 of agent 0, degrees (Jadbabaie eq. 22)")


class VicsekParams(BaseModel):
    """Parameters of the Vicsek family (DESIGN.md section 3.1)."""

    model_config = ConfigDict(extra="forbid")

    n: Int = Field(100_000, gt=0, description="number of agents N, > 0")
    box: Float = Field(
        223.6,
        gt=0,
        description="side L of the periodic or reflecting box, > 0; "
        "in open space the side of the initial square",
    )
    radius: Float = Field(1.0, gt=0, description="interaction radius R, > 0")
    speed: Float = Field(0.5, ge=0, description="speed v0, distance per step, >= 0")
    noise: Float = Field(
        0.5,
        ge=0,
        le=TWO_PI,
        description="noise eta in [0, 2 pi]: angular noise adds uniform noise in [-eta/2, eta/2] radians each step "
        "(3D: a direction uniform in the cap of half-angle eta/2); vectorial noise uses eta as its weight",
    )
    boundary: Literal["periodic", "reflecting", "open"] = Field(
        "periodic", description="boundary: periodic, reflecting (mirror walls) or open (unbounded)"
    )
    rule: Literal["vector", "average", "relative", "laplacian"] = Field(
        "vector",
        description="heading rule: vector (Vicsek 1995), average (Jadbabaie eq. 2), "
        "relative (wrapped differences) or laplacian (Jadbabaie eqs. 17-20)",
    )
    g: OptionalFloat = Field(
        None,
        gt=0,
        description="gain g of rule laplacian, must be > n (Jadbabaie eq. 18); unused by the other rules",
    )
    max_turn_deg: Float = Field(
        360.0,
        gt=0,
        le=360,
        description="turn limit alpha per step, degrees, in (0, 360] (Samiloglu eq. 7); 360 = no limit",
    )
    async_bound: Int = Field(
        1,
        ge=1,
        le=1000,
        description="asynchrony bound B in [1, 1000] (Samiloglu Assumption 1): each agent updates at least once "
        "in any B steps and sees neighbours up to B - 1 steps late; 1 = synchronous updates",
    )
    leader: LeaderConfig = Field(default_factory=LeaderConfig, description="optional leader (agent 0)")
    noise_type: Literal["angular", "vectorial"] = Field(
        "angular",
        description="angular: the heading turns by uniform noise in [-eta/2, eta/2] (Vicsek 1995); vectorial: a "
        "random unit vector of weight eta times the neighbour count (itself included) joins the sum of headings "
        "before it is normalised (Gregoire-Chate), eta then a weight, not radians; vector rule only",
    )
    dim: Literal[2, 3] = Field(
        2, description="space dimension: 2, or 3 for the vector rule (headings are unit vectors on the sphere)"
    )
    neighbours: Literal["metric", "topological"] = Field(
        "metric",
        description="metric: the agents within radius R; topological: the k nearest agents (Ballerini et al. "
        "2008), ties broken by agent id; synchronous updates only",
    )
    k: Int = Field(6, ge=1, le=32, description="neighbours of each agent when topological, in [1, 32], < n")
    wrap_headings: bool = Field(
        True,
        description="wrap headings into [0, 2 pi) after every update and wall reflection (Samiloglu section 3); "
        "false keeps them as real numbers, which changes only the rules that use angle values (average, laplacian)",
    )

    @model_validator(mode="after")
    def _cross_field_rules(self) -> VicsekParams:
        if self.noise_type == "vectorial" and self.rule != "vector":
            raise _rule_error(f"must be 'angular' for rule '{self.rule}' (vectorial noise joins the sum of heading "
                              "vectors of rule 'vector')", self.noise_type, key="noise_type")
        if self.dim == 3:
            for key, value, allowed, text in (
                    ("rule", self.rule, "vector", "'vector' in 3D (the other rules are defined on angles only)"),
                    ("async_bound", self.async_bound, 1, "1 in 3D (asynchrony is 2D only)"),
                    ("leader", self.leader.enabled, False, "off in 3D (a leader's heading is an angle in the plane)")):
                if value != allowed:
                    raise _rule_error(f"must be {text}", value, key=f"{key}.enabled" if key == "leader" else key)
        if self.neighbours == "topological":
            if self.async_bound != 1:
                raise _rule_error("must be 1 with topological neighbours (delayed views are defined for metric ones)",
                                  self.async_bound, key="async_bound")
            if self.k >= self.n:
                raise _rule_error(f"must be < params.n (= {self.n}) for topological neighbours", self.k, key="k")
        if self.rule == "laplacian" and (self.g is None or self.g <= self.n):
            raise _rule_error(
                f"must be > params.n (= {self.n}) for rule 'laplacian' (Jadbabaie eq. 18)", self.g, key="g"
            )
        if self.boundary != "open" and self.speed >= self.box / 2:
            raise _rule_error(
                f"must be < params.box / 2 (= {_number_text(self.box / 2)}) for boundary '{self.boundary}'",
                self.speed,
                key="speed",
            )
        return self


PARAMS_SCHEMAS: dict[str, type[BaseModel]] = {"vicsek": VicsekParams}
"""The params schema of each model, by model name."""

MODEL_DESCRIPTIONS: dict[str, str] = {
    "vicsek": "Vicsek family: vector / average (Jadbabaie) / relative / laplacian rules, leader, turn limit",
}
"""One line per model, for ``tflock models``."""

MODEL_IMPLEMENTATIONS: dict[str, str] = {"vicsek": "tflock.models.vicsek:Vicsek"}
"""The class of each model, as ``"module:Class"`` (imported only when a model is built)."""


class Config(BaseModel):
    """A complete run config. ``params`` is an instance of ``PARAMS_SCHEMAS[model]`` (e.g. VicsekParams)."""

    model_config = ConfigDict(extra="forbid")

    model: StrictStr = Field(description="simulation model (see `tflock models`), e.g. vicsek")
    seed: Int = Field(
        0,
        ge=0,
        le=2**32 - 1,
        description="seed of all random draws (initial state, noise), in [0, 2**32 - 1]",
    )
    steps: Int = Field(200, ge=0, le=MAX_STEPS, description="number of steps to simulate, in [0, 2**31 - 1] "
                       "(the kernels count steps in 32-bit integers)")
    engine: EngineConfig = Field(default_factory=EngineConfig, description="where the kernels run")
    params: SerializeAsAny[BaseModel] = Field(
        default_factory=dict, validate_default=True, description="parameters of the model"
    )
    log: LogConfig = Field(default_factory=LogConfig, description="what is recorded to Rerun, and how often")

    @field_validator("model")
    @classmethod
    def _known_model(cls, value: str) -> str:
        if value not in PARAMS_SCHEMAS:
            raise _rule_error(f"must be one of {', '.join(PARAMS_SCHEMAS)}", value)
        return value

    @field_validator("params", mode="plain")
    @classmethod
    def _params_of_model(cls, value: Any, info: ValidationInfo) -> Any:
        schema = PARAMS_SCHEMAS.get(info.data.get("model", ""))
        if schema is None:  # the model is invalid and reported already; its params can't be checked
            return value
        if isinstance(value, schema):
            return value
        if isinstance(value, BaseModel):
            value = value.model_dump()
        return schema.model_validate(value)  # its errors come out located under "params"


# ----------------------------------------------------------------------------------------------------------
# Loading and overrides.


def load_config(
    source: str | Path | Mapping[str, Any] | None = None,
    *,
    model: str | None = None,
    overrides: Sequence[str] | Mapping[str, Any] | None = None,
) -> Config:
    """Load, override and validate a run config.

    ``source`` is a TOML file path, a nested dict shaped like the TOML, or None for the defaults. A
    source without ``model`` takes ``model`` (default ``"vicsek"``); a source naming another model than
    ``model`` is an error. ``overrides`` are ``"key=value"`` strings (values parsed as TOML, else a bare
    string) or a mapping of dotted keys to Python values; they are applied before validation, so they are
    checked like values from the file. Raises :class:`ConfigError`.
    """
    if source is None:
        raw: dict[str, Any] = {}
    elif isinstance(source, Mapping):
        raw = _plain_dict(source)
    else:
        raw = _read_toml(Path(source))

    items = overrides.items() if isinstance(overrides, Mapping) else map(parse_override, overrides or ())
    for key, value in items:
        _set_dotted(raw, key, value)

    named = raw.get("model")
    if model is not None and named is not None and named != model:
        raise ConfigError(f"model: the config says {_value_text(named)} but model {model!r} was requested")
    raw.setdefault("model", DEFAULT_MODEL if model is None else model)

    try:
        return Config.model_validate(raw)
    except ValidationError as error:
        raise ConfigError(_error_text(error, raw["model"])) from None


def parse_override(expr: str) -> tuple[str, Any]:
    """Split ``"params.noise=0.3"`` into ``("params.noise", 0.3)``.

    The value is parsed as a TOML value (``0.3``, ``true``, ``"x"``, ``[1, 2]``), falling back to the bare
    string, so ``params.rule=average`` works. Raises :class:`ConfigError` for anything without ``key=``.
    """
    key, sep, text = expr.partition("=")
    key, text = key.strip(), text.strip()
    if not sep or not key or not all(part.strip() for part in key.split(".")):
        raise ConfigError(f"--set expects key=value, got {_one_line(repr(expr))}")
    try:
        parsed = tomllib.loads(f"value = {text}")
    except tomllib.TOMLDecodeError:
        return key, text
    return key, parsed["value"] if list(parsed) == ["value"] else text


def _read_toml(path: Path) -> dict[str, Any]:
    """Read a TOML file; a missing, unreadable or empty file (no keys: most likely a truncated one) or bad TOML is
    a ConfigError."""
    try:
        with path.open("rb") as file:
            data = tomllib.load(file)
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot read: {error.strerror or error}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ConfigError(_one_line(f"{path}: invalid TOML: {error}")) from None
    if not data:
        raise ConfigError(f"{path}: the config file is empty; it needs at least a key such as model = \"vicsek\"")
    return data


def _plain_dict(mapping: Mapping[str, Any]) -> dict[str, Any]:
    """A deep copy of ``mapping`` with every nested mapping made a dict (the caller's stays untouched)."""
    return {
        key: _plain_dict(value) if isinstance(value, Mapping) else copy.deepcopy(value)
        for key, value in mapping.items()
    }


def _set_dotted(raw: dict[str, Any], key: str, value: Any) -> None:
    """Set ``raw["a"]["b"]["c"] = value`` for ``key = "a.b.c"``, creating missing tables."""
    *tables, last = [part.strip() for part in key.split(".")]
    table = raw
    for depth, part in enumerate(tables):
        inner = table.setdefault(part, {})
        if not isinstance(inner, dict):
            where = ".".join(tables[: depth + 1])
            got = _value_text(inner)
            raise ConfigError(f"{key}: {where} must be a table to set a key in it, got {got}")
        table = inner
    table[last] = _plain_dict(value) if isinstance(value, Mapping) else value


# ----------------------------------------------------------------------------------------------------------
# Error messages: one line, "<dotted.key>: <what is allowed>, got <value>".


#: a config's errors named in its one-line message, the first included; the rest are counted
NAMED_ERRORS = 4


def _error_text(error: ValidationError, model: Any) -> str:
    """The first error as one line, then the next few by key and problem, and a count of the rest: a file with two
    mistakes shows both. The allowed keys are listed once, with the first unknown key."""
    errors = error.errors()
    text = _one_error_text(errors[0], model)
    others = []
    for e in errors[1:NAMED_ERRORS]:
        other = _one_error_text(e, model)
        others.append(other.split("; allowed:")[0] if "; allowed:" in text + "".join(others) else other)
    rest = len(errors) - len(others) - 1
    if others:
        text += f" (also {'; '.join(others)}" + (f"; and {rest} more" if rest else "") + ")"
    return text


def _one_error_text(error: ErrorDetails, model: Any) -> str:
    loc = tuple(str(part) for part in error["loc"])
    kind, ctx, got = error["type"], error.get("ctx") or {}, error.get("input")
    schema = _schema_at(loc[:-1], model)
    field = schema.model_fields.get(loc[-1]) if schema is not None and loc else None

    if kind == "config_rule":
        key = ".".join(loc + ((ctx["key"],) if "key" in ctx else ()))
        return f"{key}: {error['msg']}, got {_value_text(ctx.get('got'))}"
    key = ".".join(loc) or "config"
    if kind == "extra_forbidden":
        allowed = ", ".join(sorted(schema.model_fields)) if schema is not None else "(unknown)"
        text = f"{key}: unknown key; allowed: {allowed}"
        from tflock.sweep.spec import SWEEP_KEYS  # (here: the sweep spec's module imports this one)

        if len(loc) == 1 and key in SWEEP_KEYS:  # a sweep file's keys: not a run config
            text += " (this looks like a sweep file, which `tflock sweep FILE` runs)"
        return text
    if kind == "missing":
        return f"{key}: required key is missing"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        allowed = _range_text(field) if field is not None else _range_text_from(ctx)
    elif kind == "literal_error":
        allowed = f"must be one of {ctx.get('expected', '')}"
        if field is not None and get_origin(field.annotation) is Literal:
            allowed = f"must be one of {', '.join(map(str, get_args(field.annotation)))}"
    elif kind in ("model_type", "model_attributes_type", "dict_type"):
        allowed = "expected a table"
    elif kind == "bool_type":
        allowed = "expected true or false"
    elif kind == "string_type":
        allowed = "expected a string"
    else:
        allowed = error["msg"][:1].lower() + error["msg"][1:]
        if kind == "config_type" and field is not None:
            allowed = with_range(allowed, field)
    return f"{key}: {allowed}, got {_value_text(got)}"


def _schema_at(loc: tuple[str, ...], model: Any) -> type[BaseModel] | None:
    """The schema that holds the table at ``loc`` (``()`` = Config, ``("params",)`` = the model's params)."""
    schema: type[BaseModel] | None = Config
    for part in loc:
        if schema is Config and part == "params":
            schema = PARAMS_SCHEMAS.get(model) if isinstance(model, str) else None
        else:
            field = schema.model_fields.get(part)
            annotation = field.annotation if field is not None else None
            is_table = isinstance(annotation, type) and issubclass(annotation, BaseModel)
            schema = annotation if is_table else None
        if schema is None:
            return None
    return schema


def _bounds(field: FieldInfo) -> dict[str, Any]:
    """The field's numeric bounds, by name (gt, ge, lt, le)."""
    bounds: dict[str, Any] = {}
    for constraint in field.metadata:
        for name in ("gt", "ge", "lt", "le"):
            if getattr(constraint, name, None) is not None:
                bounds[name] = getattr(constraint, name)
    return bounds


def with_range(expected: str, field: FieldInfo) -> str:
    """A type error's "expected a number" with the field's bounds, if any: "expected a finite number > 0",
    "expected an integer between 0 and 4294967295"."""
    return f"{expected} {_range_text(field).removeprefix('must be ')}" if _bounds(field) else expected


def _range_text(field: FieldInfo) -> str:
    """``must be > 0``, ``must be between 0 and 6.283 (2 pi)``, ``must be > 0 and <= 360`` from a field."""
    return _range_text_from(_bounds(field))


def _range_text_from(bounds: Mapping[str, Any]) -> str:
    if "ge" in bounds and "le" in bounds:
        return f"must be between {_number_text(bounds['ge'])} and {_number_text(bounds['le'])}"
    symbols = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}
    parts = [f"{symbol} {_number_text(bounds[name])}" for name, symbol in symbols.items() if name in bounds]
    return "must be " + " and ".join(parts)


def _number_text(value: float) -> str:
    """A bound as people write it: ``0``, ``360``, ``4294967295``, ``111.8``, ``6.283 (2 pi)``."""
    if isinstance(value, int) or float(value).is_integer():
        return str(int(value))
    text = f"{value:.4g}"
    return f"{text} (2 pi)" if value == TWO_PI else text


def _value_text(value: Any) -> str:
    """A given value in a message: ``'abc'``, ``-1``, ``50`` (also for 50.0), ``true``, ``none``; long values
    are cut."""
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e16:
        return str(int(value))
    text = _one_line(repr(value))
    return text if len(text) <= 60 else text[:57] + "..."


def _one_line(text: str) -> str:
    return " ".join(text.split())


# ----------------------------------------------------------------------------------------------------------
# Writing TOML.


#: the header's example of an override, one of each model's own keys
OVERRIDE_EXAMPLES = {"vicsek": "params.noise=0.3", "adaptive": "params.noise=0.3", "potential": "params.dt=0.005",
                     "formation": "params.noise_deg=0.5"}


def default_config_toml(model: str) -> str:
    """The default config of ``model`` as TOML, each key under a ``#`` comment saying what it is.

    It parses back to exactly the defaults; unset keys (``g``) appear as comments only.
    """
    if model not in PARAMS_SCHEMAS:
        raise ConfigError(f"model: must be one of {', '.join(PARAMS_SCHEMAS)}, got {_value_text(model)}")
    header = [
        f"# tflock run config, model {model!r}: {MODEL_DESCRIPTIONS.get(model, '')}".rstrip(),
        f"# Override any key on the command line, e.g. --set {OVERRIDE_EXAMPLES[model]}",
        "",
    ]
    return "\n".join(header + _toml_lines(load_config(model=model), "", comments=True)) + "\n"


def config_to_toml(config: Config) -> str:
    """The resolved config as TOML; ``load_config`` of it gives an equal Config."""
    return "\n".join(_toml_lines(config, "", comments=False)) + "\n"


def config_to_dict(config: Config) -> dict[str, Any]:
    """The config as a plain nested dict of TOML-able values; unset (None) values are left out."""
    return config.model_dump(exclude_none=True)


def _toml_lines(model: BaseModel, table: str, comments: bool) -> list[str]:
    """The keys of ``model`` as TOML lines under ``[table]`` (none for the root), then its sub-tables."""
    lines = [f"[{table}]"] if table else []
    tables: list[tuple[str, FieldInfo, BaseModel]] = []
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        if isinstance(value, BaseModel):
            tables.append((name, field, value))
            continue
        if comments:
            lines += _comment_lines(field)
        if value is not None:
            lines.append(f"{name} = {_toml_value(value)}")
        elif comments:
            lines.append(f"# {name} = (unset)")
    for name, field, value in tables:
        lines += [""] + (_comment_lines(field) if comments else [])
        lines += _toml_lines(value, f"{table}.{name}" if table else name, comments)
    return lines


def _comment_lines(field: FieldInfo) -> list[str]:
    return [f"# {line}" for line in (field.description or "").splitlines()]


_TOML_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def _toml_value(value: Any) -> str:
    """A scalar or a list of scalars as a TOML value."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value)  # shortest text that reads back to the same float; inf and nan are TOML too
    if isinstance(value, str):
        escaped = (
            _TOML_ESCAPES.get(ch) or (f"\\u{ord(ch):04x}" if ord(ch) < 0x20 or ord(ch) == 0x7F else ch)
            for ch in value
        )
        return '"' + "".join(escaped) + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} as a TOML value: {value!r}")


def register_model(name: str, schema: type[BaseModel], description: str, implementation: str) -> None:
    """Add a model: its params schema, a one-line description and its class as ``"module:Class"``.

    Called by each ``tflock/models/<name>_params.py`` (Taichi-free), which this module imports at load time.
    """
    PARAMS_SCHEMAS[name] = schema
    MODEL_DESCRIPTIONS[name] = description
    MODEL_IMPLEMENTATIONS[name] = implementation


def _import_params_modules() -> None:
    import pkgutil
    from importlib import import_module

    import tflock.models

    for info in pkgutil.iter_modules(tflock.models.__path__):
        if info.name.endswith("_params"):
            import_module(f"tflock.models.{info.name}")


_import_params_modules()
