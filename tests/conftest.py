"""Shared test setup: one Taichi initialisation per test process.

In-process tests run at the precision named by TFLOCK_TEST_PRECISION (f64 by default, so oracle comparisons can
run long horizons) and on the arch named by TFLOCK_TEST_ARCH (cpu by default; cuda or vulkan run the in-process
tests on a GPU); `test_precision.py` reruns the oracle tests in a subprocess at f32. Anything that needs other
engine settings (thread counts, the CLI) runs in a subprocess.
"""

import os
import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

PRECISION = os.environ.get("TFLOCK_TEST_PRECISION", "f64")
ARCH = os.environ.get("TFLOCK_TEST_ARCH", "cpu")  # cuda / vulkan: the in-process tests on a GPU


@pytest.fixture(scope="session")
def engine():
    from tflock.engine import init_engine

    return init_engine(ARCH, 0, PRECISION)


@pytest.fixture(scope="session")
def cpu_engine(engine):
    """The engine, for tests that run tflock's default engine (cpu) in this process: through the CLI, a sweep or
    the README's example. Such tests carry a skip mark when this process runs another arch (TFLOCK_TEST_ARCH; see
    :func:`pytest_collection_modifyitems`)."""
    return engine


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the tests that use ``cpu_engine`` to be skipped when this process runs another arch than the cpu: a
    mark set at collection, which the report shows, rather than a skip found once the fixture runs."""
    if ARCH == "cpu":
        return
    mark = pytest.mark.skip(reason=f"runs tflock's default engine (cpu) in this process, which runs {ARCH}")
    for item in items:
        if "cpu_engine" in getattr(item, "fixturenames", ()):
            item.add_marker(mark)


@pytest.fixture
def make_sim(engine):
    """Simulation factory at the session's precision and arch, recording off unless asked."""
    from tflock import Simulation

    def make(**kwargs):
        kwargs.setdefault("engine", {})["precision"] = PRECISION
        kwargs["engine"]["arch"] = ARCH
        return Simulation(**kwargs)

    return make


@pytest.fixture(scope="session")
def reproduce_quick():
    """``run(name, out)``: ``tflock reproduce NAME --quick --out OUT`` in a subprocess (reproductions run at the
    default f32 engine; this process's Taichi is f64), failing the test with its stderr unless it exits 0."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo), os.environ.get("PYTHONPATH", "")])}

    def run(name: str, out: Path) -> Path:
        done = subprocess.run([sys.executable, "-m", "tflock", "reproduce", name, "--quick", "--out", str(out)],
                              capture_output=True, text=True, env=env, timeout=600)
        assert done.returncode == 0, done.stderr[-3000:]
        return out

    return run


@pytest.fixture(autouse=True)
def _restore_signal_handlers() -> Iterator[None]:
    """`tflock sim` run in-process installs SIGINT / SIGTERM handlers for its run; give pytest its own back."""
    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    yield
    for sig, handler in saved.items():
        signal.signal(sig, handler)


def invoke_in(cwd: Path, args: list[str]) -> Any:
    """`tflock ARGS` in-process (typer's CliRunner) with `cwd` as the current directory."""
    from tflock.cli import app

    old = os.getcwd()
    os.chdir(cwd)
    try:
        return CliRunner().invoke(app, args)
    finally:
        os.chdir(old)


def assert_one_error_line(result: Any, *needles: str) -> str:
    """Exit code 2 and exactly one non-empty line, ``error: ...`` with every needle, and no traceback."""
    output = result.stdout + result.stderr
    described = f"exit {result.exit_code}, exception {result.exception!r}\n{output}"
    assert result.exit_code == 2, described
    assert result.exception is None or isinstance(result.exception, SystemExit), described
    assert "Traceback" not in output, described
    lines = output.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and len(lines[0]) > len("error: "), described
    for needle in needles:
        assert needle in lines[0], f"{needle!r} not in {lines[0]!r}"
    return lines[0]


def tflock_process(cwd: Path, *args: str) -> Any:
    """`python -m tflock ARGS` started in `cwd` (stdout and stderr to files there), with this checkout first on
    the path."""
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(repo), os.environ.get("PYTHONPATH")]))}
    with open(cwd / "stdout.txt", "w") as stdout, open(cwd / "stderr.txt", "w") as stderr:
        return subprocess.Popen([sys.executable, "-m", "tflock", *args], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                                stdout=stdout, stderr=stderr)


def wait_for_rows(proc: Any, table: Path, rows: int, timeout: float = 120.0) -> None:
    """Wait until a running `tflock sim` has written `rows` rows to its metrics table (its step loop runs)."""
    import time

    deadline = time.monotonic() + timeout
    while not (table.is_file() and table.read_text(encoding="utf-8").count("\n") > rows):
        assert proc.poll() is None, f"sim exited early with {proc.returncode}"
        assert time.monotonic() < deadline, f"{table} did not reach {rows} rows within {timeout} s"
        time.sleep(0.05)


def assert_same_run(a: Any, b: Any) -> None:
    """Two Simulations hold the same state and the same metrics table, bit for bit (nan where both have nan)."""
    import numpy as np

    sa, sb = a.state(), b.state()
    for key in sa:
        assert np.array_equal(sa[key], sb[key]), key
    ma, mb = a.metrics(), b.metrics()
    assert list(ma) == list(mb)
    for key in ma:
        assert np.array_equal(ma[key], mb[key], equal_nan=True), key
