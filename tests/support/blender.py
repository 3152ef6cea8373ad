"""The add-on built, installed and reached in bpy, and probes of its panels: what the tests under tests/blender/ share."""

from __future__ import annotations

import importlib
import json
import subprocess
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tests.support.fake_backend import make_tiny_workspace  # noqa: E402

bpy = pytest.importorskip("bpy")
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

from backend.splats.gaussians import GaussianSet  # noqa: E402
from backend.splats.ply import write_ply  # noqa: E402
from backend.synth import mesh_rig  # noqa: E402
from tests.support.addon_install import MOD, PYTHON, REPO, ROOT, build_zip  # noqa: E402, F401  (the tests' names for them)


def sub(name: str):
    """The add-on's module ``igs_blender.<name>`` (imported if nothing in the add-on has yet)."""
    return importlib.import_module(f"{MOD}.igs_blender.{name}")


def backend_commands() -> set[str]:
    """The commands the backend offers now, as the add-on's own check reports them."""
    if not hasattr(backend_commands, "cache"):
        res = subprocess.run([PYTHON, str(ROOT / "igs_blender" / "env" / "check_env.py"), "--requirements-json", "[]"],
                             capture_output=True, text=True, cwd=ROOT, timeout=120)
        env = next(json.loads(ln) for ln in res.stdout.splitlines() if '"event": "env"' in ln)
        backend_commands.cache = set(env["commands"])
    return backend_commands.cache


def need_command(name: str) -> None:
    if name not in backend_commands():
        pytest.skip(f"backend command '{name}' has not landed yet")


def write_layers(ws: Path, n: int = 200) -> dict:
    from backend.splats.ply import write_ply
    from tests.support.gaussians import random_gaussians

    sets = {"albedo": random_gaussians("albedo", n, 0, 1), "shading": random_gaussians("shading", n + 10, 0, 2),
            "residual": random_gaussians("residual", 40, 3, 3)}
    for kind, g in sets.items():
        write_ply(ws / "layers" / f"{kind}.ply", g)
    return sets


def attr(obj, name: str, width: int, field: str, dtype=np.float32) -> np.ndarray:
    a = obj.data.attributes[name]
    out = np.empty(len(obj.data.points) * width, dtype=dtype)
    a.data.foreach_get(field, out)
    return out.reshape(-1, width) if width > 1 else out


class LayoutProbe:
    """Stands in for ``UILayout`` (background mode has no UI): every call is checked against the real
    UILayout API, properties and operators must exist, icons must be Blender icons."""

    icons = set(bpy.types.UILayout.bl_rna.functions["label"].parameters["icon"].enum_items.keys())

    def __init__(self, calls: list):
        object.__setattr__(self, "calls", calls)

    def __setattr__(self, name, value):
        assert name in bpy.types.UILayout.bl_rna.properties, f"UILayout has no property {name}"

    def __getattr__(self, name):
        fn = bpy.types.UILayout.bl_rna.functions.get(name)
        assert fn is not None, f"UILayout has no function {name}"
        params = set(fn.parameters.keys())

        def call(*args, **kw):
            assert not set(kw) - params, f"{name}() has no argument(s) {set(kw) - params}"
            if "icon" in kw:
                assert kw["icon"] in self.icons, f"unknown icon {kw['icon']}"
            if name in ("prop", "template_list"):
                data, prop = (args[0], args[1]) if name == "prop" else (args[2], args[3])
                assert prop in data.bl_rna.properties, f"{data.bl_rna.identifier} has no property {prop}"
            if name == "template_list":
                assert hasattr(bpy.types, args[0]), args[0]
            self.calls.append((name, args[1] if name == "prop" else args[0] if args else kw.get("text")))
            if name == "operator":
                return OperatorProbe(args[0])
            return LayoutProbe(self.calls)

        return call


class OperatorProbe:
    def __init__(self, idname: str):
        mod, op = idname.split(".")
        rna = getattr(getattr(bpy.ops, mod), op).get_rna_type()  # raises for an unknown operator
        object.__setattr__(self, "props", set(rna.properties.keys()))

    def __setattr__(self, name, value):
        assert name in self.props, f"operator has no property {name}"


