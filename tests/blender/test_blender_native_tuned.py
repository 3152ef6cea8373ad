"""Layers tuned for Blender's drawing (``igs native-tune``) on Blender 5.3 (the bpy 5.3 module, background mode):
with Cycles as the engine, Load Layers draws them while they belong to the current layers, and F12 then comes
closer to ``igs render`` of the decomposition; with EEVEE, or after a decomposition, the originals are drawn,
and the report says why.

The scene is a wall of discs tilted every which way, so that they cross: there Cycles (which orders the
splats along each ray) and the rasteriser (which orders their centres) draw differently."""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
if bpy.app.version < (5, 3, 0):
    pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})", allow_module_level=True)

from backend.core.imageio import srgb_psnr  # noqa: E402
from backend.splats.ply import write_ply  # noqa: E402
from tests.support import addon_package  # noqa: E402, F401  (the add-on's bpy-free modules as the package intrinsic_splats)
from tests.support.blender import draw, load, reference, render_outputs, shown_text, sub, wall_workspace  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


def _crossing_wall(tmp_path):
    """The tiny workspace's wall with every disc turned at random up to 50 degrees: discs that cross."""
    import torch

    ws, sets = wall_workspace(tmp_path, 200)
    rng = np.random.default_rng(5)
    for kind, g in sets.items():
        axis = rng.normal(size=(len(g), 3))
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        half = np.radians(rng.uniform(0, 50, len(g))) / 2
        turn = np.concatenate([np.cos(half)[:, None], np.sin(half)[:, None] * axis], 1)
        q = g.params["quats"].detach().numpy().astype(np.float64)
        w1, v1, w2, v2 = turn[:, :1], turn[:, 1:], q[:, :1], q[:, 1:]  # turn * q (Hamilton product)
        prod = np.concatenate([w1 * w2 - (v1 * v2).sum(1, keepdims=True),
                               w1 * v2 + w2 * v1 + np.cross(v1, v2)], 1)
        g.params["quats"] = torch.nn.Parameter(torch.tensor(prod, dtype=torch.float32))
        write_ply(ws / "layers" / f"{kind}.ply", g)
    return ws, sets


def test_f12_of_the_tuned_layers_comes_closer_to_igs_render(native_scene, tmp_path):
    scene = native_scene
    ws, sets = _crossing_wall(tmp_path)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert "Tune for Blender (`igs native-tune`)" in scene.igs.last_report
    load(scene, ws)
    want = reference(scene, sets)
    before = srgb_psnr(render_outputs(scene, tmp_path / "before", ("Image",))["Image"], want["Image"])

    # the backend's command, as the add-on's Tune for Blender runs it (in-process, its imports would load a second
    # LLVM beside Blender's)
    done = subprocess.run([sys.executable, "-m", "backend", "native-tune", str(ws), "--iterations", "150"],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert "drawn from layers/native/" in scene.igs.last_report
    for kind in ("albedo", "shading", "residual"):
        assert bpy.data.objects[f"IGS {kind}"]["igs_ply"] == str(ws / "layers" / "native" / f"{kind}.ply")
    after = srgb_psnr(render_outputs(scene, tmp_path / "after", ("Image",))["Image"], want["Image"])
    assert after > before + 1.0, (before, after)
    assert sub("layers").shows_tuned()
    scene.render.engine = sub("compat").eevee_engine()  # switched after loading: the Layers panel says so
    assert "tuned for Cycles; with this engine, Load Layers again" in shown_text(draw("IGS_PT_layers"))

    # they are Cycles': with EEVEE (which sorts splats as the rasteriser does) Load Layers draws the originals
    scene.render.engine = sub("compat").eevee_engine()
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert "layers/native/ is tuned for Cycles' drawing of splats" in scene.igs.last_report
    assert bpy.data.objects["IGS albedo"]["igs_ply"] == str(ws / "layers" / "albedo.ply")
    assert not sub("layers").shows_tuned()
    scene.render.engine = "CYCLES"

    # a decomposition since: the tuned copies belong to other layers and are left aside
    g = sets["albedo"]
    g.params["colors"].data += 0.1
    write_ply(ws / "layers" / "albedo.ply", g)
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    assert "tuned from other layers (albedo changed since)" in scene.igs.last_report
    assert bpy.data.objects["IGS albedo"]["igs_ply"] == str(ws / "layers" / "albedo.ply")
