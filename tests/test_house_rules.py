"""The tree's rules beside the import order: no module over 600 lines, and a harness whose tests import
only packages (``tests.support``, conftest fixtures), never another test module or a path of their own.
"""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
MAX_LINES = 600
# Not ours to measure: the virtual environments, the shared design folder, git, workspaces, installed tools.
SKIP_TOP = {"shared", ".git", "workspaces", "node_modules"}


def python_files(root: Path) -> list[Path]:
    out = []
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root).parts
        if parts[0].startswith(".venv") or parts[0] in SKIP_TOP or "__pycache__" in parts:
            continue
        out.append(path)
    return out


def long_modules(root: Path) -> dict[str, int]:
    """Path (relative, posix) -> line count, for every Python file over ``MAX_LINES`` lines."""
    counts = {p.relative_to(root).as_posix(): len(p.read_text(encoding="utf-8").splitlines())
              for p in python_files(root)}
    return {rel: n for rel, n in counts.items() if n > MAX_LINES}


def harness_faults(tests: Path) -> list[str]:
    """Imports of a test module (``test_*``) and ``sys.path`` edits in the code of ``tests/``."""
    bad = []
    for path in sorted(tests.rglob("*.py")):
        rel = path.relative_to(tests.parent).as_posix()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            else:
                names = []
            bad += [f"{rel}:{node.lineno} imports the test module {n}" for n in names
                    if n.rpartition(".")[2].startswith("test_")]
            if (isinstance(node, ast.Attribute) and node.attr in ("insert", "append", "extend")
                    and ast.unparse(node.value) == "sys.path"):
                bad.append(f"{rel}:{node.lineno} edits sys.path")
    return sorted(bad, key=lambda line: (line.split(":")[0], int(line.split(":")[1].split()[0])))


def test_no_module_is_over_600_lines():
    over = long_modules(REPO)
    assert over == {}, "\n".join(f"{rel}: {n} lines (at most {MAX_LINES}: split it)" for rel, n in over.items())


def test_no_test_imports_another_test_module_or_edits_sys_path():
    faults = harness_faults(REPO / "tests")
    assert faults == [], "\n".join(faults)


def test_the_rules_see_a_long_module_a_test_import_and_a_path_edit(tmp_path):
    """The checks themselves, on a planted tree."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "long.py").write_text("x = 1\n" * (MAX_LINES + 1))
    (tmp_path / "pkg" / "short.py").write_text("x = 1\n" * MAX_LINES)
    (tmp_path / ".venv").mkdir()
    (tmp_path / ".venv" / "vendored.py").write_text("x = 1\n" * (MAX_LINES + 5))
    assert long_modules(tmp_path) == {"pkg/long.py": MAX_LINES + 1}
    tests = tmp_path / "tests"
    tests.mkdir()
    (tests / "test_a.py").write_text("import sys\nfrom test_b import helper\nsys.path.insert(0, '.')\n"
                                     "from tests.blender import test_c\nSCRIPT = 'sys.path.insert(0, x)'\n")
    (tests / "test_ok.py").write_text("from tests.support.train_scene import make_workspace\n")
    assert harness_faults(tests) == ["tests/test_a.py:2 imports the test module test_b",
                                     "tests/test_a.py:3 edits sys.path",
                                     "tests/test_a.py:4 imports the test module tests.blender.test_c"]
