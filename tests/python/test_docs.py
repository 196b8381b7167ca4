"""Every Python snippet in README.md and docs/*.md runs as written.

The blocks of one file run in order in one namespace (a page builds on its earlier blocks), with
the repository root as the working directory. Blocks that import bpy run in the Blender suite
(tests/blender/test_docs.py) instead, and so do blocks that import addon_utils, bmesh or
mathutils. A block preceded by a line ``<!-- doc-test: skip REASON
-->`` is only shown, never run (say why in REASON).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_BLOCK = re.compile(r"(<!-- doc-test: skip[^>]*-->\s*\n)?```python\n(.*?)```", re.S)


def python_blocks(page: Path) -> list[tuple[int, str, bool]]:
    """(line, code, skipped) of every ```python block of a page."""
    text = page.read_text(encoding="utf-8")
    out = []
    for m in _BLOCK.finditer(text):
        line = text.count("\n", 0, m.start(2)) + 1
        out.append((line, m.group(2), m.group(1) is not None))
    return out


def uses_bpy(code: str) -> bool:
    """True for a block that needs Blender (bpy or another module only Blender has)."""
    return (
        re.search(r"^\s*(import|from)\s+(bpy|addon_utils|bmesh|mathutils)\b", code, re.M)
        is not None
    )


def run_page(page: Path, want_bpy: bool) -> int:
    """Run a page's blocks; returns how many ran."""
    ns: dict = {"__name__": "__doc_snippet__"}
    ran = 0
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        for line, code, skipped in python_blocks(page):
            if skipped or uses_bpy(code) != want_bpy:
                continue
            try:
                exec(compile(code, f"{page.name}:{line}", "exec"), ns)
            except Exception as exc:
                raise AssertionError(f"{page.relative_to(ROOT)} line {line}: {exc!r}") from exc
            ran += 1
    finally:
        os.chdir(cwd)
    return ran


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_python_snippets_run(page):
    """In a fresh interpreter, as a reader would run them (no module this suite imported)."""
    code = (
        "import sys; sys.path.insert(0, sys.argv[1]); import test_docs; "
        "from pathlib import Path; test_docs.run_page(Path(sys.argv[2]), want_bpy=False)"
    )
    here = str(Path(__file__).resolve().parent)
    r = subprocess.run(
        [sys.executable, "-c", code, here, str(page)], capture_output=True, text=True, timeout=600
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]


def test_the_readme_has_a_runnable_snippet():
    assert run_page(ROOT / "README.md", want_bpy=False) >= 1


def test_the_extractor_sees_skips_and_bpy(tmp_path):
    page = tmp_path / "p.md"
    page.write_text(
        "text\n```python\nx = 1\n```\n<!-- doc-test: skip needs a GPU -->\n```python\nboom\n```\n"
        "```python\nimport bpy\n```\n",
        encoding="utf-8",
    )
    blocks = python_blocks(page)
    assert [(b[1].strip(), b[2]) for b in blocks] == [
        ("x = 1", False),
        ("boom", True),
        ("import bpy", False),
    ]
    assert blocks[0][0] == 3 and uses_bpy(blocks[2][1]) and not uses_bpy(blocks[0][1])
