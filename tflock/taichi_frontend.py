"""A start-up shortcut for Taichi 1.7's Python front end: its source-position messages, computed once.

While Taichi turns a kernel's Python AST into its IR, it formats, for every statement, loop and call it visits, a
message that points at the source (``File ..., line ..., in f:`` then the line and a row of carets, each wrapped to
80 columns by ``textwrap.TextWrapper``); the message is kept for error reports and debug-mode assertions. A
``ti.static`` loop visits its body once per unrolled pass and a ``ti.func`` is visited at every call, so the same
messages are formatted again and again, a large share of the front end's time before the first step. The message
depends only on where the node lies in its source, so :func:`memoize_position_messages` caches it under everything
the original reads: the file, the function and its offset and indent, the node's kind and span, and the source
lines it quotes. The messages are the same strings Taichi formats itself.
"""

from __future__ import annotations

import ast
from collections.abc import Callable
from typing import Any

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
