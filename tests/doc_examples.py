"""The code blocks of README.md and docs/: collected here, and run by this file as a script.

Every fenced block has a language: ``bash`` and ``python`` blocks are run, ``toml`` blocks are parsed (and
validated as a config or a sweep file where marked), ``text`` blocks (output, equations) are not code. A block may
be preceded by HTML comments, invisible on the rendered page, that say how it runs:

- ``<!-- doctest: not-run REASON -->``: the block is not run, for that reason;
- ``<!-- doctest: sim-args ARGS -->``: ARGS are appended to each ``tflock sim`` of the block (small sizes, few steps);
- ``<!-- doctest: replace "OLD" -> "NEW" -->``: a text substitution before the block runs (OLD must occur);
- ``<!-- doctest: config -->`` / ``<!-- doctest: sweep -->``: a TOML block is checked as a run config / a sweep file.

``python tests/doc_examples.py WORKDIR RESULTS.json`` runs every block in one Python process, at the default
engine (cpu, f32), each page's blocks in order in a folder of its own under WORKDIR that holds a link to the
repository's ``configs/`` (so a page can make a recording and then inspect it). ``tflock`` commands run in this
process through the CLI (``bench`` runs each case in a process of its own), except ``reproduce NAME`` and sweeps
on workers, which start engines of their own and run as ``python -m tflock``. ``pip install`` and ``pytest``
lines are not run: the tests run in the installed package, and CI runs exactly these two commands on a fresh
machine (.ci/run). Any other command must be in a not-run block.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shlex
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

from markdown_it import MarkdownIt

REPO = Path(__file__).resolve().parents[1]
LANGUAGES = ("bash", "python", "toml", "text")
DIRECTIVE = re.compile(r"<!--\s*doctest:\s*(.*?)\s*-->", re.S)
REPLACE = re.compile(r'^replace\s+"(.*)"\s*->\s*"(.*)"$', re.S)
OWN_PROCESS = ("reproduce",)  # it starts engines (and processes) of its own; bench runs each case in a process
NOT_RUN_BY_RULE = {"pip": "installs packages (CI installs on a fresh machine)", "pytest": "the test suite itself"}


@dataclass
class Block:
    """One fenced code block of a Markdown page, with its doctest directives."""

    path: str  # relative to the repository
    line: int  # 1-based line of the opening fence
    lang: str
    text: str
    not_run: str | None = None
    sim_args: list[str] = field(default_factory=list)
    replacements: list[tuple[str, str]] = field(default_factory=list)
    check: str | None = None  # "config" | "sweep" for TOML blocks

    @property
    def id(self) -> str:
        return f"{self.path}:{self.line}"

    def source(self) -> str:
        """The block's text with its replacements applied."""
        text = self.text
        for old, new in self.replacements:
            text = text.replace(old, new)
        return text


def doc_pages() -> list[Path]:
    """README.md and every page of docs/."""
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def collect(page: Path) -> tuple[list[Block], list[str]]:
    """The page's code blocks, and the problems found: a block without a known language, an indented code block,
    a malformed or stale directive, a directive that does not precede a block."""
    rel = page.relative_to(REPO).as_posix()
    tokens = MarkdownIt("commonmark").parse(page.read_text(encoding="utf-8"))
    blocks: list[Block] = []
    problems: list[str] = []
    pending: list[tuple[str, int]] = []
    for token in tokens:
        line = token.map[0] + 1 if token.map else 0
        if token.type == "html_block" and DIRECTIVE.search(token.content):
            pending += [(d, line) for d in DIRECTIVE.findall(token.content)]
            continue
        if token.type == "code_block":
            problems.append(f"{rel}:{line}: an indented code block; use a fenced block with a language")
        if token.type != "fence":
            if pending and token.type not in ("html_block",):
                problems.append(f"{rel}:{pending[0][1]}: doctest directive not followed by a code block")
                pending = []
            continue
        lang = token.info.split()[0] if token.info.strip() else ""
        block = Block(rel, line, lang, token.content)
        if lang not in LANGUAGES:
            problems.append(f"{rel}:{line}: code block language {lang!r}; use one of {', '.join(LANGUAGES)}")
        for directive, where in pending:
            problems += [f"{rel}:{where}: {p}" for p in _apply(block, directive)]
        pending = []
        if block.lang == "text":
            problems += [f"{block.id}: a command in a text block: {ln!r}" for ln in block.text.splitlines()
                         if ln.lstrip().startswith(("tflock ", "$ ", "python "))]
        blocks.append(block)
    if pending:
        problems.append(f"{rel}:{pending[0][1]}: doctest directive not followed by a code block")
    return blocks, problems


def _apply(block: Block, directive: str) -> list[str]:
    """Attach one directive to its block; returns the problems with it."""
    kind, _, rest = directive.partition(" ")
    rest = rest.strip()
    if kind == "not-run":
        if not rest:
            return ["not-run needs a reason"]
        block.not_run = rest
    elif kind == "sim-args":
        if not rest or block.lang != "bash":
            return ["sim-args needs arguments and a bash block"]
        block.sim_args += shlex.split(rest)
    elif kind == "replace":
        match = REPLACE.match(directive)
        if not match:
            return [f'replace must read: replace "OLD" -> "NEW", got {directive!r}']
        old, new = match.groups()
        if old not in block.text:
            return [f"replace: {old!r} does not occur in the block"]
        block.replacements.append((old, new))
    elif kind in ("config", "sweep"):
        if block.lang != "toml":
            return [f"{kind} applies to a toml block"]
        block.check = kind
    else:
        return [f"unknown doctest directive {directive!r}"]
    return []


