"""Patterns in the kernels' source that compile and run on the CPU but fail on a GPU arch, checked here, where CI
has no GPU.

A value that a kernel sets at its top level and a later top-level loop reads crosses from one offloaded task to
another, so Taichi 1.7 keeps it in a global temporary. It lays those out without aligning them to their element
size: in ``_velocity_stats`` a vector of float64 sat at byte 4, after an int32, and every launch on an H100 stopped
with CUDA_ERROR_MISALIGNED_ADDRESS (2026-11-27). Values made inside the loop stay in registers instead.
"""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "tflock"


def _is_kernel(node: ast.FunctionDef) -> bool:
    return any(ast.unparse(d) in ("ti.kernel", "kernel") for d in node.decorator_list)


def _is_static(value: ast.expr) -> bool:
    """``ti.static(...)``: a compile-time value, which no task keeps."""
    return isinstance(value, ast.Call) and ast.unparse(value.func) == "ti.static"


def _top_level_values_before_loops(source: str) -> list[str]:
    """'kernel: name' for each name a kernel assigns at its top level (not at compile time) before a top-level
    loop."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not (isinstance(node, ast.FunctionDef) and _is_kernel(node)):
            continue
        loops = [i for i, s in enumerate(node.body) if isinstance(s, (ast.For, ast.While))]
        for statement in node.body[: loops[-1]] if loops else []:
            if isinstance(statement, (ast.Assign, ast.AnnAssign, ast.AugAssign)) and not _is_static(statement.value):
                targets = statement.targets if isinstance(statement, ast.Assign) else [statement.target]
                found += [f"{node.name}: {ast.unparse(t)}" for t in targets if not isinstance(t, ast.Subscript)]
    return found


def test_the_check_finds_the_pattern_that_failed_on_the_h100() -> None:
    failed = '''
@ti.kernel
def k(n: ti.i32, out: ti.types.ndarray()):
    """doc"""
    ti.loop_config(serialize=True)
    width = ti.static(8)
    out[0] = 0
    zeros = ti.Vector([0.0] * width, dt=ti.f64)
    for t in range(n):
        out[t] = zeros.sum()
'''
    assert _top_level_values_before_loops(failed) == ["k: zeros"]
    fixed = failed.replace("    zeros = ti.Vector([0.0] * width, dt=ti.f64)\n    for t in range(n):\n",
                           "    for t in range(n):\n        zeros = ti.Vector([0.0] * width, dt=ti.f64)\n")
    assert fixed != failed and _top_level_values_before_loops(fixed) == []


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_kernel_sets_a_value_for_a_later_top_level_loop(path: Path) -> None:
    assert _top_level_values_before_loops(path.read_text()) == []
