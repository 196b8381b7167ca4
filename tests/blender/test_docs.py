"""The bpy snippets of README.md and docs/*.md run as written in Blender (the others run in
tests/python/test_docs.py, whose extractor this reuses)."""

import importlib.util
from pathlib import Path

import bpy
import pytest

_spec = importlib.util.spec_from_file_location(
    "doc_snippets", Path(__file__).resolve().parents[1] / "python" / "test_docs.py"
)
docs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(docs)
# pages with a bpy block that runs (one marked doc-test: skip is only shown)
PAGES = [
    p
    for p in docs.PAGES
    if any(docs.uses_bpy(c) and not skip for _, c, skip in docs.python_blocks(p))
]


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_bpy_snippets_run(page):
    bpy.ops.wm.read_homefile(use_factory_startup=True)  # the default scene, as a user has it
    assert docs.run_page(page, want_bpy=True) >= 1