# A stand-in interpreter for the commands that have not landed yet: it implements the documented
# contract (arguments, events, files) minimally, and checks what Blender sends with the backend's own
# validators (proxy files go through backend.edit.proxy.load_proxy). The real commands are tested in
# the flow below as soon as they exist.
CONTRACT_DOUBLE = r'''#!{python}
import argparse, json, sys, time
from pathlib import Path
import numpy as np
sys.path[:0] = [{root!r}]
from tests.support import addon_package  # the extension as a package, as Blender imports it
from intrinsic_splats.igs_blender.ply_io import SplatLayer, read_splat_ply, write_splat_ply, C0

def emit(ev, **f):
    print(json.dumps({{"event": ev, **f}}), flush=True)

argv = sys.argv[4:]
cmd = argv[0]
emit("start", command=cmd, argv=argv)
p = argparse.ArgumentParser()
p.add_argument("cmd"); p.add_argument("sub", nargs="?")
if cmd == "edit":
    p.add_argument("ws")
else:
    p.set_defaults(sub=None)
    p.add_argument("ws")
p.add_argument("--iterations", type=int); p.add_argument("--stage"); p.add_argument("--restart", action="store_true")
p.add_argument("--view"); p.add_argument("--rect", type=float, nargs=4); p.add_argument("--out")
p.add_argument("--proxy"); p.add_argument("--name"); p.add_argument("--edit"); p.add_argument("--cameras")
p.add_argument("--layers", default="A,S,R,full")
p.add_argument("--mp4", action="store_true")
p.add_argument("--turntable", action="store_true"); p.add_argument("--frames", type=int); p.add_argument("--size", type=int, nargs=2)
a = p.parse_args(argv if cmd == "edit" else [argv[0], *argv[1:]])
ws = Path(a.ws)

def layer(kind, n, seed):
    r = np.random.default_rng(seed)
    rest = np.zeros((n, 15 if kind == "residual" else 0, 3), np.float32)
    return SplatLayer(kind, r.uniform(-1, 1, (n, 3)).astype(np.float32), r.normal(size=(n, 3)).astype(np.float32),
                      rest, r.normal(size=n).astype(np.float32), np.full((n, 3), -3, np.float32),
                      np.tile(np.float32([1, 0, 0, 0]), (n, 1)), encoding={{"albedo": "rgb01", "shading": "rgb"}}.get(kind, "sh"))

if cmd == "decompose":
    for i, kind in enumerate(("albedo", "shading", "residual")):
        emit("stage", stage=kind, total=3)
        for step in range(1, 4):
            emit("progress", stage=kind, step=step, total=3, eta_s=0.0, loss=0.1 / step)
        out = write_splat_ply(ws / "layers" / f"{{kind}}.ply", layer(kind, 300, i))
        emit("output", kind="layer", path=str(out))
    (ws / "metrics.json").write_text(json.dumps({{"decompose": {{"albedo_psnr": 30.5}}}}))
elif cmd == "train-3dgs":
    emit("stage", stage="train_3dgs", total=a.iterations)
    out = write_splat_ply(ws / "layers" / "radiance.ply", layer("radiance", 120, 7))
    emit("output", kind="layer", path=str(out))
elif cmd == "edit" and a.sub == "fit-plane":
    from backend.capture.colmap_io import read_model
    from backend.edit.proxy import plane_proxy, save_proxy
    cam = next(c for c in read_model(ws / "sparse" / "0").cameras if c.name == a.view)
    assert 0 <= a.rect[0] < a.rect[2] <= cam.width and 0 <= a.rect[1] < a.rect[3] <= cam.height, a.rect
    fwd = cam.R[2]
    proxy = plane_proxy(cam.center + 0.5 * fwd, -fwd, cam.R[0], -cam.R[1], [0.4, 0.3], name=a.view, color=[0.5, 0.5, 0.5])
    emit("output", kind="proxy", path=str(save_proxy(a.out, proxy)))
elif cmd == "edit" and a.sub == "bake":
    from backend.edit.proxy import load_proxy
    proxy = load_proxy(a.proxy)  # the backend's own validation of what Blender wrote
    base = read_splat_ply(ws / "layers" / "albedo.ply")
    verts = proxy.vertices.astype(np.float32)
    new = SplatLayer("albedo", verts, np.zeros((len(verts), 3), np.float32), np.zeros((len(verts), 0, 3), np.float32),
                     np.full(len(verts), 5, np.float32), np.full((len(verts), 3), -4, np.float32),
                     np.tile(np.float32([1, 0, 0, 0]), (len(verts), 1)), encoding="rgb01")
    merged = SplatLayer("albedo", *[np.concatenate([getattr(base, f), getattr(new, f)]) for f in
                                    ("means", "f_dc", "f_rest", "opacity_logits", "log_scales", "quats")], encoding="rgb01")
    out = write_splat_ply(ws / "edits" / a.name / "albedo.ply", merged)
    (ws / "edits" / a.name / "received.json").write_text(json.dumps({{"texture": str(proxy.texture_path), "color": None if proxy.color is None else proxy.color.tolist(), "matrix_world": proxy.matrix_world.tolist()}}))
    emit("output", kind="layer", path=str(out))
elif cmd == "render":
    import cv2
    out = Path(a.out)
    if a.turntable:  # the backend's own orbit: only the count and size come from Blender
        assert a.cameras is None and a.frames >= 1, argv
        cams = [{{"name": f"{{k:04d}}", "width": a.size[0], "height": a.size[1], "fx": 1.0, "R": np.eye(3).tolist(),
                  "t": [0.0, 0.0, 0.0]}} for k in range(a.frames)]
        out.mkdir(parents=True, exist_ok=True)
        (out / "argv.json").write_text(json.dumps(argv))
    else:
        cams = json.loads(Path(a.cameras).read_text())["cameras"]
    emit("stage", stage="render", total=len(cams))
    for lay in a.layers.split(","):
        (out / lay).mkdir(parents=True, exist_ok=True)
        for i, c in enumerate(cams):
            assert np.asarray(c["R"]).shape == (3, 3) and len(c["t"]) == 3 and c["fx"] > 0, c
            cv2.imwrite(str(out / lay / f"{{c['name']}}.png"), np.full((c["height"], c["width"], 3), 40 + 10 * i, np.uint8))
            emit("progress", stage="render", step=i + 1, total=len(cams), eta_s=0.0)
        emit("output", kind=f"render_{{lay}}", path=str(out / lay))
        if a.mp4:
            w = cv2.VideoWriter(str(out / f"{{lay}}.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 24, (cams[0]["width"], cams[0]["height"]))
            for c in cams:
                w.write(cv2.imread(str(out / lay / f"{{c['name']}}.png")))
            w.release()
            emit("output", kind="video", path=str(out / f"{{lay}}.mp4"))
    (out / "edit.txt").write_text(str(a.edit))
else:
    emit("error", message=f"the contract double has no {{cmd}}")
    sys.exit(2)
emit("done", command=cmd, seconds=0.1)
'''


