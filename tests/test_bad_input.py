"""Bad input, from the command line: every case is refused with exactly one line (``error: ...`` naming what is
wrong), exit code 2, no traceback, and no file written (no recording, metrics table or checkpoint that could pass
for a finished run).

Hand-written cases cover every model's parameters, every command and option, config and checkpoint files (empty,
binary, invalid, directories, wrong types, nan / inf, unknown keys) and output paths that cannot be written;
hypothesis generates more: out-of-range, non-finite and wrongly typed values for every constrained key of every
model's schema, garbage option values, ``--set`` expressions, config files and checkpoints. They run in-process
(typer's CliRunner); a few run the real entry point, ``python -m tflock``, to show that no traceback reaches a
terminal. Refusals of a run's config or paths must come before the Taichi engine starts (nothing is allocated),
which the tests enforce by making the engine's start-up fail loudly.
"""

import math
import os
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any, Literal, get_args, get_origin

import numpy as np
import pytest
from conftest import PRECISION, assert_one_error_line, invoke_in
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, TypeAdapter

from tflock.config import PARAMS_SCHEMAS, Config, load_config
from tflock.preflight import check_viewer

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
SMALL = ["--set", "params.n=200", "--set", "params.box=10.0", "--steps", "3"]
GENERATED = settings(max_examples=50, deadline=None, derandomize=True, database=None,
                     suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


# ----------------------------------------------------------------------------------------------------------
# Helpers


@pytest.fixture(autouse=True)
def _small_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    """A machine with 8 GiB of memory, so that the huge-N cases are beyond memory wherever the tests run."""
    monkeypatch.setattr("tflock.preflight.physical_memory", lambda: 8 * 2**30)


@pytest.fixture
def no_engine(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test (exit code 1, not 2) if a run gets as far as starting the engine."""

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the engine was started: the input should have been refused before")

    monkeypatch.setattr("tflock.simulation.init_engine", refuse)


def checkpoint_file(path: Path, config_toml: str | None = 'model = "vicsek"\n', **arrays: Any) -> None:
    """An .npz shaped like a tflock checkpoint (format 1), with what is given."""
    fields: dict[str, Any] = {"format": np.int64(1), "recording_id": np.str_("x"), "step": np.int64(3), **arrays}
    if config_toml is not None:
        fields["config_toml"] = np.str_(config_toml)
    with open(path, "wb") as file:
        np.savez(file, **fields)


SMALL_TOML = f'model = "vicsek"\n[engine]\nprecision = "{PRECISION}"\n[params]\nn = 50\nbox = 5.0\n'

FILES: dict[str, bytes | str | None] = {  # None: a directory
    "empty.toml": "",
    "comments.toml": "# only a comment\n\n",
    "binary.toml": bytes(range(256)) * 4,
    "invalid.toml": 'model = "vicsek\n[params\nn = 500\n',
    "nul.toml": 'model = "vicsek"\x00\n',
    "utf16.toml": 'model = "vicsek"\n'.encode("utf-16"),
    "dir.toml": None,
    "unknown_top.toml": 'model = "vicsek"\nsteps = 3\nbogus_key = 1\n',
    "sweep_file.toml": 'name = "noise"\nmodel = "vicsek"\nreplicas = 2\n[grid]\n"params.noise" = [0.5, 1.0]\n',
    "unknown_param.toml": 'model = "vicsek"\n[params]\nnosie = 0.1\n',
    "n_string.toml": 'model = "vicsek"\n[params]\nn = "100"\n',
    "n_float.toml": 'model = "vicsek"\n[params]\nn = 100.5\n',
    "noise_list.toml": 'model = "vicsek"\n[params]\nnoise = [0.1]\n',
    "noise_bool.toml": 'model = "vicsek"\n[params]\nnoise = true\n',
    "box_nan.toml": 'model = "vicsek"\n[params]\nbox = nan\n',
    "radius_neginf.toml": 'model = "vicsek"\n[params]\nradius = -inf\n',
    "speed_inf.toml": 'model = "vicsek"\n[params]\nspeed = inf\n',
    "radius_negative.toml": 'model = "vicsek"\n[params]\nradius = -1.0\n',
    "model_int.toml": "model = 3\n",
    "model_unknown.toml": 'model = "boids"\n',
    "params_int.toml": 'model = "vicsek"\nparams = 3\n',
    "engine_string.toml": 'model = "vicsek"\nengine = "cpu"\n',
    "steps_negative.toml": 'model = "vicsek"\nsteps = -5\n',
    "huge_n.toml": 'model = "vicsek"\n[params]\nn = 10000000000000\n',
    "alpha_nan.toml": 'model = "adaptive"\n[params]\nalpha = nan\n',
    "alpha_neginf.toml": 'model = "adaptive"\n[params]\nalpha = -inf\n',
    "dt_inf.toml": 'model = "potential"\n[params]\ndt = inf\n',
    "weights_nan.toml": 'model = "formation"\n[params.weights]\nalign = nan\n',
    "notes.txt": "not a checkpoint, not a recording\n" * 20,
    "empty.npz": "",
    "fake.npz": b"PK\x03\x04 not really a zip",
    "afile": "a regular file: no directory can be made under it\n",
    "out_dir.rrd": None,
    "ck_dir": None,
    "ck_dir.npz": None,
    "empty.rrd": "",
    "garbage.rrd": bytes(range(256)) * 8,
    "graph_binary.txt": bytes(range(256)),
    "graph_split.txt": "0 1\n2 3\n",
    "graph_superscript.txt": "0 1\n1 \u00b2\n",
    "m.metrics.csv": None,  # a directory where `--out m.rrd` would put its metrics table
}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with every bad file the cases name (the current directory of every in-process run)."""
    root = tmp_path_factory.mktemp("bad-input")
    for name, content in FILES.items():
        path = root / name
        if content is None:
            path.mkdir()
        elif isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content, encoding="utf-8")
    np.savez(root / "noformat.npz", a=np.arange(3))
    checkpoint_file(root / "noconfig.npz", config_toml=None)
    checkpoint_file(root / "badtoml.npz", config_toml="model = [[[")
    checkpoint_file(root / "badconfig.npz", config_toml='model = "vicsek"\n[params]\nn = -5\n')
    checkpoint_file(root / "mismatch.npz", config_toml=SMALL_TOML, **{"model__pos": np.zeros((2, 7))})
    checkpoint_file(root / "at3.npz", config_toml=SMALL_TOML)  # a run at step 3
    whole = (root / "mismatch.npz").read_bytes()
    (root / "truncated.npz").write_bytes(whole[: len(whole) // 2])
    with open(root / "array.npz", "wb") as file:
        np.save(file, np.arange(3))
    return root


def listing(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def refused_cleanly(args: list[str], cwd: Path, *needles: str) -> str:
    """`assert_one_error_line`, and nothing was written in `cwd`."""
    before = listing(cwd)
    line = assert_one_error_line(invoke_in(cwd, args), *needles)
    assert listing(cwd) == before, f"files left behind: {sorted(listing(cwd) - before)}"
    return line


# ----------------------------------------------------------------------------------------------------------
# Hand-written cases: `tflock sim`


def params(model: str, *pairs: str) -> list[str]:
    return ["--model", model, *(arg for pair in pairs for arg in ("--set", f"params.{pair}"))]


MODEL_PARAMS = [
    # vicsek
    (params("vicsek", "n=0"), ["params.n", "must be > 0", "got 0"]),
    (params("vicsek", "n=-3"), ["params.n", "must be > 0", "-3"]),
    (params("vicsek", "n=abc"), ["params.n", "expected an integer", "abc"]),
    (params("vicsek", "n=1.5"), ["params.n", "expected an integer", "1.5"]),
    (params("vicsek", "n=[1,2]"), ["params.n", "expected an integer"]),
    (params("vicsek", "n=true"), ["params.n", "expected an integer", "true"]),
    (params("vicsek", "n=nan"), ["params.n", "expected an integer", "nan"]),
    (params("vicsek", "n={a=1}"), ["params.n", "expected an integer"]),
    (params("vicsek", "box=0"), ["params.box", "must be > 0"]),
    (params("vicsek", "box=-1"), ["params.box", "must be > 0", "-1"]),
    (params("vicsek", "box=nan"), ["params.box", "finite", "nan"]),
    (params("vicsek", "box=inf"), ["params.box", "finite", "inf"]),
    (params("vicsek", 'box="10"'), ["params.box", "expected a number", "'10'"]),
    (params("vicsek", "radius=0"), ["params.radius", "must be > 0"]),
    (params("vicsek", "radius=-1"), ["params.radius", "must be > 0", "-1"]),
    (params("vicsek", "radius=-inf"), ["params.radius", "finite", "-inf"]),
    (params("vicsek", "speed=-0.1"), ["params.speed", "must be >= 0", "-0.1"]),
    (params("vicsek", "speed=inf"), ["params.speed", "finite"]),
    (params("vicsek", "speed=200.0"), ["params.speed", "params.box / 2", "200"]),
    (params("vicsek", "noise=-1"), ["params.noise", "between 0 and 6.283", "-1"]),
    (params("vicsek", "noise=7"), ["params.noise", "between 0 and 6.283", "7"]),
    (params("vicsek", "noise=nan"), ["params.noise", "finite", "nan"]),
    (params("vicsek", "noise=[0.1]"), ["params.noise", "expected a number"]),
    (params("vicsek", "noise=true"), ["params.noise", "expected a number", "true"]),
    (params("vicsek", "boundary=torus"), ["params.boundary", "periodic, reflecting, open", "torus"]),
    (params("vicsek", "boundary=1"), ["params.boundary", "periodic, reflecting, open"]),
    (params("vicsek", "rule=boids"), ["params.rule", "vector, average, relative, laplacian", "boids"]),
    (params("vicsek", "rule=laplacian"), ["params.g", "> params.n", "laplacian"]),
    (params("vicsek", "rule=laplacian", "g=10", "n=500"), ["params.g", "> params.n (= 500)", "10"]),
    (params("vicsek", "g=-1"), ["params.g", "must be > 0", "-1"]),
    (params("vicsek", "max_turn_deg=0"), ["params.max_turn_deg", "must be > 0 and <= 360"]),
    (params("vicsek", "max_turn_deg=361"), ["params.max_turn_deg", "<= 360", "361"]),
    (params("vicsek", "async_bound=0"), ["params.async_bound", "between 1 and 1000", "0"]),
    (params("vicsek", "async_bound=1001"), ["params.async_bound", "between 1 and 1000", "1001"]),
    (params("vicsek", "async_bound=2.5"), ["params.async_bound", "expected an integer", "2.5"]),
    (params("vicsek", "leader=3"), ["params.leader", "expected a table", "3"]),
    (params("vicsek", "leader.enabled=1"), ["params.leader.enabled", "true or false", "1"]),
    (params("vicsek", 'leader.enabled="yes"'), ["params.leader.enabled", "true or false", "'yes'"]),
    (params("vicsek", "leader.heading_deg=nan"), ["params.leader.heading_deg", "finite", "nan"]),
    (params("vicsek", "leader.bogus=1"), ["params.leader.bogus", "unknown key", "enabled, heading_deg"]),
    (params("vicsek", "nosie=1"), ["params.nosie", "unknown key", "noise"]),
    (params("vicsek", "dim=4"), ["params.dim", "2, 3", "4"]),
    (params("vicsek", "dim=3", "rule=average"), ["params.rule", "'vector' in 3D", "'average'"]),
    (params("vicsek", 'noise_type="gauss"'), ["params.noise_type", "angular, vectorial", "'gauss'"]),
    (params("vicsek", 'noise_type="vectorial"', 'rule="relative"'), ["params.noise_type", "rule 'relative'"]),
    (params("vicsek", 'neighbours="knn"'), ["params.neighbours", "metric, topological", "'knn'"]),
    (params("vicsek", "k=0"), ["params.k", "between 1 and 32", "0"]),
    (params("vicsek", 'neighbours="topological"', "n=10", "k=20"), ["params.k", "< params.n (= 10)", "20"]),
    (params("vicsek", "n.x=1"), ["params.n", "expected an integer"]),
    # adaptive
    (params("adaptive", "alpha=-1"), ["params.alpha", '>= 0 or "inf"', "-1"]),
    (params("adaptive", "alpha=nan"), ["params.alpha", '>= 0 or "inf"', "nan"]),
    (params("adaptive", "alpha=-inf"), ["params.alpha", '>= 0 or "inf"', "-inf"]),
    (params("adaptive", "alpha=infinity"), ["params.alpha", '>= 0 or "inf"', "'infinity'"]),
    (params("adaptive", "alpha=true"), ["params.alpha", '>= 0 or "inf"', "true"]),
    (params("adaptive", "alpha=[1]"), ["params.alpha", '>= 0 or "inf"']),
    (params("adaptive", "dim=4"), ["params.dim", "2, 3", "4"]),
    (params("adaptive", "dim=1"), ["params.dim", "2, 3", "1"]),
    (params("adaptive", "noise=4"), ["params.noise", "between 0 and 3.142", "4"]),
    (params("adaptive", "boundary=reflecting"), ["params.boundary", "open, periodic", "reflecting"]),
    (params("adaptive", "box=0"), ["params.box", "must be > 0"]),
    (params("adaptive", "radius=inf"), ["params.radius", "finite"]),
    (params("adaptive", "speed=-1"), ["params.speed", ">= 0"]),
    (params("adaptive", "rule=vector"), ["params.rule", "unknown key", "alpha"]),
    # potential
    (params("potential", "dt=0"), ["params.dt", "must be > 0"]),
    (params("potential", "dt=-1"), ["params.dt", "must be > 0", "-1"]),
    (params("potential", "dt=inf"), ["params.dt", "finite", "inf"]),
    (params("potential", "desired_distance=3.0"), ["params.desired_distance", "< params.radius (= 2)", "3"]),
    (params("potential", "min_separation=1.5"), ["params.min_separation", "< params.desired_distance", "1.5"]),
    (params("potential", "n=1000", "box=1.0", "min_separation=0.5"), ["params.min_separation", "too large"]),
    (params("potential", "box=1e-200"), ["params.min_separation", "too large"]),
    (params("potential", "topology=random"), ["params.topology", "switching, fixed", "random"]),
    (params("potential", "topology=fixed", "graph=star"), ["params.graph", "random, complete", "star"]),
    (params("potential", "topology=fixed", "graph=complete"), ["params.graph", "n <= 5000"]),
    (params("potential", "topology=fixed", "graph=file", "n=10", "box=5.0"), ["params.graph_file", "must name"]),
    (params("potential", "topology=fixed", "graph=file", "n=10", "box=5.0", "graph_file=nope.txt"),
     ["params.graph_file", "nope.txt"]),
    (params("potential", "topology=fixed", "graph=file", "n=10", "box=5.0", "graph_file=graph_binary.txt"),
     ["params.graph_file", "graph_binary.txt"]),
    (params("potential", "topology=fixed", "graph=file", "n=4", "box=5.0", "graph_file=graph_split.txt"),
     ["params.graph_file", "graph_split.txt"]),
    (params("potential", "topology=fixed", "graph=file", "n=4", "box=5.0", "graph_file=graph_superscript.txt"),
     ["params.graph_file", "expected two agent ids"]),
    (params("potential", "topology=fixed", "graph=file", "n=10", "box=5.0", "graph_file=dir.toml"),
     ["params.graph_file", "dir.toml"]),
    (params("potential", "graph_p=0"), ["params.graph_p", "must be > 0 and <= 1"]),
    (params("potential", "graph_p=1.5"), ["params.graph_p", "<= 1", "1.5"]),
    (params("potential", "lambda2_every=0"), ["params.lambda2_every", ">= 1", "0"]),
    (params("potential", "dim=1"), ["params.dim", "2, 3", "1"]),
    (params("potential", "speed=0"), ["params.speed", "must be > 0"]),
    (params("potential", "graph_file=3"), ["params.graph_file", "expected a string", "3"]),
    # formation
    (params("formation", "strategy=S-3.1"), ["params.strategy", "S-1.1", "S-3.1"]),
    (params("formation", "weights.align=-1"), ["params.weights.align", ">= 0", "-1"]),
    (params("formation", "weights.align=nan"), ["params.weights.align", "finite", "nan"]),
    (params("formation", "weights.bogus=1"), ["params.weights.bogus", "unknown key", "va_cohesion"]),
    (params("formation", "weights=3"), ["params.weights", "expected a table", "3"]),
    (params("formation", "fail_prob=1.5"), ["params.fail_prob", "between 0 and 1", "1.5"]),
    (params("formation", "noise_deg=181"), ["params.noise_deg", "between 0 and 180", "181"]),
    (params("formation", "min_separation=6"), ["params.min_separation", "<= params.radius", "6"]),
    (params("formation", "align_radius=1"), ["params.align_radius", "[params.min_separation, params.radius]"]),
    (params("formation", "out_speed=0.5"), ["params.out_speed", ">= params.va_speed", "0.5"]),
    (params("formation", "world=100"), ["params.world", "must be >", "100"]),
    (params("formation", "ramp_jitter=2"), ["params.ramp_jitter", "between 0 and 1", "2"]),
    (params("formation", "tau_cap=0"), ["params.tau_cap", "must be > 0", "0"]),
    (params("formation", "va_heading_deg=inf"), ["params.va_heading_deg", "finite", "inf"]),
    (params("formation", "beta_lim_deg=0"), ["params.beta_lim_deg", "must be > 0"]),
    (params("formation", "separation_turn_deg=-2"), ["params.separation_turn_deg", "must be > 0", "-2"]),
    # huge N: refused before anything is allocated, naming params.n and the memory
    (params("vicsek", "n=10000000000000"), ["params.n", "<= 2147483647", "10000000000000"]),
    (params("vicsek", "n=1e13"), ["params.n", "<= 2147483647"]),
    (params("vicsek", "n=2000000000"), ["params.n", "GiB", "bytes per agent", "of memory", "agents fit"]),
    (params("adaptive", "n=2000000000", "dim=3"), ["params.n", "GiB", "of memory"]),
    (params("potential", "n=2000000000", "box=1e6"), ["params.n", "GiB", "of memory"]),
    (params("formation", "n=2000000000", "world=1e7", "init_length=1e6", "init_width=1e6"),
     ["params.n", "GiB", "of memory"]),
    (params("vicsek", "n=10000000", "async_bound=1000"), ["params.n", "GiB", "of memory"]),
]

SIM_OPTIONS = [
    (["--steps", "-1"], ["steps", "must be between 0 and 2147483647", "-1"]),
    (["--steps", "abc"], ["--steps", "valid integer", "sim --help"]),
    (["--steps", "1.5"], ["--steps", "valid integer"]),
    (["--steps", str(2**31)], ["steps", "between 0 and 2147483647", str(2**31)]),  # the kernels' 32-bit counter
    (["--steps", str(2**62)], ["steps", "between 0 and 2147483647", str(2**62)]),
    (["--steps", str(2**63)], ["steps", "between 0 and 2147483647", str(2**63)]),
    (["--set", "steps=1e30"], ["steps", "between 0 and 2147483647"]),
    (["--steps"], ["--steps", "requires an argument"]),
    (["--seed", "-1"], ["seed", "between 0 and 4294967295", "-1"]),
    (["--seed", "4294967296"], ["seed", "between 0 and 4294967295"]),
    (["--seed", "x"], ["--seed", "valid integer"]),
    (["--threads", "-1"], ["engine.threads", ">= 0", "-1"]),
    (["--threads", "1.5"], ["--threads", "valid integer"]),
    (["--arch", "bogus"], ["engine.arch", "cpu, cuda, vulkan, auto", "bogus"]),
    (["--arch", ""], ["engine.arch", "cpu, cuda, vulkan, auto"]),
    (["--precision", "f16"], ["No such option: --precision"]),
    (["--set", "engine.precision=f16"], ["engine.precision", "f32, f64", "f16"]),
    (["--set", "engine.precision=64"], ["engine.precision", "f32, f64"]),
    (["--set", "engine.bogus=1"], ["engine.bogus", "unknown key", "arch, precision, threads"]),
    (["--set", "engine=cpu"], ["engine", "expected a table"]),
    (["--set", "log.every=0"], ["log.every", ">= 1", "0"]),
    (["--set", "log.metrics_every=0"], ["log.metrics_every", ">= 1", "0"]),
    (["--set", "log.max_agents=-1"], ["log.max_agents", ">= 0", "-1"]),
    (["--set", "log.max_edges=-5"], ["log.max_edges", ">= 0", "-5"]),
    (["--set", "log.out=x.txt"], ["log.out", ".rrd", "x.txt"]),
    (["--set", "log.out=3"], ["log.out", "expected a string", "3"]),
    (["--set", "bogus=1"], ["bogus", "unknown key", "engine, log, model, params, seed, steps"]),
    (["--set", "model=3"], ["model", "3"]),
    (["--set", "params=3"], ["params", "expected a table", "3"]),
    (["--set", "params"], ["--set", "key=value", "params"]),
    (["--set", "=3"], ["--set", "key=value"]),
    (["--set", "params..n=1"], ["--set", "key=value"]),
    (["--set", ".n=1"], ["--set", "key=value"]),
    (["--set", "params.n="], ["params.n", "expected an integer"]),
    (["--set", "[params]=1"], ["[params]", "unknown key"]),
    (["--model", "nosuch"], ["model", "nosuch", "vicsek"]),
    (["--model", ""], ["model", "vicsek"]),
    (["--model", "adaptive", "--config", "huge_n.toml"], ["model", "vicsek", "adaptive"]),
    (["--checkpoint-every", "-1"], ["--checkpoint-every", ">= 0", "-1"]),
    (["--checkpoint-every", "x"], ["--checkpoint-every", "valid integer"]),
    (["--bogus"], ["No such option: --bogus"]),
    (["extra"], ["extra"]),
    (["--out", "x.txt"], ["--out", ".rrd", "x.txt"]),
    (["--out", "x"], ["--out", ".rrd"]),
]

CONFIG_FILES = [
    ("empty.toml", ["empty.toml", "empty"]),
    ("comments.toml", ["comments.toml", "empty"]),
    ("binary.toml", ["binary.toml", "invalid TOML"]),
    ("invalid.toml", ["invalid.toml", "invalid TOML"]),
    ("nul.toml", ["nul.toml", "invalid TOML"]),
    ("utf16.toml", ["utf16.toml", "invalid TOML"]),
    ("dir.toml", ["dir.toml", "cannot read"]),
    ("missing.toml", ["missing.toml", "not found"]),
    ("unknown_top.toml", ["bogus_key", "unknown key", "engine, log, model, params, seed, steps"]),
    ("unknown_param.toml", ["params.nosie", "unknown key", "noise"]),
    ("sweep_file.toml", ["name", "unknown key", "this looks like a sweep file, which `tflock sweep FILE` runs"]),
    ("n_string.toml", ["params.n", "expected an integer", "'100'"]),
    ("n_float.toml", ["params.n", "expected an integer", "100.5"]),
    ("noise_list.toml", ["params.noise", "expected a number"]),
    ("noise_bool.toml", ["params.noise", "expected a number", "true"]),
    ("box_nan.toml", ["params.box", "finite", "nan"]),
    ("radius_neginf.toml", ["params.radius", "finite", "-inf"]),
    ("speed_inf.toml", ["params.speed", "finite", "inf"]),
    ("radius_negative.toml", ["params.radius", "must be > 0", "-1"]),
    ("model_int.toml", ["model", "3"]),
    ("model_unknown.toml", ["model", "must be one of", "boids"]),
    ("params_int.toml", ["params", "expected a table"]),
    ("engine_string.toml", ["engine", "expected a table", "'cpu'"]),
    ("steps_negative.toml", ["steps", "between 0 and 2147483647", "-5"]),
    ("huge_n.toml", ["params.n", "<= 2147483647"]),
    ("alpha_nan.toml", ["params.alpha", "nan"]),
    ("alpha_neginf.toml", ["params.alpha", "-inf"]),
    ("dt_inf.toml", ["params.dt", "finite"]),
    ("weights_nan.toml", ["params.weights.align", "finite"]),
    ("notes.txt", ["notes.txt", "invalid TOML"]),
]

RESUMES = [
    (["--resume", "missing.npz"], ["--resume", "not found", "missing.npz"]),
    (["--resume", "ck_dir"], ["--resume", "ck_dir", "not a checkpoint file"]),
    (["--resume", "notes.txt"], ["--resume", "notes.txt", "not a tflock checkpoint"]),
    (["--resume", "empty.npz"], ["--resume", "empty.npz", "not a tflock checkpoint"]),
    (["--resume", "fake.npz"], ["--resume", "fake.npz", "not a tflock checkpoint"]),
    (["--resume", "noformat.npz"], ["--resume", "noformat.npz", "not a tflock checkpoint"]),
    (["--resume", "noconfig.npz"], ["--resume", "noconfig.npz", "not a tflock checkpoint"]),
    (["--resume", "badtoml.npz"], ["--resume", "badtoml.npz", "not a tflock checkpoint"]),
    (["--resume", "truncated.npz"], ["--resume", "truncated.npz", "not a tflock checkpoint"]),
    (["--resume", "array.npz"], ["--resume", "array.npz", "not a tflock checkpoint"]),
    (["--resume", "garbage.rrd"], ["--resume", "garbage.rrd", "not a tflock checkpoint"]),
    (["--resume", "badconfig.npz"], ["params.n", "must be > 0", "-5"]),
    (["--resume", "notes.txt", "--model", "vicsek"], ["--resume", "only --steps"]),
    (["--resume", "notes.txt", "--config", "empty.toml"], ["--resume"]),
    (["--resume", "notes.txt", "--seed", "3"], ["--resume"]),
    (["--resume", "notes.txt", "--set", "params.n=5"], ["--resume", "only --steps"]),
    (["--resume", "at3.npz", "--steps", "3"], ["--steps", "checkpoint is at step 3", "nothing to run", "> 3"]),
    (["--resume", "at3.npz", "--steps", "1", "--out", "r.rrd"], ["--steps", "would end at step 1", "nothing to run"]),
]

OUTPUTS = [
    (["--out", "/proc/forbidden/x.rrd"], ["cannot write the recording", "/proc/forbidden/x.rrd"]),
    (["--out", "afile/x.rrd"], ["cannot write the recording", "afile/x.rrd"]),
    (["--out", "afile/deeper/x.rrd"],
     ["cannot write the recording", "afile/deeper/x.rrd", "afile is a file, not a folder"]),
    (["--out", "out_dir.rrd"], ["cannot write the recording", "out_dir.rrd", "directory"]),
    (["--out", "m.rrd"], ["cannot write the metrics table", "m.metrics.csv", "directory"]),
    (["--set", "log.out=afile/x.rrd"], ["cannot write the recording", "afile/x.rrd"]),
    (["--set", "log.out=/proc/forbidden/x.rrd"], ["cannot write the recording", "/proc/forbidden"]),
    (["--no-log", "--checkpoint", "afile/c.npz"], ["cannot write the checkpoint", "afile/c.npz"]),
    (["--no-log", "--checkpoint-every", "2", "--checkpoint", "/proc/forbidden/c.npz"],
     ["cannot write the checkpoint", "/proc/forbidden/c.npz"]),
    (["--no-log", "--checkpoint-every", "2", "--checkpoint", "ck_dir.npz"],
     ["cannot write the checkpoint", "directory"]),
    (["--checkpoint-every", "2", "--out", "afile/x.rrd"], ["cannot write the checkpoint", "afile/x.checkpoint.npz"]),
    (["--out", "x.rrd", "--no-log"], ["--out and --no-log", "give one of them"]),
    (["--no-log", "--checkpoint", "c.txt"], ["--checkpoint", "must be a .npz file", "c.txt"]),
]


@pytest.mark.parametrize(("args", "needles"), MODEL_PARAMS + SIM_OPTIONS,
                         ids=[" ".join(a) for a, _ in MODEL_PARAMS + SIM_OPTIONS])
def test_sim_values(workdir: Path, no_engine: None, args: list[str], needles: list[str]) -> None:
    refused_cleanly(["sim", *args], workdir, *needles)


@pytest.mark.parametrize(("name", "needles"), CONFIG_FILES, ids=[n for n, _ in CONFIG_FILES])
def test_sim_config_files(workdir: Path, no_engine: None, name: str, needles: list[str]) -> None:
    refused_cleanly(["sim", "--config", name], workdir, *needles)


@pytest.mark.parametrize(("args", "needles"), RESUMES, ids=[" ".join(a) for a, _ in RESUMES])
def test_sim_resume(workdir: Path, no_engine: None, args: list[str], needles: list[str]) -> None:
    refused_cleanly(["sim", *args], workdir, *needles)


@pytest.mark.parametrize(("args", "needles"), OUTPUTS, ids=[" ".join(a) for a, _ in OUTPUTS])
def test_sim_outputs(workdir: Path, no_engine: None, args: list[str], needles: list[str]) -> None:
    refused_cleanly(["sim", *SMALL, *args], workdir, *needles)


def test_resume_of_a_checkpoint_that_does_not_match_its_config(workdir: Path, cpu_engine: Any) -> None:
    """Its config is valid, so the engine starts (at this session's settings); the arrays are refused."""
    refused_cleanly(["sim", "--resume", "mismatch.npz", "--no-log"], workdir, "--resume", "does not match")


def test_spawn_without_a_display(workdir: Path, cpu_engine: Any, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    refused_cleanly(["sim", *SMALL, "--set", f"engine.precision={PRECISION}", "--spawn"], workdir,
                    "--spawn", "display")


def test_connect_to_a_bad_url(workdir: Path, cpu_engine: Any) -> None:
    refused_cleanly(["sim", *SMALL, "--set", f"engine.precision={PRECISION}", "--connect", "notaurl"], workdir,
                    "notaurl")


def test_connect_where_no_viewer_answers(workdir: Path, no_engine: None) -> None:
    """Refused before anything starts: Rerun's sink would drop the whole run and say so only at its end. A port
    that accepts connections passes the check."""
    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen()
        check_viewer(f"rerun+http://127.0.0.1:{listening.getsockname()[1]}/proxy")
        with socket.socket() as closed:  # a port nothing listens on
            closed.bind(("127.0.0.1", 0))
            port = closed.getsockname()[1]
    refused_cleanly(["sim", *SMALL, "--connect", f"rerun+http://127.0.0.1:{port}/proxy"], workdir,
                    "--connect", "no Rerun viewer answers", f"127.0.0.1:{port}", "connection refused")


# ----------------------------------------------------------------------------------------------------------
# Hand-written cases: the other commands

OTHER_COMMANDS = [
    (["config", "show", "nosuch"], ["model", "must be one of", "nosuch"]),
    (["config", "show", ""], ["model", "must be one of"]),
    (["config", "show", "vicsek", "adaptive"], ["unexpected extra argument", "adaptive"]),
    (["config", "show", "--bogus"], ["No such option: --bogus"]),
    (["config", "bogus"], ["No such command", "bogus"]),
    (["inspect"], ["Missing argument", "inspect --help"]),
    (["inspect", "missing.rrd"], ["recording not found", "missing.rrd"]),
    (["inspect", "out_dir.rrd"], ["out_dir.rrd is a folder, not a recording"]),
    (["inspect", "empty.rrd"], ["cannot read", "empty.rrd"]),
    (["inspect", "garbage.rrd"], ["cannot read", "garbage.rrd"]),
    (["inspect", "notes.txt"], ["notes.txt"]),
    (["inspect", "mismatch.npz"], ["mismatch.npz"]),
    (["repair"], ["Missing argument", "repair --help"]),
    (["repair", "missing.rrd"], ["recording not found", "missing.rrd"]),
    (["repair", "out_dir.rrd"], ["out_dir.rrd is not a file"]),
    (["repair", "empty.rrd"], ["empty.rrd is empty", "nothing to recover"]),
    (["repair", "garbage.rrd"], ["garbage.rrd is not a Rerun recording"]),
    (["repair", "notes.txt"], ["notes.txt is not a Rerun recording"]),
    (["repair", "garbage.rrd", "--out", "x.txt"], ["--out", ".rrd", "x.txt"]),
    (["view"], ["Missing argument", "view --help"]),
    (["view", "missing.rrd"], ["recording not found", "missing.rrd"]),
    (["view", "out_dir.rrd"], ["out_dir.rrd is a folder, not a recording"]),
    (["view", "missing.rrd", "--port", "abc"], ["--port", "valid integer"]),
    (["view", "--live", "missing.rrd"], ["--live and missing.rrd", "give one of them"]),
    (["view", "--live", "--screenshot", "shot.png"], ["--screenshot needs a recording"]),
    (["bench", "--sizes", "abc"], ["--sizes", "comma-separated numbers", "abc"]),
    (["bench", "--sizes", "0"], ["--sizes", "must be > 0"]),
    (["bench", "--sizes", "-5"], ["--sizes", "must be > 0"]),
    (["bench", "--sizes", ""], ["--sizes", "must be > 0"]),
    (["bench", "--sizes", "1e3,nan"], ["--sizes"]),
    (["bench", "--sizes", "1e3,inf"], ["--sizes"]),
    (["bench", "--sizes", "1e13", "--models", "vicsek"], ["--sizes", "params.n", "<= 2147483647"]),
    (["bench", "--sizes", "2e9", "--models", "potential"], ["--sizes", "params.n", "of memory"]),
    (["bench", "--threads", "-1"], ["--threads", "must be > 0"]),
    (["bench", "--threads", "x"], ["--threads", "comma-separated numbers such as 1,2", "x"]),
    (["bench", "--arch", "bogus"], ["--arch", "bogus"]),
    (["bench", "--precision", "f16"], ["--precision", "f16"]),
    (["bench", "--repeats", "0"], ["--repeats", ">= 1", "got 0"]),
    (["bench", "--repeats", "abc"], ["--repeats", "valid integer"]),
    (["bench", "--develop-steps", "-1"], ["--develop-steps", ">= 0", "got -1"]),
    (["bench", "--models", "nosuch"], ["--models", "vicsek", "nosuch"]),
    (["bench", "--models", "vicsek,nosuch"], ["--models", "nosuch"]),
    (["bench", "--states", "bogus"], ["--states", "uniform, developed", "bogus"]),
    (["bench", "--states", ""], ["--states"]),
    (["bench", "--sizes", "1e3", "--models", "vicsek", "--out", "afile/b"], ["--out", "cannot write", "afile/b"]),
    (["bogus"], ["No such command", "bogus"]),
    (["--bogus"], ["No such option: --bogus"]),
    (["models", "extra"], ["unexpected extra argument", "extra"]),
]


@pytest.mark.parametrize(("args", "needles"), OTHER_COMMANDS, ids=[" ".join(a) for a, _ in OTHER_COMMANDS])
def test_other_commands(workdir: Path, args: list[str], needles: list[str]) -> None:
    refused_cleanly(args, workdir, *needles)


def test_bench_with_an_engine_that_does_not_start(workdir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Known only once a case's process starts its engine, and the same for every case: the engine's one line,
    not a skipped case and an empty table."""
    monkeypatch.setenv("TFLOCK_LANES", "7")
    refused_cleanly(["bench", "--sizes", "1e3", "--models", "vicsek", "--states", "uniform", "--repeats", "1",
                     "--no-peers", "--out", "b"], workdir, "TFLOCK_LANES", "must be 8 or 16")


# ----------------------------------------------------------------------------------------------------------
# Generated cases (hypothesis, derandomized: the same examples on every run)


def _constrained_keys() -> list[tuple[str, str, Any]]:
    """(model, dotted key, pydantic field) of every scalar key of every model's params, engine, log and the top
    level (nested tables included)."""
    out: list[tuple[str, str, Any]] = []

    def walk(model: str, prefix: str, schema: type[BaseModel]) -> None:
        for name, field in schema.model_fields.items():
            annotation = field.annotation
            if isinstance(annotation, type) and issubclass(annotation, BaseModel):
                walk(model, f"{prefix}{name}.", annotation)
            elif name != "model":
                out.append((model, prefix + name, field))

    for model, schema in PARAMS_SCHEMAS.items():
        walk(model, "params.", schema)
    top = {k: v for k, v in Config.model_fields.items() if k != "params"}
    for name, field in top.items():
        annotation = field.annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            walk("vicsek", f"{name}.", annotation)
        elif name != "model":
            out.append(("vicsek", name, field))
    return out


KEYS = _constrained_keys()


def _bounds(field: Any) -> dict[str, float]:
    return {name: getattr(c, name) for c in field.metadata for name in ("gt", "ge", "lt", "le")
            if getattr(c, name, None) is not None}


def _kind(field: Any) -> str:
    """int, float, bool, str or literal (the values a key takes)."""
    annotation = field.annotation
    if get_origin(annotation) is Literal:
        return "literal"
    text = str(annotation)
    for kind in ("bool", "int", "float", "str"):
        if kind in text:
            return kind
    return "other"


def toml_text(value: Any) -> str:
    """`value` as the TOML text of a --set value."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(toml_text(v) for v in value) + "]"
    return str(value)


def _beyond(kind: str, side: str, bound: float) -> st.SearchStrategy[Any]:
    """Numbers on the wrong side of a ``gt``, ``ge``, ``lt`` or ``le`` bound."""
    if kind == "int":
        low = {"lt": bound, "le": bound + 1}.get(side)
        high = {"gt": bound, "ge": bound - 1}.get(side)
        return st.integers(min_value=low, max_value=high)
    upper = side in ("gt", "ge")  # no subnormals: once Taichi runs in this process, the CPU flushes them to zero
    return st.floats(min_value=None if upper else bound, max_value=bound if upper else None, exclude_min=side == "le",
                     exclude_max=side == "ge", allow_nan=False, allow_infinity=False, allow_subnormal=False)


@st.composite
def bad_key_values(draw: st.DrawFn) -> tuple[str, str, Any]:
    """A (model, key, value) that the key's schema must refuse (see :func:`bad_value`)."""
    model, key, field = draw(st.sampled_from(KEYS))
    return model, key, draw(bad_value(key, field))


@st.composite
def bad_value(draw: st.DrawFn, key: str, field: Any) -> Any:
    """A value of `key` that its schema must refuse: of the wrong type, non-finite, non-integral, out of range or
    not among the allowed words."""
    kind = _kind(field)
    words = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=12)
    wrong_type = st.one_of(words, st.lists(st.integers(), max_size=3))
    if kind in ("int", "float"):
        bounds = _bounds(field)
        options = [wrong_type, st.booleans()]
        options.append(st.sampled_from([math.nan, math.inf, -math.inf]).filter(
            lambda v: not (key == "params.alpha" and v == math.inf)))  # alpha = inf is the paper's eq. (6)
        if kind == "int":
            options.append(st.integers(-(10**6), 10**6).map(lambda i: i + 0.5))
        options += [_beyond(kind, side, bound) for side, bound in bounds.items()]
        if key == "params.alpha":
            options = [words.filter(lambda w: w != "inf"), st.floats(max_value=-1e-9), st.just(math.nan)]
        value = draw(st.one_of(options))
    elif kind == "bool":
        value = draw(st.one_of(st.integers(), words, st.floats()))
    elif kind == "literal":
        allowed = set(get_args(field.annotation))
        value = draw(st.one_of(words, st.integers(-10, 10), st.floats()).filter(lambda v: v not in allowed))
    else:  # strings: log.out must name a .rrd; potential's graph_file must be a string
        value = draw(st.one_of(st.integers(), st.booleans(), st.lists(st.integers(), max_size=2)))
    return value


@GENERATED
@given(case=bad_key_values())
def test_generated_bad_values(workdir: Path, no_engine: None, case: tuple[str, str, Any]) -> None:
    model, key, value = case
    line = refused_cleanly(["sim", "--model", model, "--set", f"{key}={toml_text(value)}"], workdir)
    assert key in line


def _pydantic_int(text: str) -> bool:
    try:
        TypeAdapter(int).validate_python(text)
        return True
    except ValueError:
        return False


@GENERATED
@given(option=st.sampled_from(["--steps", "--seed", "--threads", "--checkpoint-every"]),
       text=st.text(max_size=10).filter(lambda t: not _pydantic_int(t) and not t.startswith("-")))
def test_generated_option_garbage(workdir: Path, no_engine: None, option: str, text: str) -> None:
    refused_cleanly(["sim", option, text], workdir, option)


@GENERATED
@given(option=st.sampled_from(["--steps", "--seed", "--threads", "--checkpoint-every"]),
       value=st.integers(max_value=-1))
def test_generated_negative_counts(workdir: Path, no_engine: None, option: str, value: int) -> None:
    key = {"--threads": "engine.threads", "--checkpoint-every": "--checkpoint-every"}.get(option, option[2:])
    refused_cleanly(["sim", option, str(value)], workdir, key)


@GENERATED
@given(expr=st.one_of(
    st.text(max_size=30).filter(lambda t: "=" not in t),  # no key=value at all
    st.builds(lambda k, v: f"params.{k}={v}", st.text(min_size=1, max_size=12), st.text(max_size=20))))
def test_generated_set_expressions(workdir: Path, no_engine: None, expr: str) -> None:
    key = expr.partition("=")[0].strip()
    assume(key.removeprefix("params.").strip() not in PARAMS_SCHEMAS["vicsek"].model_fields)
    refused_cleanly(["sim", "--set", expr], workdir)


def _parses_to_keys(data: bytes) -> bool:
    try:
        return bool(tomllib.loads(data.decode("utf-8")))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return False


@GENERATED
@given(data=st.one_of(st.binary(max_size=300), st.text(max_size=200).map(lambda t: t.encode("utf-8"))))
def test_generated_config_files(tmp_path_factory: pytest.TempPathFactory, no_engine: None, data: bytes) -> None:
    assume(not _parses_to_keys(data))  # garbage: not a TOML table with keys (an empty one is refused too)
    root = tmp_path_factory.mktemp("generated-config")
    (root / "c.toml").write_bytes(data)
    refused_cleanly(["sim", "--config", "c.toml"], root, "c.toml")


@GENERATED
@given(data=st.binary(max_size=500))
def test_generated_checkpoints(tmp_path_factory: pytest.TempPathFactory, no_engine: None, data: bytes) -> None:
    root = tmp_path_factory.mktemp("generated-checkpoint")
    (root / "c.npz").write_bytes(data)
    refused_cleanly(["sim", "--resume", "c.npz"], root, "--resume", "c.npz")


# ----------------------------------------------------------------------------------------------------------
# The memory estimate against the arrays the models really allocate


@pytest.mark.parametrize(("model", "overrides"), [
    ("vicsek", {"params.n": 20_000, "params.box": 100.0}),
    ("vicsek", {"params.n": 20_000, "params.box": 100.0, "params.async_bound": 3}),
    ("adaptive", {"params.n": 20_000, "params.box": 40.0}),
    ("potential", {"params.n": 20_000, "params.box": 200.0}),
    ("formation", {"params.n": 20_000, "params.world": 3000.0, "params.init_length": 1000.0,
                   "params.init_width": 1000.0}),
])
def test_memory_estimate_counts_the_allocated_arrays(engine: Any, model: str, overrides: dict[str, Any]) -> None:
    from tflock.bench import device_bytes
    from tflock.models import model_class
    from tflock.preflight import device_bytes_per_agent

    config = load_config(model=model, overrides={**overrides, "engine.precision": PRECISION})
    built = model_class(model)(config.params, config.seed, engine)
    built.advance(1)  # arrays allocated on first use (the runs of cells of the CPU's lane-wise steps) count too
    measured = device_bytes(built) / config.params.n
    assert 0.75 * measured <= device_bytes_per_agent(config) <= 1.3 * measured


# ----------------------------------------------------------------------------------------------------------
# The real entry point: no traceback reaches a terminal


def run_entry_point(*args: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **(env or {}),
           "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    return subprocess.run([sys.executable, "-m", "tflock", *args], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=120, check=False)


@pytest.mark.parametrize("args", [
    ["sim", "--steps", "abc"],
    ["sim", "--set", "params.noise=nan"],
    ["sim", "--set", "params.n=2000000000", "--set", "params.async_bound=1000"],  # ~50 TB
    ["sim", "--out", "afile/x.rrd"],
    ["sim", "--resume", "fake.npz"],
    ["inspect", "garbage.rrd"],
    ["repair", "garbage.rrd"],
    # beyond the float range of f32: the start state is refused, and NumPy's overflow warnings are not printed
    ["sim", "--model", "vicsek", "--set", "params.box=1e39", "--set", "params.n=100", "--no-log"],
    ["sim", "--model", "adaptive", "--set", "params.box=1e39", "--set", "params.n=100", "--no-log"],
    ["sim", "--model", "potential", "--set", "params.box=1e39", "--set", "params.n=100", "--no-log"],
    ["sim", "--model", "formation", "--set", "params.world=1e39", "--set", "params.n=10", "--no-log"],
], ids=["usage", "nan", "huge-n", "unwritable", "resume", "inspect", "repair", "f32-box-vicsek", "f32-box-adaptive",
        "f32-box-potential", "f32-world-formation"])
def test_entry_point_prints_one_line(workdir: Path, args: list[str]) -> None:
    before = listing(workdir)
    assert_entry_point_refuses(run_entry_point(*args, cwd=workdir))
    assert listing(workdir) == before


def test_bad_lanes_variable_prints_one_line(workdir: Path) -> None:
    before = listing(workdir)
    result = run_entry_point("sim", "--steps", "1", cwd=workdir, env={"TFLOCK_LANES": "12"})
    assert_entry_point_refuses(result)
    assert "TFLOCK_LANES: must be 8 or 16" in result.stderr
    assert listing(workdir) - before <= {"recordings"}  # at most the default output folder, empty (as for engine.arch)


def assert_entry_point_refuses(result: subprocess.CompletedProcess[str]) -> None:
    described = f"exit {result.returncode}\n{result.stdout}\n{result.stderr}"
    assert result.returncode == 2, described
    assert "Traceback" not in result.stdout + result.stderr, described
    assert result.stdout == "" and len(result.stderr.splitlines()) == 1, described
    assert result.stderr.startswith("error: "), described
