"""The memoized source-position messages of Taichi's front end (tflock.taichi_frontend) are the messages Taichi
formats itself, and compile errors still point at the right line of the right function."""

import pytest
import taichi as ti
from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext

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
