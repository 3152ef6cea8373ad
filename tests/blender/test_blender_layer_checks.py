"""Load Layers refuses what it cannot show (issue #59, K): a layer whose log-scales are beyond the
contract's range is one error naming the file, and with ``layers/shading.ply`` missing the report says
that F12 cannot render A x S + R rather than promising it (the bpy 5.3 module, background mode)."""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import sub, wall_workspace  # noqa: E402


@pytest.fixture
def scene(native_scene):
    """Native splats on (the conftest's ``native_scene``), as in test_blender_native."""
    return native_scene

from backend.splats.formats import read_splat_file  # noqa: E402
from backend.splats.formats_write import ply_bytes  # noqa: E402


def test_load_layers_without_shading_says_what_f12_lacks(scene, tmp_path):
    ws, _ = wall_workspace(tmp_path, n=60)
    (ws / "layers" / "shading.ply").unlink()
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    report = scene.igs.last_report
    assert "F12 does not render A×S+R: layers/shading.ply missing" in report, report
    assert "F12 renders" not in report, report


def test_load_layers_refuses_a_log_scale_of_1e30(scene, tmp_path):
    ws, _ = wall_workspace(tmp_path, n=60)
    path = ws / "layers" / "albedo.ply"
    arrays = read_splat_file(path).arrays
    arrays.log_scales[5, 2] = 1e30
    path.write_bytes(ply_bytes(arrays, ["igs_kind albedo", "igs_color rgb01", "igs_space linear"]))
    with pytest.raises(sub("errors").UserError, match="a log-scale above 30"):
        sub("ply_io").read_splat_ply(path)
    scene.igs.workspace = str(ws)
    with pytest.raises(RuntimeError, match="log-scale above 30"):  # bpy.ops raises the operator's ERROR report
        bpy.ops.igs.load_layers()
