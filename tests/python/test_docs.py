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


# The docs describe the project as it is: no diary of past work sessions, no issue numbers
# (git and the tracker keep those). "the session" naming the add-on's `session` package is fine.
_DIARY = [
    re.compile(r"\b[Ss]essions?[ -]?\d"),  # "session 8", "sessions 2-4", "session-4 VM"
    re.compile(r"\bSession\b"),  # a diary heading ("Session 10: ...")
    re.compile(r"\b(this|that|same|previous|earlier|later|last|next|one)\s+session\b", re.I),
    re.compile(r"\b[Ii]ssues?[ -]?\d"),  # "issue 12", "issue-11 audit", "issues 13-15"
    re.compile(r"\bissue's\b|\bissue author\b", re.I),  # "the issue's target"
    re.compile(r"(?<![\w/])#\d+(?![\w-])"),  # "#12" (a link anchor such as "#6-scripting" is fine)
]

# Parts another branch is rewriting, exempt until it lands: page -> None (the whole page) or the
# heading that starts the exempt section (up to the next heading of the same level). When the
# part is clean, test_pending_parts_are_still_pending fails: drop its entry then.
_PENDING: dict[str, str | None] = {}


def _split_pending(page: Path) -> tuple[str, str]:
    """(checked text, exempt text) of a page."""
    text = page.read_text(encoding="utf-8")
    if page.name not in _PENDING or page.parent.name != "docs":
        return text, ""
    heading = _PENDING[page.name]
    if heading is None:
        return "", text
    start = text.find("\n" + heading)
    if start < 0:
        return text, ""
    level = heading.split(" ", 1)[0]
    end = text.find("\n" + level + " ", start + 1)
    end = len(text) if end < 0 else end
    return text[:start] + text[end:], text[start:end]


def diary_lines(text: str) -> list[str]:
    """The lines of a text that read as a diary of sessions or name an issue number."""
    return [line.strip() for line in text.splitlines() if any(p.search(line) for p in _DIARY)]


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_docs_are_references_not_diaries(page):
    checked, _ = _split_pending(page)
    found = diary_lines(checked)
    assert not found, f"{page.relative_to(ROOT)} reads as a diary here:\n" + "\n".join(found)


@pytest.mark.parametrize("name", sorted(_PENDING))
def test_pending_parts_are_still_pending(name):
    """An exempt part that has become clean must lose its exemption (drop it from _PENDING)."""
    _, exempt = _split_pending(ROOT / "docs" / name)
    assert diary_lines(exempt), f"docs/{name}: its pending part is clean now; drop it from _PENDING"


def test_the_checks_see_every_page():
    """The page list is not empty or partial, and only the named pending parts are left out."""
    names = [p.name for p in PAGES]
    docs = sorted(p.name for p in (ROOT / "docs").glob("*.md"))
    assert names[0] == "README.md" and names[1:] == docs and len(docs) >= 10
    for page in PAGES:
        checked, exempt = _split_pending(page)
        text = page.read_text(encoding="utf-8")
        if page.parent.name == "docs" and page.name in _PENDING:
            assert exempt, f"{page.name}: its pending part is gone; drop it from _PENDING"
            if _PENDING[page.name] is not None:  # a section, not most of the page
                assert exempt.startswith("\n" + _PENDING[page.name])
                assert len(exempt) < len(text) / 2
        else:
            assert checked == text and not exempt


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_a_diary_line_anywhere_in_a_checked_page_is_found(page, tmp_path):
    """'session 12' put at the top, the middle and the end of each page's checked text fails it
    (the middle of performance.md is next to its exempt section)."""
    if page.parent.name == "docs" and _PENDING.get(page.name, "") is None:
        pytest.skip("exempt as a whole")
    text = page.read_text(encoding="utf-8")
    heading = _PENDING.get(page.name) if page.parent.name == "docs" else None
    # just before the exempt section, or a line break near the middle
    middle = text.find("\n" + heading) if heading else text.rfind("\n", 0, len(text) // 2)
    for at in (0, middle, len(text)):
        copy = tmp_path / ("docs" if page.parent.name == "docs" else "root") / page.name
        copy.parent.mkdir(exist_ok=True)
        copy.write_text(text[:at] + "\nMeasured in session 12.\n" + text[at:], encoding="utf-8")
        checked, _ = _split_pending(copy)
        assert diary_lines(checked) == ["Measured in session 12."], (page.name, at)


def test_the_diary_check_tells_sessions_and_issues_from_the_code_session():
    diary = [
        "**Session 8 re-run** (2026-12-01)",
        "the session-4 Intel VM",
        "Sessions 2-4 ran on a 2-vCPU Intel VM",
        "run at the start of this session",
        "Targets (issue 2): deform() <= 3 ms",
        "each crash the issue-11 audit found",
        "the issue's 10 ms",
        "fixed in #12",
    ]
    fine = [
        "The session (`addon/material_deform/session/`) owns everything the methods share",
        "the session calls the interface of `methods/base.py`",
        "[Scripting and background use](#6-scripting-and-background-use)",
        "see [farm.md](farm.md#same-positions-on-every-worker)",
    ]
    assert [bool(diary_lines(s)) for s in diary] == [True] * len(diary)
    assert [bool(diary_lines(s)) for s in fine] == [False] * len(fine)


def test_the_readme_lists_every_doc_page():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    missing = [
        p.name for p in sorted((ROOT / "docs").glob("*.md")) if f"(docs/{p.name})" not in readme
    ]
    assert not missing, f"README.md's Documentation list lacks {missing}"


def _without_code(text: str) -> str:
    return re.sub(r"```.*?```", "", text, flags=re.S)


def heading_anchors(page: Path) -> set[str]:
    """The anchors GitHub gives a page's headings (lower case, punctuation dropped, spaces to
    hyphens, -1, -2, ... on repeats) and its explicit <a id="..."> anchors."""
    text = _without_code(page.read_text(encoding="utf-8"))
    out: set[str] = set(re.findall(r'<a id="([^"]+)"', text))
    seen: dict[str, int] = {}
    for m in re.finditer(r"^#{1,6} (.+)$", text, re.M):
        slug = re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-")
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return out


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_links_between_pages_reach_their_file_and_heading(page):
    """A renamed heading or page must not leave a dead link behind (pages another branch is
    rewriting are not checked as sources until it lands)."""
    if page.parent.name == "docs" and _PENDING.get(page.name, "") is None:
        pytest.skip("rewritten on another branch")
    dead = []
    for target in re.findall(r"\]\(([^)\s]+)\)", _without_code(page.read_text(encoding="utf-8"))):
        if re.match(r"[a-z]+:", target):
            continue  # http:, https:, mailto:
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            dead.append(target)
        elif anchor and dest.suffix == ".md" and anchor not in heading_anchors(dest):
            dead.append(target)
    assert not dead, f"{page.relative_to(ROOT)}: dead links {dead}"


def test_heading_anchors_follow_githubs_rules(tmp_path):
    page = tmp_path / "p.md"
    page.write_text(
        "# Inside Blender (`bench/bench_blender.py`)\n## 5. Bake\n## Limits\n### Limits\n"
        '```sh\n# not a heading\n```\n<a id="kept"></a>\n',
        encoding="utf-8",
    )
    assert heading_anchors(page) == {
        "inside-blender-benchbench_blenderpy",
        "5-bake",
        "limits",
        "limits-1",
        "kept",
    }
