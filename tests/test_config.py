"""Tests of tflock.config: defaults, TOML round trips, overrides and one-line error messages."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from tflock.config import (
    MODEL_DESCRIPTIONS,
    PARAMS_SCHEMAS,
    Config,
    ConfigError,
    VicsekParams,
    config_to_dict,
    config_to_toml,
    default_config_toml,
    load_config,
    parse_override,
)

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

REPO = Path(__file__).parents[1]


def config_error(**kwargs: object) -> str:
    """The message of the ConfigError that load_config(**kwargs) raises; it must be one line."""
    with pytest.raises(ConfigError) as info:
        load_config(**kwargs)
    message = str(info.value)
    assert "\n" not in message
    return message


# ------------------------------------------------------------------------------------------------------------
# Defaults and round trips.


def test_defaults() -> None:
    config = load_config()
    assert config.model == "vicsek"
    assert (config.seed, config.steps) == (0, 200)
    assert isinstance(config.params, VicsekParams)
    assert config.params.model_dump() == {
        "n": 100_000,
        "box": 223.6,
        "radius": 1.0,
        "speed": 0.5,
        "noise": 0.5,
        "boundary": "periodic",
        "rule": "vector",
        "g": None,
        "max_turn_deg": 360.0,
        "async_bound": 1,
        "leader": {"enabled": False, "heading_deg": 0.0},
        "noise_type": "angular",
        "dim": 2,
        "neighbours": "metric",
        "k": 6,
        "wrap_headings": True,
    }
    assert config.engine.model_dump() == {"arch": "cpu", "threads": 0, "precision": "f32"}
    assert config.log.model_dump() == {
        "out": "",
        "every": 1,
        "max_agents": 2000,
        "max_edges": 4000,
        "field": -1,
        "trail": 0,
        "metrics_every": 1,
    }
    assert load_config(model="vicsek") == config == load_config({})


def test_registry_is_consistent() -> None:
    assert set(MODEL_DESCRIPTIONS) == set(PARAMS_SCHEMAS)
    assert all("\n" not in line for line in MODEL_DESCRIPTIONS.values())


def test_every_field_is_described() -> None:
    for schema in [Config, *PARAMS_SCHEMAS.values()]:
        for name, field in schema.model_fields.items():
            assert field.description, f"{schema.__name__}.{name} has no description"


def test_default_toml_parses_back_to_the_defaults() -> None:
    text = default_config_toml("vicsek")
    assert tomllib.loads(text) == config_to_dict(load_config())
    assert load_config(tomllib.loads(text)) == load_config()
    assert "# g = (unset)" in text
    assert 'out = ""' in text
    for header in ("[engine]", "[params]", "[params.leader]", "[log]"):
        assert header in text
    lines = text.splitlines()
    for i, line in enumerate(lines):  # every key has a comment line right above it
        if line and not line.startswith(("#", "[")):
            assert lines[i - 1].startswith("#"), line


@pytest.mark.parametrize("model", sorted(PARAMS_SCHEMAS))
def test_each_configs_header_example_is_one_of_its_keys(model: str) -> None:
    """The header of `tflock config show MODEL` (and configs/MODEL.toml) suggests an override the model accepts
    (formation has no params.noise: the header once suggested it to every model)."""
    text = default_config_toml(model)
    assert (REPO / "configs" / f"{model}.toml").read_text() == text
    key, value = parse_override(text.splitlines()[1].split("--set ")[1])
    assert load_config(model=model, overrides={key: value}) != load_config(model=model)


def test_configs_vicsek_toml_is_the_default(tmp_path: Path) -> None:
    path = REPO / "configs" / "vicsek.toml"
    assert path.read_text() == default_config_toml("vicsek")
    assert load_config(path) == load_config()
    assert load_config(str(path), model="vicsek") == load_config()


def test_config_to_toml_round_trip(tmp_path: Path) -> None:
    config = load_config(
        overrides=[
            "params.rule=laplacian",
            "params.g=2e5",
            "params.noise=0.1",
            "params.leader.enabled=true",
            "params.leader.heading_deg=-12.5",
            'log.out="runs/a \\"quoted\\" \\\\ name\\t.rrd"',
            "engine.arch=cuda",
            "seed=4294967295",
        ]
    )
    assert config.log.out == 'runs/a "quoted" \\ name\t.rrd'
    text = config_to_toml(config)
    assert load_config(tomllib.loads(text)) == config
    path = tmp_path / "run.toml"
    path.write_text(text)
    assert load_config(path) == config
    assert load_config(config_to_dict(config)) == config


def test_config_to_dict_drops_none() -> None:
    data = config_to_dict(load_config())
    assert "g" not in data["params"]
    assert data["params"]["leader"] == {"enabled": False, "heading_deg": 0.0}


def test_float_text_round_trips() -> None:
    values = {"params.noise": 0.1 + 0.2, "params.radius": 1e-7, "params.box": 1e20}
    config = load_config(overrides=values)
    assert load_config(tomllib.loads(config_to_toml(config))) == config


# ------------------------------------------------------------------------------------------------------------
# Sources and overrides.


def test_mapping_source_is_not_modified() -> None:
    source = {"params": {"n": 10}}
    config = load_config(source, overrides=["params.n=20"])
    assert config.params.n == 20
    assert source == {"params": {"n": 10}}


def test_file_without_model_takes_the_argument(tmp_path: Path) -> None:
    path = tmp_path / "run.toml"
    path.write_text("steps = 7\n[params]\nn = 1e3\n")
    config = load_config(path, model="vicsek")
    assert (config.model, config.steps, config.params.n) == ("vicsek", 7, 1000)
    assert isinstance(config.params.n, int)


def test_overrides_are_parsed_as_toml_values() -> None:
    config = load_config(
        overrides=[
            "steps=10",
            "params.noise=0.3",
            "params.rule=average",  # a bare string
            'params.boundary="open"',
            "params.leader.enabled=true",
            "params.leader.heading_deg=90",
            " seed = 3 ",
        ]
    )
    assert (config.steps, config.seed) == (10, 3)
    assert config.params.noise == 0.3
    assert (config.params.rule, config.params.boundary) == ("average", "open")
    assert config.params.leader.enabled is True
    assert config.params.leader.heading_deg == 90.0


def test_mapping_overrides() -> None:
    config = load_config(overrides={"params.noise": 0.25, "params.leader": {"enabled": True}})
    assert config.params.noise == 0.25
    assert config.params.leader.enabled is True


def test_integral_floats_are_integers() -> None:
    assert load_config(overrides=["params.n=1e5"]).params.n == 100_000
    assert load_config(overrides=["params.box=100"]).params.box == 100.0


@pytest.mark.parametrize(
    ("expr", "expected"),
    [
        ("steps=10", ("steps", 10)),
        ("params.noise=0.3", ("params.noise", 0.3)),
        ("params.rule=average", ("params.rule", "average")),
        ('log.out="a=b.rrd"', ("log.out", "a=b.rrd")),
        ("x=[1, 2]", ("x", [1, 2])),
        ("x=true", ("x", True)),
        ("x=", ("x", "")),
        ("x=1\ny=2", ("x", "1\ny=2")),
    ],
)
def test_parse_override(expr: str, expected: tuple[str, object]) -> None:
    assert parse_override(expr) == expected


@pytest.mark.parametrize("expr", ["foo", "=3", "a..b=1", ".a=1"])
def test_bad_override_expression(expr: str) -> None:
    message = config_error(overrides=[expr])
    assert message == f"--set expects key=value, got {expr!r}"


def test_laplacian_with_large_g_is_valid() -> None:
    config = load_config(overrides=["params.rule=laplacian", "params.g=100001"])
    assert config.params.g == 100001.0


# ------------------------------------------------------------------------------------------------------------
# Errors: one line, naming the key and what is allowed.


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        (["params.nosie=1"], "params.nosie: unknown key; allowed: async_bound, boundary, box, dim, g, k, leader,"),
        (["colour=1"], "colour: unknown key; allowed: engine, log, model, params, seed, steps"),
        (["engine.gpu=1"], "engine.gpu: unknown key; allowed: arch, precision, threads"),
        (["params.leader.color=1"], "params.leader.color: unknown key; allowed: enabled, heading_deg"),
        (["params.n=abc"], "params.n: expected an integer > 0, got 'abc'"),
        (["params.n=1.5"], "params.n: expected an integer > 0, got 1.5"),
        (["params.radius=big"], "params.radius: expected a number > 0, got 'big'"),
        (["params.box=inf"], "params.box: expected a finite number > 0, got inf"),
        (["params.leader.enabled=1"], "params.leader.enabled: expected true or false, got 1"),
        (["log.out=5"], "log.out: expected a string, got 5"),
        (["engine=5"], "engine: expected a table, got 5"),
        (["params.n=0"], "params.n: must be > 0, got 0"),
        (["params.n=-5"], "params.n: must be > 0, got -5"),
        (["params.radius=-1"], "params.radius: must be > 0, got -1"),
        (["params.noise=7"], "params.noise: must be between 0 and 6.283 (2 pi), got 7"),
        (["params.noise=-1"], "params.noise: must be between 0 and 6.283 (2 pi), got -1"),
        (["params.max_turn_deg=0"], "params.max_turn_deg: must be > 0 and <= 360, got 0"),
        (["engine.arch=tpu"], "engine.arch: must be one of cpu, cuda, vulkan, auto, got 'tpu'"),
        (["params.rule=mean"], "params.rule: must be one of vector, average, relative, laplacian, got 'me"),
        (["seed=-1"], "seed: must be between 0 and 4294967295, got -1"),
        (["seed=4294967296"], "seed: must be between 0 and 4294967295, got 4294967296"),
        (["steps=-1"], "steps: must be between 0 and 2147483647, got -1"),
        (["log.every=0"], "log.every: must be >= 1, got 0"),
        (["params.async_bound=0"], "params.async_bound: must be between 1 and 1000, got 0"),
        (["params.async_bound=1001"], "params.async_bound: must be between 1 and 1000, got 1001"),
        (
            ["params.rule=laplacian", "params.g=50"],
            "params.g: must be > params.n (= 100000) for rule 'laplacian' (Jadbabaie eq. 18), got 50",
        ),
        (
            ["params.rule=laplacian", "params.g=100000"],
            "params.g: must be > params.n (= 100000) for rule 'laplacian' (Jadbabaie eq. 18), got 100000",
        ),
        (
            ["params.rule=laplacian"],
            "params.g: must be > params.n (= 100000) for rule 'laplacian' (Jadbabaie eq. 18), got none",
        ),
        (
            ["params.speed=200"],
            "params.speed: must be < params.box / 2 (= 111.8) for boundary 'periodic', got 200",
        ),
        (
            ["params.noise_type=vectorial", "params.rule=average"],
            "params.noise_type: must be 'angular' for rule 'average' (vectorial noise joins the sum of heading",
        ),
        (["params.noise_type=scalar"], "params.noise_type: must be one of angular, vectorial, got 'scalar'"),
        (["params.dim=1"], "params.dim: must be one of 2, 3, got 1"),
        (["params.dim=3", "params.rule=relative"], "params.rule: must be 'vector' in 3D (the other rules are"),
        (["params.dim=3", "params.async_bound=2"], "params.async_bound: must be 1 in 3D (asynchrony is 2D only)"),
        (["params.dim=3", "params.leader.enabled=true"], "params.leader.enabled: must be off in 3D"),
        (["params.neighbours=knn"], "params.neighbours: must be one of metric, topological, got 'knn'"),
        (["params.k=65"], "params.k: must be between 1 and 32, got 65"),
        (
            ["params.neighbours=topological", "params.n=6"],
            "params.k: must be < params.n (= 6) for topological neighbours, got 6",
        ),
        (
            ["params.neighbours=topological", "params.async_bound=4"],
            "params.async_bound: must be 1 with topological neighbours",
        ),
    ],
)
def test_error_messages(overrides: list[str], expected: str) -> None:
    assert config_error(overrides=overrides).startswith(expected)


def test_unknown_params_key_lists_all_allowed_keys_sorted() -> None:
    message = config_error(overrides=["params.nosie=1"])
    allowed = message.split("allowed: ")[1].split(", ")
    assert allowed == sorted(VicsekParams.model_fields)


def test_open_space_allows_any_speed() -> None:
    assert load_config(overrides=["params.boundary=open", "params.speed=200"]).params.speed == 200.0


def test_several_errors_report_the_first_and_name_the_rest() -> None:
    message = config_error(overrides=["params.n=0", "params.radius=0", "steps=-1"])
    assert message == ("steps: must be between 0 and 2147483647, got -1 (also params.n: must be > 0, got 0; "
                       "params.radius: must be > 0, got 0)")
    # an unknown key among them lists the allowed keys, once; beyond NAMED_ERRORS, a count
    message = config_error(overrides=["params.n=0", "params.nosie=1", "params.nouse=1"])
    assert message.startswith("params.n: must be > 0, got 0 (also params.nosie: unknown key; allowed: ")
    assert message.count("allowed") == 1 and message.endswith("; params.nouse: unknown key)")
    message = config_error(overrides=["params.n=0", "params.radius=0", "params.speed=-1", "params.box=-1",
                                      "params.nosie=1"])
    assert message.endswith("; and 1 more)") and "\n" not in message


def test_unknown_model() -> None:
    from tflock.config import PARAMS_SCHEMAS

    allowed = ", ".join(PARAMS_SCHEMAS)
    assert "vicsek" in PARAMS_SCHEMAS and len(PARAMS_SCHEMAS) >= 2
    assert config_error(model="boids") == f"model: must be one of {allowed}, got 'boids'"
    assert config_error(source={"model": "boids"}).startswith(f"model: must be one of {allowed}")
    with pytest.raises(ConfigError, match=f"model: must be one of {allowed}, got 'boids'"):
        default_config_toml("boids")


def test_model_argument_conflicting_with_the_file() -> None:
    message = config_error(source={"model": "vicsek"}, model="boids")
    assert "'vicsek'" in message and "'boids'" in message


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.toml"
    assert config_error(source=path) == f"config file not found: {path}"
    assert config_error(source=str(path)) == f"config file not found: {path}"


def test_invalid_toml(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text("[params]\nn = = 3\n")
    message = config_error(source=path)
    assert message.startswith(f"{path}: invalid TOML: ")
    assert "line 2" in message


def test_error_values_are_kept_short_and_on_one_line() -> None:
    message = config_error(overrides={"log.out": ["x\ny"] * 50})
    assert message.startswith("log.out: expected a string, got [")
    assert len(message) < 120


def test_config_error_is_a_value_error() -> None:
    assert issubclass(ConfigError, ValueError)
    assert math.isclose(load_config(overrides=["params.noise=6.283185307179586"]).params.noise, 2 * math.pi)