class TextProbe(LayoutProbe):
    """A :class:`LayoutProbe` (every call checked against UILayout) that also records what the user reads:
    ``(function, property or operator or None, text, enum item)`` for every call, nested layouts included."""

    def __init__(self, calls: list, texts: list):
        super().__init__(calls)
        object.__setattr__(self, "texts", texts)

    def __getattr__(self, name):
        checked = super().__getattr__(name)

        def call(*args, **kw):
            checked(*args, **kw)
            prop = args[1] if name in ("prop", "prop_enum") else args[0] if name == "operator" else None
            self.texts.append((name, prop, kw.get("text"), args[2] if name == "prop_enum" else None))
            result = TextProbe(self.calls, self.texts)
            if name == "operator":
                return OperatorProbe(args[0])
            if name == "panel":
                return result, result
            return result

        return call


def draw(*names: str) -> list[tuple]:
    """Draw the named panels; the recorded (function, property, text, enum item) tuples."""
    texts: list = []
    for name in names or PANELS:
        getattr(bpy.types, name).draw(SimpleNamespace(layout=TextProbe([], texts)), bpy.context)
    return texts


def labels(texts) -> list[str]:
    return [t for fn, _, t, _ in texts if fn == "label" and t]


def shown_text(texts) -> str:
    """Every label, joined: what the user reads, wrapped lines rejoined."""
    return " ".join(labels(texts))


