"""The add-on's import graph, read from its source with ast (no Blender needed): no module of
addon/material_deform takes part in an import circle, the methods import only the shared model,
the bridge and pure helpers, and only the Blender-facing layer imports the session.

Every import statement counts, also one inside a function (a late import still ties the two
modules together). ``from P import n`` is an import of the module P.n when there is one, else of
P. Importing a submodule also runs its packages' ``__init__``; that implied edge is left out,
since every package whose ``__init__`` re-exports its submodules would otherwise be a circle.
"""

import ast
from pathlib import Path

import pytest

ADDON = Path(__file__).resolve().parents[2] / "addon" / "material_deform"

# What a method module (methods/<name>.py) may import from the add-on.
METHOD_MAY_IMPORT = {
    "methods.base",
    "model",
    "errors",
    "bridge",
    "updates",
    "anchor_math",
    "aniso_map",
    "stiffness_map",
}
# The layer that talks to Blender's UI and events; nothing else imports the session.
SESSION_USERS = {"", "handlers", "operators", "ui", "bake", "farm"}  # farm: its operator and tasks


def modules(root: Path) -> dict[str, tuple[Path, bool]]:
    """Dotted name relative to the package ("" for its __init__) -> (file, is a package)."""
    out = {}
    for f in sorted(root.rglob("*.py")):
        rel = f.relative_to(root).with_suffix("")
        if "_vendor" in rel.parts:
            continue
        parts = list(rel.parts)
        is_pkg = parts[-1] == "__init__"
        if is_pkg:
            parts.pop()
        out[".".join(parts)] = (f, is_pkg)
    return out


def import_graph(root: Path) -> dict[str, set[str]]:
    """Module -> the package's modules it imports (names relative to the package)."""
    mods = modules(root)
    pkg = root.name
    graph = {}
    for name, (path, is_pkg) in mods.items():
        here = [p for p in name.split(".") if p]
        if not is_pkg:
            here = here[:-1]  # a module's relative imports start from its package
        deps = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name.split(".") for a in node.names]
                targets = [t[1:] for t in targets if t[0] == pkg]
                deps |= {".".join(t) for t in targets}
            elif isinstance(node, ast.ImportFrom):
                parts = node.module.split(".") if node.module else []
                if node.level:
                    target = here[: len(here) - node.level + 1] + parts
                elif parts[0] == pkg:
                    target = parts[1:]
                else:
                    continue
                for alias in node.names:
                    sub = ".".join([*target, alias.name])
                    deps.add(sub if sub in mods else ".".join(target))
        deps.discard(name)
        graph[name] = {d for d in deps if d in mods}
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_the_addons_modules_and_their_imports():
    g = import_graph(ADDON)
    assert {"session", "session.live", "methods", "methods.base", "bridge", "model"} <= set(g)
    methods = {m for m in g if m.startswith("methods.") and m != "methods.base"}
    assert {"methods.material", "methods.edge", "methods.pose_space", "methods.pyramid"} <= methods
    assert "methods.base" in g["methods.edge"] and methods <= g["methods"]
    assert "session.binding" in g["session.live"]  # a sibling, by a relative import
    assert "updates" in g["properties"]  # by ``from . import methods, updates``


def test_no_import_circle_in_the_addon():
    assert cycles(import_graph(ADDON)) == []


def test_methods_import_only_the_model_the_bridge_and_pure_helpers():
    g = import_graph(ADDON)
    bad = {
        m: sorted(d for d in deps if d not in METHOD_MAY_IMPORT and not d.startswith("bridge."))
        for m, deps in g.items()
        if m.startswith("methods.") and m != "methods.base"
    }
    assert {m: d for m, d in bad.items() if d} == {}


def test_only_the_blender_facing_layer_imports_the_session():
    g = import_graph(ADDON)
    users = {
        m
        for m, deps in g.items()
        if not m.startswith("session") and any(d.split(".")[0] == "session" for d in deps)
    }
    assert users <= SESSION_USERS, sorted(users - SESSION_USERS)


@pytest.fixture
def toy_package(tmp_path):
    """A package whose method reaches back into its session with a late import."""
    root = tmp_path / "toy"
    (root / "methods").mkdir(parents=True)
    files = {
        "__init__.py": "",
        "session.py": "from .inputs import gather\n",
        "inputs.py": "from . import methods\n",
        "methods/__init__.py": "from . import base\nfrom . import edge\n",
        "methods/base.py": "import numpy\n",
        "methods/edge.py": (
            "from .base import Method\n\ndef changed():\n    from .. import session\n"
        ),
        "ui.py": "import toy.session\nfrom toy.methods import edge\n",
    }
    for name, text in files.items():
        (root / name).write_text(text)
    return root


def test_the_checks_catch_a_late_import_back_into_the_session(toy_package):
    g = import_graph(toy_package)
    assert g["methods.edge"] == {"methods.base", "session"}
    assert g["ui"] == {"session", "methods.edge"}  # absolute imports of the package
    assert cycles(g) == [["inputs", "methods", "methods.edge", "session"]]
    (toy_package / "methods" / "edge.py").write_text("from .base import Method\n")
    assert cycles(import_graph(toy_package)) == []
