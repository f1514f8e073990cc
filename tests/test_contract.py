"""The contract of `tflock sim`, on configs and command lines generated from the schema, valid and invalid (hypothesis,
derandomized, so CI sees the same examples every run):

* exit 0: a recording that `rerun rrd verify` accepts, with a frame at every `log.every`-th step and the last, and a
  metrics table with a row at every `log.metrics_every`-th step and the last (or no file at all with --no-log);
  stderr holds nothing but tflock's one-line warnings (tflock/advice.py);
* exit 2, refused: exactly one `error: ...` line and no file written;
* exit 2, a numerical fault: one line, a verified recording up to the last good step and its checkpoint;
* never a traceback, never a Python warning.

Runs are in-process, tiny (at most 40 agents, 4 steps) and at this test session's engine settings.
"""

import re
from pathlib import Path
from typing import Any, get_args

import pytest
from conftest import PRECISION, invoke_in
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from test_bad_input import KEYS, _bounds, _kind, bad_value, toml_text

from tflock.config import ConfigError, load_config
from tflock.record import read_recording, verify_recording

CONTRACT = settings(max_examples=30, deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
#: the keys a generated run may set to a valid value: the engine is this session's, outputs come from options
SETTABLE = [(model, key, field) for model, key, field in KEYS if not key.startswith("engine.") and key != "log.out"
            and key != "params.graph_file"]
#: valid values of these keys stay small, so that every run is quick
SMALL_INTS = {"params.n": (1, 40), "steps": (0, 4)}


def good_value(key: str, field: Any) -> st.SearchStrategy[Any]:
    """A value the key's own constraints accept (cross-key rules may still refuse it)."""
    kind = _kind(field)
    if kind == "literal":
        return st.sampled_from(get_args(field.annotation))
    if kind == "bool":
        return st.booleans()
    bounds = _bounds(field)
    if kind == "int":
        low = bounds.get("ge", bounds.get("gt", -1) + 1)
        low = max(low, 0) if "ge" in bounds or "gt" in bounds else 0
        high = bounds.get("le", bounds.get("lt", low + 21) - 1)
        low, high = SMALL_INTS.get(key, (low, min(high, low + 20)))
        return st.integers(low, high)
    low = bounds.get("ge", bounds.get("gt", 0.0))
    high = bounds.get("le", bounds.get("lt", low + 50.0))
    return st.floats(low, high, exclude_min="gt" in bounds, exclude_max="lt" in bounds, allow_nan=False,
                     allow_subnormal=False)


@st.composite
def runs(draw: st.DrawFn) -> tuple[str, dict[str, Any], list[str]]:
    """A model, its --set keys and values, and the other options of a `tflock sim` command line."""
    model = draw(st.sampled_from(sorted({m for m, _, _ in SETTABLE})))
    own = [(key, field) for m, key, field in SETTABLE if m == model]
    chosen: dict[str, Any] = {"params.n": draw(st.integers(1, 40)), "steps": draw(st.integers(0, 4))}
    for key, field in draw(st.lists(st.sampled_from(own), max_size=3, unique_by=lambda kf: kf[0])):
        chosen[key] = draw(good_value(key, field))
    if draw(st.integers(0, 3)) == 0:  # one run in four has a key with a value its schema refuses
        _, key, field = draw(st.sampled_from([case for case in KEYS if case[0] == model]))
        chosen[key] = draw(bad_value(key, field))
    options = draw(st.sampled_from([[], ["--no-log"], ["--out", "run.rrd"], ["--out", "run.txt"],
                                    ["--checkpoint-every", "2", "--out", "run.rrd"], ["--checkpoint-every", "-1"]]))
    return model, chosen, options


def files_in(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()}


def due(steps: int, every: int) -> list[int]:
    return sorted({0, steps} | set(range(0, steps + 1, every)))


@CONTRACT
@given(run=runs())
def test_every_run_keeps_the_contract(cpu_engine: Any, tmp_path_factory: pytest.TempPathFactory,
                                      run: tuple[str, dict[str, Any], list[str]]) -> None:
    model, chosen, options = run
    folder = tmp_path_factory.mktemp("contract")
    sets = [arg for key, value in chosen.items() for arg in ("--set", f"{key}={toml_text(value)}")]
    result = invoke_in(folder, ["sim", "--model", model, *sets, "--set", f"engine.precision={PRECISION}", *options])
    output = result.stdout + result.stderr
    described = f"exit {result.exit_code} {result.exception!r}\n{output}"
    assert result.exit_code in (0, 2) and "Traceback" not in output, described
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert not [line for line in lines if re.match(r"warning: \w+Warning: ", line)], described  # Python's
    written = files_in(folder)
    event(f"exit {result.exit_code}" + (" fault" if "numerical fault" in output else "") + (" warned" if any(
        line.startswith("warning: ") for line in lines) else ""))

    if result.exit_code == 2:
        assert len(lines) == 1 and lines[0].startswith("error: ") and result.stdout == "", described
        if not lines[0].startswith("error: numerical fault"):
            assert written == set(), described
            return
        recording = next(folder.rglob("*.rrd"), None)
        assert recording is None or verify_recording(recording), described
        assert any(name.endswith(".lastgood.npz") or name.endswith(".checkpoint.npz") for name in written), described
        return

    assert all(line.startswith("warning: ") for line in lines), described
    try:
        config = load_config(model=model, overrides={**chosen, "engine.precision": PRECISION})
    except ConfigError:
        pytest.fail(f"exit 0 on a config that does not load\n{described}")
    if "--no-log" in options:
        assert written == set(), described
        return
    recording = folder / "run.rrd" if "--out" in options else next((folder / "recordings").glob("*.rrd"))
    assert verify_recording(recording), described
    assert read_recording(recording).steps == due(config.steps, config.log.every), described
    table = recording.with_suffix(".metrics.csv").read_text(encoding="utf-8").splitlines()
    assert [int(row.split(",", 1)[0]) for row in table[1:]] == due(config.steps, config.log.metrics_every)
    expected = {recording.name, recording.with_suffix(".metrics.csv").name}
    if "--checkpoint-every" in options and config.steps >= 2:
        expected.add(recording.with_suffix(".checkpoint.npz").name)
    assert {Path(name).name for name in written} == expected, described