def wall_workspace(tmp_path: Path, n: int = 300) -> tuple[Path, dict[str, GaussianSet]]:
    ws = tmp_path / "ws"
    make_tiny_workspace(ws, size=SIZE)
    sets = {"albedo": wall("albedo", n, 1),
            # shading above 1 and a few below 0: Blender must keep both
            "shading": wall("shading", n, 2, color=lambda rng, m: np.where(rng.random((m, 1)) < 0.1, -0.2,
                                                                            rng.uniform(0.5, 1.8, (m, 3)))),
            "residual": wall("residual", n // 2, 3, sh_degree=1)}
    for kind, g in sets.items():
        write_ply(ws / "layers" / f"{kind}.ply", g)
    return ws, sets


def load(scene, ws: Path) -> None:
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.load_cameras() == {"FINISHED"}
    assert bpy.ops.igs.load_layers() == {"FINISHED"}
    cam = bpy.data.objects["IGS frame_0000"]
    sub("camera_objects").use_frame_camera(scene, cam)
    cycles(scene)


def reference(scene, sets: dict[str, GaussianSet]) -> dict[str, np.ndarray]:
    """``igs render`` of the scene camera: A, S, R and A*S+R, linear (H, W, 3), as render_views computes them."""
    import torch

    from backend.core.cameras import Camera
    from backend.render import render_layers
    from backend.train.intrinsic.stages import layer_splats

    v = sub("camera_objects").sfm_view_from_object(scene, scene.camera)
    cam = Camera("view", v.width, v.height, v.fx, v.fy, v.cx, v.cy, v.R, v.t)
    with torch.no_grad():
        outs = render_layers([layer_splats(sets[k]) for k in ("albedo", "shading", "residual")], cam)
    a, s, r = (o.color.clamp_min(0).numpy().astype(np.float64) for o in outs)
    return {"Albedo": a, "Shading": s, "Residual": r, "Image": a * s + r}


def render_outputs(scene, folder: Path, outputs=("Image", "Albedo", "Shading", "Residual")) -> dict[str, np.ndarray]:
    """F12 of ``scene`` with the composite group's outputs read back (the add-on's own helper)."""
    assert bpy.context.scene == scene
    return sub("native.outputs").render_outputs(folder, tuple(outputs))


PANELS = ("IGS_PT_main", "IGS_PT_capture", "IGS_PT_decompose", "IGS_PT_layers", "IGS_PT_edit", "IGS_PT_render")


SIZE = (32, 24)


def wall(kind: str, n: int, seed: int, *, color=None, sh_degree: int = 0, scale: float = 0.12) -> GaussianSet:
    """``n`` Gaussians on the plane x = 0 (|y|, |z| < 1.1), flat along x, seen by camera 0 of the tiny workspace."""
    import torch

    rng = np.random.default_rng(seed)
    means = np.stack([rng.normal(0, 0.01, n), rng.uniform(-1.1, 1.1, n), rng.uniform(-0.8, 1.1, n)], 1)
    t = {"means": torch.tensor(means, dtype=torch.float32),
         "log_scales": torch.tensor(np.log(np.stack([np.full(n, 0.01), rng.uniform(0.7, 1.3, n) * scale,
                                                     rng.uniform(0.7, 1.3, n) * scale], 1)), dtype=torch.float32),
         "opacity_logits": torch.tensor(rng.uniform(1.5, 4.0, n), dtype=torch.float32)}
    # Every disc faces camera 0 (thin along its local x, turned about y towards the camera at height 0.5):
    # parallel discs lie in the same order along every ray, so Cycles (which orders the splats along each ray)
    # and the rasteriser (which orders their centres) blend them in the same order.
    half = -0.5 * np.arctan2(0.5, 2.0)
    t["quats"] = torch.tensor(np.tile([np.cos(half), 0.0, np.sin(half), 0.0], (n, 1)), dtype=torch.float32)
    if kind in ("residual", "radiance"):
        t["sh0"] = torch.tensor(rng.normal(-1.4, 0.2, (n, 1, 3)), dtype=torch.float32)  # small positive radiance
        t["shN"] = torch.tensor(rng.normal(0, 0.02, (n, (sh_degree + 1) ** 2 - 1, 3)), dtype=torch.float32)
    else:
        c = color(rng, n) if color is not None else rng.uniform(0.2, 0.8, (n, 3))
        # albedo stores the logit of its colour, shading the colour itself (igs_contract.layer_ply)
        t["colors"] = torch.tensor(np.log(c / (1 - c)) if kind == "albedo" else c, dtype=torch.float32)
    return GaussianSet(kind, t, sh_degree=sh_degree)


def cycles(scene, samples: int = 256) -> None:
    scene.render.engine = "CYCLES"
    c = scene.cycles
    c.device = "CPU"
    c.samples = samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = 0
    c.pixel_filter_type = "BOX"  # one sample lands in one pixel, as the rasteriser's pixel centres
    c.filter_width = 1.0
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 2


def check_cameras_match_colmap(scene, ws: Path, rng_points: np.ndarray) -> int:
    """Every SfM camera object: pose == COLMAP after conversion, and Blender projects points to COLMAP's pixels."""
    from backend.capture.colmap_io import read_model
    from backend.core.cameras import blender_matrix_world

    model = read_model(ws / "sparse" / "0")
    objs = {o["igs_frame"]: o for o in bpy.data.objects if o.type == "CAMERA" and "igs_frame" in o}
    assert sorted(objs) == [c.name for c in model.cameras]
    camera_objects = sub("camera_objects")
    for cam in model.cameras:
        obj = objs[cam.name]
        np.testing.assert_allclose(np.array(obj.matrix_world), blender_matrix_world(cam), atol=1e-5)
        camera_objects.use_frame_camera(scene, obj)
        uv, z = cam.project(rng_points)
        seen = z > 0.05
        for p, (u, v) in zip(rng_points[seen], uv[seen]):
            ndc = world_to_camera_view(scene, obj, Vector(p))
            np.testing.assert_allclose([ndc.x * cam.width, (1 - ndc.y) * cam.height], [u, v], atol=2e-3)
        back = camera_objects.sfm_view_from_object(scene, obj)
        np.testing.assert_allclose([back.fx, back.fy, back.cx, back.cy], [cam.fx, cam.fy, cam.cx, cam.cy], rtol=1e-5)
        np.testing.assert_allclose(back.R, cam.R, atol=1e-5)
        np.testing.assert_allclose(back.t, cam.t, atol=1e-4)
    return len(objs)


def flat_layer(kind: str, means: np.ndarray, scale, color: float):
    """Flat discs (thin along z, so their shortest axis is the floor's normal) of one grey colour."""
    import torch

    from backend.splats.gaussians import GaussianSet

    n = len(means)
    t = {"means": torch.tensor(means, dtype=torch.float32),
         "log_scales": torch.tensor(np.log(np.stack(np.broadcast_arrays(scale, scale, 0.004, np.zeros(n))[:3], 1)), dtype=torch.float32),
         "quats": torch.tensor(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), dtype=torch.float32),
         "opacity_logits": torch.full((n,), 5.0)}
    if kind == "residual":
        t["sh0"] = torch.full((n, 1, 3), -1.6)
        t["shN"] = torch.zeros((n, 0, 3))
    else:  # albedo stores the logit of its colour, shading the colour itself (igs_contract.layer_ply)
        t["colors"] = torch.full((n, 3), float(np.log(color / (1 - color)) if kind == "albedo" else color))
    return GaussianSet(kind, t, sh_degree=0)


def diffuse(name: str, value: float) -> bpy.types.Material:
    """A grey Diffuse BSDF material (the truth's mesh surfaces)."""
    return mesh_rig.diffuse_material(bpy, name, (value, value, value))


def truth_scene(scene, sky: float | None = None, samples: int = 32, name: str = "truth") -> bpy.types.Scene:
    """A scene of its own for Cycles' truth of ``scene``: its output size, the Standard view, ``samples``, a
    transparent film, and under a uniform white sky of strength ``sky`` (None: no world light)."""
    ts = bpy.data.scenes.new(name)
    ts.world = bpy.data.worlds.new(f"{name} sky")
    background = next(n for n in ts.world.node_tree.nodes if n.type == "BACKGROUND")
    background.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    background.inputs["Strength"].default_value = 0.0 if sky is None else sky
    ts.render.resolution_x, ts.render.resolution_y = scene.render.resolution_x, scene.render.resolution_y
    ts.render.resolution_percentage = 100
    ts.render.film_transparent = True
    ts.view_settings.view_transform = "Standard"
    cycles(ts, samples)
    ts.camera = scene.camera
    return ts


def render_still(ts: bpy.types.Scene, path: Path) -> np.ndarray:
    """F12 of ``ts`` written to the 32-bit EXR ``path`` and read back: linear (H, W, 4) float64, alpha last.
    The window keeps showing the scene it showed."""
    window = bpy.context.window
    previous = window.scene if window is not None else None
    ts.render.image_settings.file_format = "OPEN_EXR"
    ts.render.image_settings.color_depth = "32"
    ts.render.filepath = str(path)
    bpy.ops.render.render(write_still=True, scene=ts.name)
    image = bpy.data.images.load(ts.render.filepath)
    try:
        return sub("images").pixels(image).astype(np.float64)
    finally:
        bpy.data.images.remove(image)
        if previous is not None:
            window.scene = previous


FLOOR_ALBEDO, FLOOR_SHADING = 0.5, 0.4
"""The albedo and shading of :func:`floor_workspace`'s floor."""


def floor_capture(ws: Path) -> None:
    """A capture of three 48x36 views from above, 1.6 m out and 1.6 m up around the origin (grey images, 20
    points near z = 0), with its COLMAP model, ``transforms.json`` and ``capture.json``: the cameras of
    :func:`floor_workspace` and the other floor scenes."""
    import json

    import cv2

    from backend.capture.colmap_io import write_model
    from backend.capture.transforms_io import write_transforms
    from backend.core.cameras import Camera

    w, h = 48, 36
    cams = [Camera.look_at(f"frame_{i:04d}.png", [1.6 * np.cos(2.1 * i), 1.6 * np.sin(2.1 * i), 1.6], [0, 0, 0],
                           [0, 0, 1], w, h, 60) for i in range(3)]
    write_model(ws / "sparse" / "0", cams, np.random.default_rng(0).uniform(-0.5, 0.5, (20, 3)) * [1, 1, 0],
                np.full((20, 3), 128))
    write_transforms(ws / "transforms.json", cams)
    (ws / "images").mkdir(parents=True, exist_ok=True)
    for cam in cams:
        cv2.imwrite(str(ws / "images" / cam.name), np.full((h, w, 3), 128, np.uint8))
    (ws / "capture.json").write_text(json.dumps({"schema": 1, "source": {"kind": "test"},
                                                 "frames": [c.name for c in cams], "size": [w, h]}))


def floor_workspace(ws: Path, albedo: float = FLOOR_ALBEDO, shading=None) -> None:
    """Layers of a floor of flat discs on z = 0 (|x|, |y| <= 1), seen by three cameras from above
    (:func:`floor_capture`): albedo ``albedo``, shading :data:`FLOOR_SHADING` or ``shading(points)`` ((N, 3)
    disc centres -> (N,) grey values)."""
    import torch

    from backend.splats.ply import write_ply

    floor_capture(ws)
    g = np.arange(-1.0, 1.001, 0.05)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    layer = flat_layer("shading", floor, 0.035, FLOOR_SHADING)
    if shading is not None:
        grey = np.asarray(shading(floor), np.float32)
        layer.params["colors"].data[:] = torch.from_numpy(np.repeat(grey[:, None], 3, 1))
    write_ply(ws / "layers" / "albedo.ply", flat_layer("albedo", floor, 0.035, albedo))
    write_ply(ws / "layers" / "shading.ply", layer)
    write_ply(ws / "layers" / "residual.ply", flat_layer("residual", floor[::4], 0.035, 0.0))


def patch(img: np.ndarray, scene, point, r: int = 1) -> float:
    """Mean of the (2r+1)^2 pixels around the pixel that ``point`` (world) falls in."""
    h, w = img.shape[:2]
    p = world_to_camera_view(scene, scene.camera, Vector(point))
    col, row = int(p.x * w), int((1 - p.y) * h)
    return float(img[row - r:row + r + 1, col - r:col + r + 1].mean())
