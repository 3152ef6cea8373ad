"""The add-on built from this checkout and installed into bpy as Blender installs an extension.

:func:`build_zip` runs Blender's own extension tool (``validate``, then ``build``) on the repository root;
:func:`install` puts the zip into a temporary user repository and enables it, as a user does with
*Install from Disk*. The tests under tests/blender/ (their conftest) and the benches that drive the add-on
through its operators (``backend/bench/native_render_worker.py``) install it this way, so they reach it
by its registered operators and properties rather than by importing its modules.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PYTHON = sys.executable
REPO = "igs_test"
MOD = f"bl_ext.{REPO}.intrinsic_splats"


def _scripts() -> Path:
    import bpy

    return Path(bpy.utils.system_resource("SCRIPTS"))


def build_zip(out_dir: Path) -> Path:
    """The extension's zip, built into ``out_dir`` from this checkout; AssertionError with the tool's output."""
    blender_ext = _scripts() / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    valid_tags = _scripts() / "modules" / "_bpy_internal" / "extensions" / "tags.py"
    out_dir.mkdir(parents=True, exist_ok=True)
    for sub in (["validate", "--valid-tags", str(valid_tags), str(ROOT)],
                ["build", "--valid-tags", str(valid_tags), "--source-dir", str(ROOT), "--output-dir", str(out_dir)]):
        res = subprocess.run([PYTHON, str(blender_ext), *sub], capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stdout + res.stderr
    return out_dir / "intrinsic_splats-0.1.0.zip"


def install(tmp: Path):
    """A fresh empty scene with the extension built, installed into a user repository in ``tmp`` and enabled;
    its preferences (the backend's Python set to this one)."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    prefs = bpy.context.preferences
    repo = prefs.extensions.repos.new(name="IGS", module=REPO, source="USER", custom_directory=str(tmp / "repo"))
    bpy.ops.extensions.package_install_files(filepath=str(build_zip(tmp / "build")), repo=repo.module,
                                             enable_on_install=True)
    if MOD not in prefs.addons:
        raise RuntimeError("the extension did not install")
    addon = prefs.addons[MOD].preferences
    addon.backend_python = PYTHON
    return addon
