"""The documentation: the manual builds with `mkdocs build --strict`, every code block of README.md and docs/ runs
(or says why not; see tests/doc_examples.py), the README is a front page whose test command is CI's, and each model
page's parameter table matches the model's schema."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from typing import Any

import pytest
from doc_examples import REPO, collect, doc_pages

BLOCKS = [block for page in doc_pages() for block in collect(page)[0]]
README = (REPO / "README.md").read_text(encoding="utf-8")


def _env() -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
            "NO_MKDOCS_2_WARNING": "1"}


def test_manual_builds_strict(tmp_path):
    """Broken links and anchors, missing pages and pages left out of the navigation fail the build."""
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=REPO, env=_env(), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert (tmp_path / "site" / "models" / "vicsek" / "index.html").exists()


def test_code_blocks_are_well_formed():
    """Every block has a known language, and every doctest directive is well formed and applies to its block."""
    problems = [p for page in doc_pages() for p in collect(page)[1]]
    assert not problems, "\n".join(problems)


@pytest.fixture(scope="session")
def example_results(tmp_path_factory) -> dict[str, Any]:
    """Every block run once, in one process of its own at the default engine (tests/doc_examples.py)."""
    work = tmp_path_factory.mktemp("doc-examples")
    out = work / "results.json"
    done = subprocess.run([sys.executable, str(REPO / "tests" / "doc_examples.py"), str(work / "pages"), str(out)],
                          cwd=REPO, env=_env(), capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr[-3000:]
    return {**json.loads(out.read_text()), "pages": work / "pages"}


@pytest.mark.parametrize("block", BLOCKS, ids=[b.id for b in BLOCKS])
def test_example_runs(block, example_results):
    result = example_results[block.id]
    assert result["status"] in ("passed", "not-run", "not-code"), f"{block.id}:\n{result['detail']}"
    if result["status"] == "not-run":
        assert len(str(result["detail"]).split()) >= 2, f"{block.id}: say why the block is not run"


def test_bench_writes_under_results_by_default(example_results):
    """The README's `tflock bench` (no --out) wrote its results under results/bench/ in its working directory."""
    written = list((example_results["pages"] / "README").glob("results/bench/bench-*.json"))
    assert len(written) == 1, written


def test_readme_is_a_front_page():
    """At most ~150 lines, opening with the two commands that work on a fresh machine; the second is what CI runs."""
    assert README.count("\n") <= 150
    first = BLOCKS[0]
    assert first.path == "README.md" and first.lang == "bash"
    lines = [ln.split("#")[0].strip() for ln in first.text.strip().splitlines()]
    assert lines == ["pip install -e . && tflock sim", "pip install -e '.[test]' && pytest"]
    assert lines[1] in (REPO / ".ci" / "run").read_text(encoding="utf-8")
    for topic in ("tflock sim --config configs/papers/", "tflock view", "tflock sweep configs/sweeps/vicsek-noise.toml",
                  "tflock reproduce", "tflock bench"):
        assert topic in README, topic


def test_readme_links_exist():
    """Relative links and images of the README point at files of the repository."""
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README)
    local = [t for t in targets if not re.match(r"[a-z]+:", t)]
    assert local
    missing = [t for t in local if not (REPO / t).exists()]
    assert not missing, missing


def _schema_keys(schema, prefix: str = "") -> dict[str, object]:
    from pydantic import BaseModel

    keys: dict[str, object] = {}
    for name, info in schema.model_fields.items():
        if isinstance(info.annotation, type) and issubclass(info.annotation, BaseModel):
            keys.update(_schema_keys(info.annotation, f"{prefix}{name}."))
        else:
            keys[prefix + name] = info.default
    return keys


@pytest.mark.parametrize("model", ["vicsek", "adaptive", "potential", "formation"])
def test_parameter_table_matches_the_schema(model):
    """The model page lists every key of [params] with the schema's default (and no key the schema lacks)."""
    from tflock.config import PARAMS_SCHEMAS, load_config

    load_config(model=model)  # registers the model's schema
    text = (REPO / "docs" / "models" / f"{model}.md").read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\| `([a-z_0-9.]+)` \|.*\| (`[^`]*`|unset) \|$", text, re.M))
    expected = _schema_keys(PARAMS_SCHEMAS[model])
    assert set(rows) == set(expected)
    for key, default in expected.items():
        shown = rows[key]
        if default is None:
            assert shown == "unset", key
        else:
            value = shown.strip("`")
            parsed = value.strip('"') if value.startswith('"') else json.loads(value)
            assert parsed == default, f"{key}: the page says {value}, the schema {default!r}"
