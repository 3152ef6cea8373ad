"""The add-on built and installed in bpy, a fresh scene, and stand-in backends: the fixtures of the tests under tests/blender/.

Each test module gets its own install (module scope), as a user's Blender session would. The bpy
imports stay inside the fixtures: where bpy is missing the modules that need it skip on their own.
"""

from __future__ import annotations

import importlib
import stat
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def ext_zip(tmp_path_factory) -> Path:
    from tests.support.blender import build_zip

    return build_zip(tmp_path_factory.mktemp("build"))


@pytest.fixture(scope="module")
def addon(ext_zip, tmp_path_factory):
    """The built extension installed into a temporary user repository and enabled."""
    import addon_utils

    from tests.support.blender import MOD, PYTHON, REPO, bpy

    prefs = bpy.context.preferences
    bpy.ops.wm.read_homefile(use_empty=True)
    repo = prefs.extensions.repos.new(name="IGS Test", module=REPO, source="USER",
                                      custom_directory=str(tmp_path_factory.mktemp("repo")))
    bpy.ops.extensions.package_install_files(filepath=str(ext_zip), repo=REPO, enable_on_install=True)
    assert MOD in prefs.addons, "the extension did not install/enable"
    prefs.addons[MOD].preferences.backend_python = PYTHON
    yield importlib.import_module(MOD)
    addon_utils.disable(MOD, default_set=True)
    prefs.extensions.repos.remove(repo)
    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture
def scene(addon):
    """A fresh empty scene with the add-on's settings at their defaults and the real backend configured.

    These tests cover the point-cloud path (Blender 4.2-5.2, and 5.3 with Native Splats off): on 5.3 it is
    chosen here. ``test_blender_native.py`` covers Blender 5.3's native splats."""
    from tests.support.blender import MOD, PYTHON, bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    prefs = bpy.context.preferences.addons[MOD].preferences
    prefs.backend_python = PYTHON
    if hasattr(prefs, "native_splats"):
        prefs.native_splats = False
    return bpy.context.scene


@pytest.fixture(scope="module")
def fake_python(tmp_path_factory) -> Path:
    from tests.support.blender import PYTHON
    from tests.support.fake_backend import FAKE_BACKEND

    path = tmp_path_factory.mktemp("fake") / "python"
    path.write_text(FAKE_BACKEND.format(python=PYTHON))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.fixture(scope="module")
def contract_python(tmp_path_factory) -> Path:
    from tests.support.blender import CONTRACT_DOUBLE, PYTHON, ROOT

    path = tmp_path_factory.mktemp("contract") / "python"
    path.write_text(CONTRACT_DOUBLE.format(python=PYTHON, root=str(ROOT)))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


@pytest.fixture(scope="module")
def bare_venv(tmp_path_factory) -> Path:
    """A venv made with ``python3.11 -m venv`` (else this Python's; no pip, nothing installed)."""
    import shutil
    import subprocess
    import sys

    from intrinsic_splats.igs_blender.env import backend_env

    PYTHON = sys.executable
    base = shutil.which("python3.11") or PYTHON
    env_dir = tmp_path_factory.mktemp("bare") / "venv"
    subprocess.run([base, "-m", "venv", "--without-pip", str(env_dir)], check=True, timeout=120)
    return backend_env.venv_python(env_dir)


@pytest.fixture
def native_scene(addon):
    """A fresh empty scene, the add-on's settings at their defaults, Blender 5.3's native splats on."""
    import sys

    from tests.support.blender import MOD, bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    prefs = bpy.context.preferences.addons[MOD].preferences
    prefs.backend_python = sys.executable
    prefs.native_splats = True
    return bpy.context.scene
