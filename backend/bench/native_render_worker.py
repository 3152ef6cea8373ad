"""Blender 5.3 renders a decomposed workspace with added lights and meshes through the add-on: bench_relight's
``native`` and ``mesh`` rows (:mod:`backend.bench.relight_native` starts it).

    python -m backend.bench.native_render_worker JOBS.json

Runs in a Python with the bpy 5.3 module, in a process of its own. It does what an artist does: the add-on
is built from this checkout, installed into a temporary extensions repository and enabled (as the tests
under tests/blender/ install it), then, through its operators, Load Cameras and Load Layers (native splats
and the A x S + R render setup) of the workspace. Each added light goes into the IGS lights collection
(Add Light, then the light's settings), each mesh (:mod:`backend.synth.mesh_rig`) into a collection of
its own, both placed through the capture's matrix. Then per job: Look Through the view's camera, show one
light (or none) and the meshes (or not), F12 in Cycles on the CPU, and the composite written as a 32-bit
EXR (linear). ``JOBS.json``::

    {"workspace": WS, "out": DIR, "samples": 16, "seed": 0, "pixel_filter": "default" | "box", "threads": 2,
     "lights": [canonical lights],
     "meshes": [canonical meshes], "renders": [{"view": "frame_0000.png", "light": "key" | null,
                                               "meshes": true, "file": "x.exr"}, ...]}

It prints one JSON line per render (``{"rendered", "seconds"}``) and a last one ``{"done", "jobs_ran"}``
where ``jobs_ran`` counts the backend jobs the add-on started (none should).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ADDON_LIGHT = {"point": "POINT", "spot": "SPOT", "sun": "SUN", "area": "AREA"}
MESHES_COLLECTION = "Added meshes"
NOT_53 = 3
"""The exit code when this bpy is older than 5.3 (:mod:`backend.bench.relight_native` reports it as a note)."""


def say(**fields: Any) -> None:
    print(json.dumps(fields), flush=True)


def install_addon(tmp: Path):
    """The extension built from this checkout, installed into a temporary repository in ``tmp`` and enabled, as
    the add-on's tests install it (:mod:`tests.support.addon_install`), with native splats on; its preferences."""
    from tests.support.addon_install import install

    addon = install(tmp)
    if hasattr(addon, "native_splats"):
        addon.native_splats = True
    return addon


def check(result: set[str], what: str, scene) -> None:
    if result != {"FINISHED"}:
        raise RuntimeError(f"{what}: {scene.igs.last_report}")


def set_up(job: dict[str, Any]):
    """The workspace loaded natively, the lights in the lights collection and the meshes in the scene, all
    hidden; (scene, lights by name, mesh objects)."""
    import bpy
    from mathutils import Matrix

    from backend.synth import light_rig, mesh_rig

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.igs.workspace = str(job["workspace"])
    scene.render.engine = "CYCLES"  # before Load Layers, which draws the layers tuned for Cycles where they are current
    check(bpy.ops.igs.load_cameras(), "Load Cameras", scene)
    check(bpy.ops.igs.load_layers(), "Load Layers", scene)
    root = bpy.data.objects.get("IGS Capture")
    to_world = root.matrix_world.copy() if root is not None else Matrix.Identity(4)
    lights = {}
    for light in job["lights"]:
        check(bpy.ops.igs.add_light(kind=ADDON_LIGHT[light["type"]]), "Add Light", scene)
        obj = bpy.context.active_object
        light_rig.configure(obj.data, light)
        obj.matrix_world = to_world @ light_rig.light_matrix(light)
        obj.hide_render = True
        lights[light["name"]] = obj
    coll = bpy.data.collections.new(MESHES_COLLECTION)
    scene.collection.children.link(coll)
    meshes = mesh_rig.add_meshes(job["meshes"], matrix=to_world, collection=coll)
    for obj in meshes:
        obj.hide_render = True
    r, c = scene.render, scene.cycles
    r.engine = "CYCLES"
    c.device = "CPU"
    c.samples = int(job["samples"])
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = int(job["seed"])
    if job.get("pixel_filter") == "box":  # as the truth: each sample lands in one pixel
        c.pixel_filter_type = "BOX"
        c.filter_width = 1.0
    # else Blender's default, Blackman-Harris 1.5 px: the low-pass the antialiased raster mode fits the layers for
    r.threads_mode = "FIXED"
    r.threads = int(job["threads"])
    r.image_settings.file_format = "OPEN_EXR"
    r.image_settings.color_depth = "32"
    return scene, lights, meshes


def render_all(job: dict[str, Any]) -> int:
    """Every render of ``job`` (module docstring); the number of backend jobs the add-on started."""
    import bpy

    scene, lights, meshes = set_up(job)
    started = 0
    out = Path(job["out"])
    for item in job["renders"]:
        cam = bpy.data.objects.get(f"IGS {Path(item['view']).stem}")
        if cam is None:
            raise RuntimeError(f"Load Cameras made no camera for the view {item['view']}")
        check(bpy.ops.igs.use_frame_camera(camera=cam.name), "Look Through", scene)
        for name, obj in lights.items():
            obj.hide_render = name != item["light"]
        for obj in meshes:
            obj.hide_render = not item["meshes"]
        bpy.context.view_layer.update()  # the add-on's depsgraph handlers see the change
        scene.render.filepath = str(out / item["file"])
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        started += int(bool(scene.igs.job_label))
        say(rendered=item["file"], seconds=round(time.perf_counter() - t, 3))
    return started


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python -m backend.bench.native_render_worker JOBS.json", file=sys.stderr)
        return 2
    job = json.loads(Path(argv[0]).read_text())
    import bpy

    if bpy.app.version < (5, 3, 0):
        print(f"native splats need Blender 5.3; this bpy is {bpy.app.version_string}", file=sys.stderr)
        return NOT_53
    with tempfile.TemporaryDirectory(prefix="igs_native_") as tmp:
        install_addon(Path(tmp))
        started = render_all(job)
        normals = sorted({str(o.get("igs_normals")) for o in bpy.data.objects if "igs_normals" in o})
    say(done=True, jobs_ran=started, normals=",".join(normals))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
