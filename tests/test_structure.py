"""The house's structure: no import cycle between files, no room importing a room above it.

The backend's rooms stand in one order (``ROOMS``): a module may import its own room and the rooms
below it, never one above. ``igs_contract`` stands under everything and imports nothing of ours; the
add-on (``igs_blender``, ``operators``, ``panels``) never imports the backend or torch, and its own
wings stand in a stack too (``ADDON_FLOORS``). Every import counts, also one inside a function: it runs
as soon as that function does.
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

# The add-on's floors, from the ground up: a module imports its own floor and those below it. A floor
# names packages or modules; a module belongs to the longest name that is it or holds it, so the scene
# modules ("igs_blender": what is left at the top of the package) are one floor and the few that use the
# display seam are named above it. native/ and viewport/ share a floor and never import each other.
ADDON_FLOORS = (
    ("igs_blender.errors", "igs_blender.addon_id"),  # what every floor raises or names
    ("igs_blender.jobs",),  # the backend process and the current job (no bpy)
    ("igs_blender.env",),  # the backend's environment, its checks and the CUDA build (no bpy)
    ("igs_blender",),  # the scene modules
    ("igs_blender.native", "igs_blender.viewport"),  # Blender 5.3's splats | our own engine
    ("igs_blender.display",),  # the one face that decides native or viewport
    # scene modules over the seam
    ("igs_blender.edit_objects", "igs_blender.light_bake", "igs_blender.props", "igs_blender.scene_renders",
     "igs_blender.splat_files"),
    ("operators", "panels"),
    ("__init__",),  # the extension's root: registers everything
)
NO_BPY_WINGS = ("igs_blender.jobs", "igs_blender.env")
BPY_MODULES = ("bpy", "bpy_extras", "gpu", "gpu_extras", "mathutils", "bmesh", "blf", "addon_utils")


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


EXTENSION_PACKAGE = "intrinsic_splats"
"""The extension folder as a package (tests/support/addon_package.py): ``intrinsic_splats.igs_blender.x`` is
``igs_blender.x`` of this checkout."""


def _ours(module: str) -> str:
    return module[len(EXTENSION_PACKAGE) + 1:] if module.startswith(EXTENSION_PACKAGE + ".") else module


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The modules of ours that ``name`` imports: ``from pkg import mod`` names the module when
    ``pkg.mod`` is one, else the package itself (its ``__init__``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            targets = [_ours(alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = [] if package == "__init__" else package.split(".")
                if node.level - 1 > len(parts):
                    continue  # above the repository: the extension's parent package once installed
                stem = ".".join([*parts[: len(parts) - (node.level - 1)], *([node.module] if node.module else [])])
            else:
                stem = _ours(node.module or "")
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
    by_name = sorted(f"{p.relative_to(REPO).as_posix()}:{n.lineno}" for p in (REPO / "backend").rglob("*.py")
                     for n in ast.walk(ast.parse(p.read_text(encoding="utf-8")))
                     if isinstance(n, ast.Call) and _called(n) in ("import_module", "__import__")
                     and any(isinstance(c, ast.Constant) and isinstance(c.value, str)
                             and any(top in c.value for top in (*ADDON_PACKAGES, EXTENSION_PACKAGE))
                             for a in n.args for c in ast.walk(a)))
    assert by_name == [], f"imports the add-on by a name made at run time (the graph cannot see it): {by_name}"


def _called(call: ast.Call) -> str:
    f = call.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""


# Shipped with the add-on but run BY the backend's interpreter (it reports whether torch and the
# backend import there): Blender imports only its helpers, so its imports of them stay in functions.
RUN_BY_BACKEND_PYTHON = {"igs_blender/env/check_env.py"}


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


def _floor(module: str) -> int | None:
    """The add-on floor (index in ``ADDON_FLOORS``) of ``module``: the longest name that is it or holds it."""
    best, found = -1, None
    for i, names in enumerate(ADDON_FLOORS):
        for name in names:
            if (module == name or module.startswith(name + ".")) and len(name) > best:
                best, found = len(name), i
    return found


def _wing(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "igs_blender" and len(parts) > 2 or module in ("igs_blender.native",
                                                                                   "igs_blender.viewport") else None


def _addon_back_edges(graph: dict[str, set[str]]) -> list[str]:
    """Imports from a lower add-on floor to a higher one, and between native/ and viewport/."""
    bad = []
    for m, targets in graph.items():
        for t in targets:
            fm, ft = _floor(m), _floor(t)
            if fm is None or ft is None:
                continue
            if ft > fm or {_wing(m), _wing(t)} == {"native", "viewport"}:
                bad.append(f"{m} -> {t}")
    return sorted(bad)


def test_every_addon_module_is_on_a_floor(graph):
    homeless = [m for m in graph if m == "__init__" or m.split(".")[0] in ADDON_PACKAGES if _floor(m) is None]
    assert homeless == [], f"add-on modules outside the floors {ADDON_FLOORS}: {homeless}"


def test_no_addon_floor_imports_one_above_it(graph):
    back = _addon_back_edges(graph)
    assert back == [], "add-on imports against its floors (or between native and viewport):\n" + "\n".join(back)


def test_jobs_and_env_import_no_bpy():
    """The job client and the environment run outside Blender too (tests, scripts run by path)."""
    bad = []
    for wing in NO_BPY_WINGS:
        folder = REPO / wing.replace(".", "/")
        assert (folder / "__init__.py").is_file(), f"{wing} is not a package"
        for path in sorted(folder.rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                         else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
                bad += [f"{path.relative_to(REPO)}:{node.lineno} imports {n}" for n in names
                        if n.split(".")[0] in BPY_MODULES]
    assert bad == [], "\n".join(bad)


def _register_calls(path: Path) -> set[str]:
    """The names ``x`` of the calls ``x.register()`` and ``x.unregister()`` in a file."""
    return {node.func.value.id for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("register", "unregister") and isinstance(node.func.value, ast.Name)}


def test_every_register_is_called_from_the_root(graph):
    """A module's register()/unregister() is called by the root ``__init__.py`` alone: no module registers
    another's handlers behind the root's back."""
    modules = _sources()
    owners = sorted(m for m, path in modules.items() if m.split(".")[0] in ADDON_PACKAGES
                    and any(isinstance(n, ast.FunctionDef) and n.name == "register"
                            for n in ast.parse(path.read_text(encoding="utf-8")).body))
    assert owners, "no add-on module has a register(): the walk is wrong"
    missing = [m for m in owners if m not in graph["__init__"]
               or m.rpartition(".")[2] not in _register_calls(REPO / "__init__.py")]
    assert missing == [], f"register() not called from the root __init__.py: {missing}"
    hidden = sorted(f"{m} calls {', '.join(sorted(names))}.register()" for m, path in modules.items()
                    if m.split(".")[0] in ADDON_PACKAGES and (names := _register_calls(path)))
    assert hidden == [], "\n".join(hidden)


def test_the_addon_checks_see_a_back_edge_and_a_cross_wing_import():
    planted = {"igs_blender.native.splats": {"igs_blender.display", "igs_blender.viewport.overlay",
                                             "igs_blender.layers", "igs_blender.errors"},
               "igs_blender.jobs.client": {"igs_blender.env.backend_env"},
               "igs_blender.edit_objects": {"igs_blender.display"}}
    assert _addon_back_edges(planted) == ["igs_blender.jobs.client -> igs_blender.env.backend_env",
                                          "igs_blender.native.splats -> igs_blender.display",
                                          "igs_blender.native.splats -> igs_blender.viewport.overlay"]
    assert _floor("igs_blender") == _floor("igs_blender.layers") < _floor("igs_blender.native.splats")


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