def commands(text: str) -> list[list[str]]:
    """A bash block's commands: continuation lines joined, comments dropped, ``&&`` chains split."""
    joined = re.sub(r"\\\n", " ", text)
    out: list[list[str]] = []
    for line in joined.splitlines():
        words = shlex.split(line, comments=True)
        while words:
            cut = words.index("&&") if "&&" in words else len(words)
            out.append(words[:cut])
            words = words[cut + 1:]
    return [c for c in out if c]


# ---------------------------------------------------------------------------------------------------------------
# Running (in the script's own process)


class ExampleError(Exception):
    pass


def _run_tflock(words: list[str], block: Block, cwd: Path) -> str:
    args = words[1:]
    redirect = None
    if ">" in args:
        at = args.index(">")
        args, redirect = args[:at], args[at + 1]
    if not args or args[0] == "view":
        raise ExampleError(f"`{shlex.join(words)}` cannot run in a test (a viewer); mark the block not-run")
    if args[0] == "sim":
        args = [*args, *block.sim_args]
    own = args[0] in OWN_PROCESS and "--list" not in args or {"--workers", "--scheduler"} & set(args)
    if own:
        done = subprocess.run([sys.executable, "-m", "tflock", *args], cwd=cwd, capture_output=True, text=True,
                              stdin=subprocess.DEVNULL, timeout=600, check=False)
        code, output = done.returncode, done.stdout + done.stderr
        stdout = done.stdout
    else:
        from typer.testing import CliRunner

        from tflock.cli import app

        old = os.getcwd()
        os.chdir(cwd)
        try:
            result = CliRunner().invoke(app, args)
        finally:
            os.chdir(old)
        code, stdout = result.exit_code, result.stdout
        output = result.stdout + result.stderr
        if result.exception is not None and not isinstance(result.exception, SystemExit):
            output += "".join(traceback.format_exception(result.exception))
    if code != 0:
        raise ExampleError(f"`tflock {shlex.join(args)}` exited {code}:\n{output[-3000:]}")
    if redirect:
        (cwd / redirect).write_text(stdout, encoding="utf-8")
    return f"tflock {shlex.join(args)}"


def run_block(block: Block, cwd: Path) -> str:
    """Run one block in `cwd`; returns what was run, raises ExampleError (or the example's own exception)."""
    source = block.source()
    if block.lang == "bash":
        ran = []
        for words in commands(source):
            if words[0] in NOT_RUN_BY_RULE:
                ran.append(f"not run: {shlex.join(words)} ({NOT_RUN_BY_RULE[words[0]]})")
            elif words[0] == "tflock":
                ran.append(_run_tflock(words, block, cwd))
            else:
                raise ExampleError(f"`{shlex.join(words)}`: only tflock, pip and pytest commands run here; "
                                    "mark the block not-run with a reason")
        return "\n".join(ran)
    if block.lang == "python":
        old = os.getcwd()
        os.chdir(cwd)
        try:
            with contextlib.redirect_stdout(io.StringIO()):
                exec(compile(source, block.id, "exec"), {"__name__": "__doc_example__"})
        finally:
            os.chdir(old)
        return "python"
    if block.lang == "toml":
        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib
        data = tomllib.loads(source)
        if block.check == "config":
            from tflock.config import load_config

            load_config(data)
        elif block.check == "sweep":
            from tflock.sweep import load_sweep

            load_sweep(data)
        return f"toml{' (' + block.check + ')' if block.check else ''}"
    return "text"


def run_all(workdir: Path) -> dict[str, dict[str, object]]:
    """Every block of every page; the result of each by its id."""
    results: dict[str, dict[str, object]] = {}
    for page in doc_pages():
        cwd = workdir / page.relative_to(REPO).as_posix().replace("/", "_").removesuffix(".md")
        cwd.mkdir(parents=True, exist_ok=True)
        (cwd / "configs").symlink_to(REPO / "configs")
        for block in collect(page)[0]:
            t0 = time.perf_counter()
            if block.not_run:
                outcome = {"status": "not-run", "detail": block.not_run}
            elif block.lang == "text":
                outcome = {"status": "not-code", "detail": ""}
            else:
                try:
                    outcome = {"status": "passed", "detail": run_block(block, cwd)}
                except Exception as e:  # the example's own failure, reported with its block
                    detail = str(e) if isinstance(e, ExampleError) else traceback.format_exc()[-3000:]
                    outcome = {"status": "failed", "detail": detail}
            outcome["seconds"] = round(time.perf_counter() - t0, 2)
            results[block.id] = outcome
    return results


if __name__ == "__main__":
    work, out = Path(sys.argv[1]), Path(sys.argv[2])
    Path(out).write_text(json.dumps(run_all(work), indent=1), encoding="utf-8")
