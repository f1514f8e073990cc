"""A start-up shortcut for Taichi 1.7's Python front end: its source-position messages, computed once.

While Taichi turns a kernel's Python AST into its IR, it formats, for every statement, loop and call it visits, a
message that points at the source (``File ..., line ..., in f:`` then the line and a row of carets, each wrapped to
80 columns by ``textwrap.TextWrapper``); the message is kept for error reports and debug-mode assertions. A
``ti.static`` loop visits its body once per unrolled pass and a ``ti.func`` is visited at every call, so the same
messages are formatted again and again, a large share of the front end's time before the first step. The message
depends only on where the node lies in its source, so :func:`memoize_position_messages` caches it under everything
the original reads: the file, the function and its offset and indent, the node's kind and span, and the source
lines it quotes. The messages are the same strings Taichi formats itself.

Before that, at import, every ``@ti.kernel`` and ``@ti.func`` asks whether it is being defined in a class body
(``kernel_impl._inside_class``): Taichi reads the source line of a frame up the stack through
``inspect.getframeinfo``, whose search for the frame's module (``inspect.getmodule``, a walk over every loaded
module) takes milliseconds a decorator; tflock has a few hundred. :func:`fast_class_check` reads the same line
through ``linecache`` (as ``getframeinfo`` does once it has the module) and matches Taichi's own patterns.
"""

from __future__ import annotations

import ast
import linecache
import sys
from collections.abc import Callable
from typing import Any

from taichi.lang import kernel_impl
from taichi.lang.ast import ast_transformer_utils

_Context = ast_transformer_utils.ASTTransformerContext


def _key(ctx: Any, node: ast.AST) -> tuple:
    """What :meth:`ASTTransformerContext.get_pos_info` reads from the context and the node."""
    lineno, end_lineno = node.lineno, node.end_lineno  # type: ignore[attr-defined]
    body = getattr(node, "body", None)
    first_body_line = body[0].lineno if isinstance(body, list) and body else None
    return (ctx.file, ctx.lineno_offset, ctx.indent, ctx.func.func.__name__, type(node).__name__, lineno,
            end_lineno, node.col_offset, node.end_col_offset, first_body_line,  # type: ignore[attr-defined]
            tuple(ctx.src[lineno - 1:end_lineno]))


def _memoized(original: Callable[[Any, ast.AST], str]) -> Callable[[Any, ast.AST], str]:
    cache: dict[tuple, str] = {}

    def get_pos_info(self: Any, node: ast.AST) -> str:
        key = _key(self, node)
        message = cache.get(key)
        if message is None:
            message = cache[key] = original(self, node)
        return message

    get_pos_info.original = original  # type: ignore[attr-defined]
    return get_pos_info


def memoize_position_messages() -> None:
    """Make Taichi's front end format each source-position message once per process (idempotent)."""
    original = getattr(_Context, "get_pos_info", None)
    if original is None or hasattr(original, "original"):
        return
    _Context.get_pos_info = _memoized(original)


def _inside_class(level_of_class_stackframe: int) -> bool:
    """Taichi's ``kernel_impl._inside_class``: whether the source line that the frame `level_of_class_stackframe`
    levels up executes opens a class (``class ...`` or a ``@data_oriented`` decorator), read through linecache."""
    try:
        frame = sys._getframe(level_of_class_stackframe)  # counted from here, as in the function it replaces
    except ValueError:  # the stack is not that deep
        return False
    line = linecache.getline(frame.f_code.co_filename, frame.f_lineno, frame.f_globals).strip()
    return any(pattern.match(line) for pattern in kernel_impl._KERNEL_CLASS_STACKFRAME_STMT_RES)


def fast_class_check() -> None:
    """Make Taichi's kernel and func decorators find their class context without inspect's module search
    (idempotent; for the decorators that run after it)."""
    if kernel_impl._inside_class is not _inside_class:
        kernel_impl._inside_class = _inside_class
