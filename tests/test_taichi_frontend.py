"""The memoized source-position messages of Taichi's front end (tflock.taichi_frontend) are the messages Taichi
formats itself, and compile errors still point at the right line of the right function; the decorators' class
check answers as Taichi's own."""

import importlib.util
import sys

import numpy as np
import pytest
import taichi as ti
from taichi.lang import kernel_impl
from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext

from tflock import taichi_frontend
from tflock.taichi_frontend import memoize_position_messages


@ti.func
def _shifted(x, k: ti.template()):
    y = x
    for _ in ti.static(range(k)):
        y = y + 1.0
    return y


@ti.kernel
def _unrolled(a: ti.types.ndarray(), k: ti.template()):
    for i in range(a.shape[0]):
        for j in ti.static(range(3)):
            if a[i] > j:
                a[i] = _shifted(a[i], k)


@ti.kernel
def _broken_one(a: ti.types.ndarray()):
    for i in range(a.shape[0]):
        a[i] = undefined_one  # noqa: F821


@ti.kernel
def _broken_two(a: ti.types.ndarray()):
    for i in range(a.shape[0]):
        a[i] = undefined_two  # noqa: F821


def test_memoized_messages_equal_taichi_own(engine, monkeypatch):
    memoized = ASTTransformerContext.get_pos_info
    assert hasattr(memoized, "original"), "installed when tflock.engine is imported"
    memoize_position_messages()  # idempotent: no second layer
    assert ASTTransformerContext.get_pos_info is memoized
    compared = []

    def checked(self, node):
        message = memoized(self, node)
        assert message == memoized.original(self, node)
        compared.append(message)
        return message

    monkeypatch.setattr(ASTTransformerContext, "get_pos_info", checked)
    a = ti.ndarray(ti.f32, 4)
    for k in (1, 2):  # two instantiations: the second reads the cache for most nodes
        _unrolled(a, k)
    assert len(compared) > len(set(compared)) > 10  # many messages, most met more than once
    assert any("in _shifted:" in m for m in compared) and any("in _unrolled:" in m for m in compared)


@pytest.mark.parametrize("kernel, name", [(_broken_one, "undefined_one"), (_broken_two, "undefined_two")])
def test_compile_errors_name_their_own_line(engine, kernel, name):
    with pytest.raises(ti.TaichiCompilationError) as caught:
        kernel(ti.ndarray(ti.f32, 2))
    text = str(caught.value)
    assert f"in {kernel.__name__}:" in text and f"a[i] = {name}" in text


DECORATED = '''
import taichi as ti


@ti.func
def plus_one(x):
    return x + 1


@ti.kernel
def fill(a: ti.types.ndarray(), value: ti.i32):
    for i in range(a.shape[0]):
        a[i] = plus_one(value)


class Plain:
    scale = 2


@ti.data_oriented
class Filled:
    def __init__(self):
        self.values = ti.ndarray(ti.i32, 3)

    @ti.kernel
    def fill(self, a: ti.types.ndarray(), value: ti.i32):
        for i in range(a.shape[0]):
            a[i] = value + self.offset()

    @ti.func
    def offset(self):
        return 1
'''


def test_the_class_check_answers_as_taichis_own(engine, monkeypatch, tmp_path):
    """Every decorator of a module (kernels and funcs at module level and in a data-oriented class) gets the same
    answer from the linecache check as from Taichi's inspect-based one (asked at the same stack depth), and the
    module's kernels run. The module is a file of its own: re-importing tflock's modules would leave two copies."""
    assert kernel_impl._inside_class is taichi_frontend._inside_class, "installed when tflock.engine is imported"
    answers = []

    def both(level_of_class_stackframe):
        level = level_of_class_stackframe + 1  # one frame deeper here
        ours, taichis = taichi_frontend._inside_class(level), _taichis_inside_class(level)
        answers.append((ours, taichis))
        return ours

    monkeypatch.setattr(kernel_impl, "_inside_class", both)
    path = tmp_path / "decorated_for_the_class_check.py"
    path.write_text(DECORATED)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)

    assert answers == [(False, False), (False, False), (True, True), (True, True)]
    a = ti.ndarray(ti.i32, 3)
    module.fill(a, 4)
    assert np.array_equal(a.to_numpy(), [5, 5, 5])
    filled = module.Filled()
    filled.fill(filled.values, 4)
    assert np.array_equal(filled.values.to_numpy(), [5, 5, 5])


def _taichis_inside_class(level_of_class_stackframe):
    """Taichi 1.7's kernel_impl._inside_class (copied: the module's own name now points at ours)."""
    import inspect

    try:
        maybe_class_frame = sys._getframe(level_of_class_stackframe)
        statement_list = inspect.getframeinfo(maybe_class_frame)[3]
        first_statment = statement_list[0].strip()
        for pat in kernel_impl._KERNEL_CLASS_STACKFRAME_STMT_RES:
            if pat.match(first_statment):
                return True
    except Exception:
        pass
    return False
