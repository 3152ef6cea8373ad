"""The house's structure: no import cycle between files, no room importing a room above it.

The backend's rooms stand in one order (``ROOMS``): a module may import its own room and the rooms
below it, never one above. ``igs_contract`` stands under everything and imports nothing of ours; the
add-on (``igs_blender``, ``operators``, ``panels``) never imports the backend or torch. Every import
counts, also one inside a function: it runs as soon as that function does.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# The backend's rooms, from the ground floor up; backend/__main__.py is the command layer's door. The
# benchmark scripts stand on top: they may use everything, and nothing the commands run imports them.
ROOMS = ("core", "capture", "synth", "priors", "render", "splats", "train", "relight", "edit", "eval", "scene_render",
         "commands", "bench")
ADDON_PACKAGES = ("igs_blender", "operators", "panels")


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts) or "__init__"


def _sources() -> dict[str, Path]:
    """Module name -> file, for the backend, the contract, the add-on and the tests' helpers (the test
    modules and scripts aside)."""
    out = {"__init__": REPO / "__init__.py"}
    for top in ("backend", "igs_contract", *ADDON_PACKAGES, "tests/support"):
        for path in sorted((REPO / top).rglob("*.py")):
            out[_module_name(path)] = path
    return out


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of ours that ``name`` imports: ``from pkg import mod`` names the module when
    ``pkg.mod`` is one, else the package itself (its ``__init__``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = [] if package == "__init__" else package.split(".")
                if node.level - 1 > len(parts):
                    continue  # above the repository: the extension's parent package once installed
                stem = ".".join([*parts[: len(parts) - (node.level - 1)], *([node.module] if node.module else [])])
            else:
                stem = node.module or ""
            targets = []
            for alias in node.names:
                sub = f"{stem}.{alias.name}" if stem else alias.name
                targets.append(sub if sub in modules else stem)
        else:
            continue
        for target in targets:
            # `import backend.render.api` loads backend.render.api: the longest name that is ours
            while target and target not in modules:
                target = target.rpartition(".")[0]
            if target and target != name:
                found.add(target)
    return found


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = _sources()
    return {name: _imports(name, path, modules) for name, path in modules.items()}


def _room(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "backend" or len(parts) < 2:
        return None
    return "commands" if parts[1] == "__main__" else parts[1]


def test_every_backend_module_is_in_a_room(graph):
    homeless = [m for m in graph if m.startswith("backend.") and _room(m) not in ROOMS]
    assert homeless == [], f"modules outside the rooms {ROOMS}: {homeless}"


def test_no_room_imports_a_room_above_it(graph):
    back = sorted(f"{m} -> {t}" for m, targets in graph.items() for t in targets
                  if _room(m) in ROOMS and _room(t) in ROOMS and ROOMS.index(_room(t)) > ROOMS.index(_room(m)))
    assert back == [], "imports against the order " + " -> ".join(ROOMS) + ":\n" + "\n".join(back)


def test_contract_imports_nothing_of_ours(graph):
    bad = sorted(f"{m} -> {t}" for m, targets in graph.items() if m.startswith("igs_contract")
                 for t in targets if not t.startswith("igs_contract"))
    assert bad == [], "igs_contract must stand on its own:\n" + "\n".join(bad)


def test_the_backend_reaches_the_addon_only_through_the_test_helper(graph):
    """A bench that measures the add-on in bpy loads it through ``tests/support/addon_package.py`` (the
    package Blender makes of the extension folder, as the add-on's tests load it) or installs it through
    ``tests/support/addon_install.py`` (the extension built and installed, as the tests under tests/blender/
    install it), arrows this graph sees; no backend module imports the add-on or the tests otherwise, or
    loads a file as a module."""
    bad = sorted(f"{m} -> {t}" for m, targets in graph.items() if m.startswith("backend.") for t in targets
                 if t.split(".")[0] in (*ADDON_PACKAGES, "tests", "__init__")
                 and not (_room(m) == "bench" and t in ("tests.support.addon_package", "tests.support.addon_install")))
    assert bad == [], "the backend reaching the add-on:\n" + "\n".join(bad)
    loaders = sorted(p.relative_to(REPO).as_posix() for p in (REPO / "backend").rglob("*.py")
                     if "spec_from_file_location" in p.read_text(encoding="utf-8"))
    assert loaders == [], f"loads a file as a module where the import graph cannot see it: {loaders}"


# Shipped with the add-on but run BY the backend's interpreter (it reports whether torch and the
# backend import there): Blender imports only its helpers, so its imports of them stay in functions.
RUN_BY_BACKEND_PYTHON = {"igs_blender/check_env.py"}


def _module_level(tree: ast.Module):
    """The nodes of a module outside its functions and classes' methods."""
    todo = list(tree.body)
    while todo:
        node = todo.pop()
        yield node
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            todo.extend(ast.iter_child_nodes(node))


def test_addon_never_imports_the_backend_or_torch():
    bad = []
    for top in ("__init__.py", *ADDON_PACKAGES):
        for path in ([REPO / top] if top.endswith(".py") else sorted((REPO / top).rglob("*.py"))):
            rel = path.relative_to(REPO).as_posix()
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in (_module_level(tree) if rel in RUN_BY_BACKEND_PYTHON else ast.walk(tree)):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
                bad += [f"{rel}:{node.lineno} imports {n}" for n in names if n.split(".")[0] in ("backend", "torch")]
    assert bad == [], "\n".join(bad)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in graph:
                    continue
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    top = stack.pop()
                    on_stack.discard(top)
                    component.append(top)
                    if top == node:
                        break
                if len(component) > 1:
                    out.append(sorted(component))
    return out


def test_no_import_cycles(graph):
    cycles = _cycles(graph)
    assert cycles == [], "import cycles between files:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_checks_see_a_cycle_and_a_back_edge(tmp_path):
    """The graph walk itself: a planted cycle, a planted back edge and each form of import are found."""
    planted = {"backend.core.a": {"backend.core.b"}, "backend.core.b": {"backend.core.a"},
               "backend.train.x": {"backend.eval.y"}, "backend.eval.y": set()}
    assert _cycles(planted) == [["backend.core.a", "backend.core.b"]]
    assert ROOMS.index(_room("backend.eval.y")) > ROOMS.index(_room("backend.train.x"))
    modules = {"backend.render": Path("r/__init__.py"), "backend.render.api": Path("r/api.py"),
               "igs_blender": Path("i/__init__.py"), "operators": Path("o/__init__.py"),
               "igs_contract.layer_ply": Path("c/layer_ply.py"), "igs_contract": Path("c/__init__.py")}
    probe = tmp_path / "probe.py"
    probe.write_text("def f():\n    from backend.render import api\n"
                     "from backend.render import BACKENDS\nimport backend.render.api\n")
    assert _imports("backend.eval.z", probe, modules) == {"backend.render.api", "backend.render"}
    probe.write_text("from .. import operators\nfrom ..igs_contract import layer_ply\nfrom ... import x\n")
    assert _imports("igs_blender.jobs", probe, modules) == {"operators", "igs_contract.layer_ply"}
