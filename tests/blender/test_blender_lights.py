"""The lights collection in bpy's background mode: Blender lights -> the lights file, the renders' arguments,
and the live light bake of the viewport's shading layer.

The extension is installed as ``test_blender_addon.py`` does (its fixtures are reused). The lights file is
read back with the backend's own reader (``igs_contract.light_json``). The renders and the bake run a
backend double that records its arguments and checks the lights file with the same reader; the last test
runs the real backend's ``igs render --light``.
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import json
import math
import stat
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from mathutils import Euler, Matrix, Vector  # noqa: E402

from igs_contract.layer_ply import C0  # noqa: E402
from igs_contract.light_json import read_lights  # noqa: E402
from tests.support.blender import MOD, PYTHON, ROOT, flat_layer, floor_capture, sub, write_layers  # noqa: E402
from tests.support.fake_backend import make_tiny_workspace  # noqa: E402

LIGHTS_DOUBLE = r'''#!{python}
import json, sys
from pathlib import Path
import numpy as np
sys.path[:0] = [{root!r}]
from tests.support import addon_package  # the extension as a package, as Blender imports it
from intrinsic_splats.igs_blender.ply_io import read_splat_ply, write_splat_ply
from intrinsic_splats.igs_contract.light_json import read_lights

def emit(ev, **f):
    print(json.dumps({{"event": ev, **f}}), flush=True)

argv = [str(a) for a in sys.argv[4:]]
cmd, ws = argv[0], Path(argv[1])
emit("start", command=cmd, argv=argv)
with open(ws / "argv.jsonl", "a") as f:
    f.write(json.dumps(argv) + "\n")
def opt(name, default=None):
    return argv[argv.index(name) + 1] if name in argv else default
if cmd == "light-bake":
    lights = read_lights(opt("--light"))  # the backend's reader of what Blender wrote
    emit("stage", stage="light-bake", total=len(lights))
    s = read_splat_ply(ws / "layers" / "shading.ply")
    s.f_dc = s.f_dc + 0.25 * len(lights)  # a lit shading layer: brighter by the number of lights
    out = write_splat_ply(ws / "layers" / "lit" / "shading.ply", s)
    (ws / "layers" / "lit" / "light.json").write_text(Path(opt("--light")).read_text())
    for i in range(len(lights)):
        emit("progress", stage="light-bake", step=i + 1, total=len(lights), eta_s=0.0)
    emit("output", kind="layer", path=str(out))
elif cmd == "render":
    import cv2
    if "--light" in argv:
        read_lights(opt("--light"))
    out, layer = Path(opt("--out")), opt("--layers")
    if "--turntable" in argv:
        names, size = [f"{{k:04d}}" for k in range(int(opt("--frames")))], (int(argv[argv.index("--size") + 1]), int(argv[argv.index("--size") + 2]))
    else:
        cams = json.loads(Path(opt("--cameras")).read_text())["cameras"]
        names, size = [c["name"] for c in cams], (cams[0]["width"], cams[0]["height"])
    (out / layer).mkdir(parents=True, exist_ok=True)
    for n in names:
        cv2.imwrite(str(out / layer / f"{{n}}.png"), np.full((size[1], size[0], 3), 90, np.uint8))
    emit("output", kind=f"render_{{layer}}", path=str(out / layer))
else:
    emit("error", message=f"the lights double has no {{cmd}}")
    sys.exit(2)
emit("done", command=cmd, seconds=0.1)
'''


@pytest.fixture(scope="module")
def lights_python(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("lights") / "python"
    path.write_text(LIGHTS_DOUBLE.format(python=PYTHON, root=str(ROOT)))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def add_light(coll, name: str, kind: str, matrix: Matrix, **settings) -> bpy.types.Object:
    data = bpy.data.lights.new(name, kind)
    for key, value in settings.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(name, data)
    coll.objects.link(obj)
    obj.matrix_world = matrix
    return obj


def placed(x, y, z, rx=0.0, ry=0.0, rz=0.0, scale=(1.0, 1.0, 1.0)) -> Matrix:
    return Matrix.LocRotScale(Vector((x, y, z)), Euler((rx, ry, rz)), Vector(scale))


def minus_z(m: Matrix) -> np.ndarray:
    d = -np.array(m.to_3x3().normalized().col[2])
    return d / np.linalg.norm(d)


def test_lights_collection_round_trips_through_the_contract_reader(scene, tmp_path):
    """Every light type, a scaled area light, Blender's colour and power settings; a hidden light, a light
    outside the collection and a mesh inside it are left out."""
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    scene.igs.workspace = str(ws)
    assert bpy.ops.igs.add_light_collection() == {"FINISHED"}
    coll = scene.igs.light_collection
    assert coll.name == "IGS Lights" and coll in scene.collection.children_recursive
    add_light(coll, "Key Light", "POINT", placed(1.0, 0.5, 2.2), energy=60.0, color=(1.0, 0.9, 0.8),
              shadow_soft_size=0.02)
    spot_m = placed(0.0, -1.0, 2.4, rx=0.6)
    add_light(coll, "cone", "SPOT", spot_m, energy=120.0, spot_size=1.05, spot_blend=0.3, exposure=1.0)
    sun_m = placed(0.0, 0.0, 5.0, rx=0.3, ry=-0.2)
    add_light(coll, "sky", "SUN", sun_m, energy=3.0, angle=0.05)
    box_m = placed(2.5, 0.0, 2.0, ry=-1.0, rz=0.4, scale=(2.0, 1.5, 1.0))
    add_light(coll, "box", "AREA", box_m, energy=80.0, shape="RECTANGLE", size=0.6, size_y=0.36)
    add_light(coll, "disk", "AREA", placed(0.0, 0.0, 3.0), energy=10.0, shape="DISK", size=0.5, normalize=False)
    hidden = add_light(coll, "hidden", "POINT", placed(0, 0, 1), energy=5.0)
    hidden.hide_set(True)
    off = add_light(coll, "render off", "POINT", placed(0, 0, 1), energy=5.0)
    off.hide_render = True
    add_light(scene.collection, "elsewhere", "POINT", placed(0, 0, 1), energy=5.0)
    mesh = bpy.data.objects.new("a mesh", bpy.data.meshes.new("a mesh"))
    coll.objects.link(mesh)
    bpy.context.view_layer.update()

    lights_mod = sub("lights")
    path = lights_mod.write_scene_lights(scene, ws)
    assert path == ws / "lights" / "scene_lights.json"
    got = {li["name"]: li for li in read_lights(path)}
    assert sorted(got) == ["Key_Light", "box", "cone", "disk", "sky"]

    key = got["Key_Light"]
    assert key["type"] == "point" and key["power"] == pytest.approx(60.0) and key["radius"] == pytest.approx(0.02)
    np.testing.assert_allclose(key["position"], [1.0, 0.5, 2.2], atol=1e-6)
    np.testing.assert_allclose(key["color"], [1.0, 0.9, 0.8], atol=1e-6)
    cone = got["cone"]
    assert cone["power"] == pytest.approx(240.0)  # 120 W at an exposure of 1
    assert cone["spot_size"] == pytest.approx(1.05) and cone["spot_blend"] == pytest.approx(0.3)
    np.testing.assert_allclose(cone["direction"], minus_z(spot_m), atol=1e-6)
    sky = got["sky"]
    assert sky["position"] is None and sky["power"] == pytest.approx(3.0) and sky["angle"] == pytest.approx(0.05)
    np.testing.assert_allclose(sky["direction"], minus_z(sun_m), atol=1e-6)
    box = got["box"]
    assert box["shape"] == "rectangle" and box["power"] == pytest.approx(80.0)
    assert box["size"] == pytest.approx(1.2) and box["size_y"] == pytest.approx(0.54)  # times the object's scale
    np.testing.assert_allclose(box["position"], [2.5, 0.0, 2.0], atol=1e-6)
    np.testing.assert_allclose(box["direction"], minus_z(box_m), atol=1e-6)
    np.testing.assert_allclose(box["x_axis"], np.array(box_m.to_3x3().normalized().col[0]), atol=1e-6)
    disk = got["disk"]  # Normalize off: the power is per square metre
    assert disk["shape"] == "disk" and disk["power"] == pytest.approx(10.0 * math.pi / 4 * 0.25)
    assert "written by the Blender add-on" in json.loads(path.read_text())["note"]

    # The capture's empty maps SfM to Blender: the file is in SfM units, the power scaled with them.
    root = sub("scene_objects").capture_root()
    root.matrix_world = Matrix.LocRotScale(Vector((1.0, 2.0, 0.0)), Euler((0.0, 0.0, 0.5)), Vector((2.0, 2.0, 2.0)))
    bpy.context.view_layer.update()
    got = {li["name"]: li for li in read_lights(lights_mod.write_scene_lights(scene, ws))}
    sfm = root.matrix_world.inverted() @ Vector((1.0, 0.5, 2.2))
    np.testing.assert_allclose(got["Key_Light"]["position"], list(sfm), atol=1e-6)
    assert got["Key_Light"]["power"] == pytest.approx(15.0) and got["sky"]["power"] == pytest.approx(3.0)
    assert got["box"]["size"] == pytest.approx(0.6)

    for obj in list(coll.objects):  # an empty collection is one clear error
        bpy.data.objects.remove(obj)
    with pytest.raises(Exception, match="holds no visible point, spot, sun or area light"):
        lights_mod.write_scene_lights(scene, ws)


def _ready_workspace(scene, tmp_path, backend: Path) -> Path:
    ws = tmp_path / "ws"
    make_tiny_workspace(ws, size=(32, 24))
    write_layers(ws)
    scene.igs.workspace = str(ws)
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(backend)
    bpy.ops.igs.load_cameras()
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    return ws


def _argvs(ws: Path) -> list[list[str]]:
    return [json.loads(ln) for ln in (ws / "argv.jsonl").read_text().splitlines()]


def test_render_view_and_turntable_pass_the_lights_and_the_baked_edit(scene, tmp_path, lights_python):
    ws = _ready_workspace(scene, tmp_path, lights_python)
    props = scene.igs
    scene.camera = bpy.data.objects["IGS frame_0001"]
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    assert "--light" not in _argvs(ws)[-1]  # no lights collection: the captured light only

    bpy.ops.igs.add_light(kind="POINT")
    light = bpy.context.active_object
    assert light.type == "LIGHT" and light.name in props.light_collection.objects
    item = props.edits.add()  # a baked edit selected in the Edit panel
    item.name, item.baked = "wall", True
    props.render_edit = True
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    argv = _argvs(ws)[-1]
    assert argv[argv.index("--light") + 1] == str(ws / "lights" / "scene_lights.json")
    assert argv[argv.index("--edit") + 1] == "wall"
    out = Path(argv[argv.index("--out") + 1])
    assert out.name.startswith("view-lit-") and (out / "full" / "view.png").is_file()
    assert [li["name"] for li in read_lights(ws / "lights" / "scene_lights.json")] == ["IGS_Point"]

    props.turntable_target, props.turntable_frames, props.write_mp4 = "CAPTURE", 3, False
    assert bpy.ops.igs.render_sequence(mode="TURNTABLE") == {"FINISHED"}, props.last_report
    argv = _argvs(ws)[-1]
    assert "--turntable" in argv and "--light" in argv and "--edit" in argv
    assert Path(argv[argv.index("--out") + 1]).name.startswith("turntable-lit-")

    props.use_lights = False  # Use Lights off: as without lights
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    assert "--light" not in _argvs(ws)[-1]
    props.use_lights = True
    light.hide_set(True)  # only hidden lights: as without lights
    bpy.context.view_layer.update()
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    assert "--light" not in _argvs(ws)[-1]


def _run_pending(bake, start: float) -> None:
    """Drive the live bake's timer as Blender would, past the debounce, until it has nothing left to do."""
    assert bake.tick(now=start + 0.5) == 0.25 and bake.LIVE.job is None  # the lights are still moving
    interval = bake.tick(now=start + bake.DEBOUNCE_S + 0.01)
    deadline = time.monotonic() + 60
    while interval is not None and time.monotonic() < deadline:
        time.sleep(0.05)
        interval = bake.tick(now=time.monotonic() + 10)
    assert interval is None and bake.LIVE.job is None


def test_moving_a_light_in_the_collection_rebakes_the_shading_layer(scene, tmp_path, lights_python):
    ws = _ready_workspace(scene, tmp_path, lights_python)
    bake = sub("light_bake")
    bake.LIVE.reset()
    props = scene.igs
    shading = bpy.data.objects["IGS shading"]
    unlit_dc = sub("display").layer_from_object(shading).f_dc.copy()

    bpy.ops.igs.add_light(kind="POINT")
    light = bpy.context.active_object
    light.location = (0.3, 0.2, 1.0)
    bpy.context.view_layer.update()  # the depsgraph handler sees the new light
    assert bake.LIVE.want and bake.LIVE.job is None
    _run_pending(bake, bake.LIVE.changed_at)
    shading = bpy.data.objects["IGS shading"]
    assert Path(shading["igs_ply"]) == ws / "layers" / "lit" / "shading.ply", props.last_report
    np.testing.assert_allclose(sub("display").layer_from_object(shading).f_dc, unlit_dc + 0.25, atol=1e-5)
    assert "lit by 1 light(s)" in props.last_report and props.job_label == "Light bake"
    sent = read_lights(ws / "layers" / "lit" / "light.json")
    np.testing.assert_allclose(sent[0]["position"], [0.3, 0.2, 1.0], atol=1e-6)

    other = bpy.data.objects.new("not a light", bpy.data.meshes.new("m"))  # outside the lights: no bake
    scene.collection.objects.link(other)
    other.location.x = 3.0
    outside = bpy.data.objects.new("other lamp", bpy.data.lights.new("other lamp", "POINT"))
    scene.collection.objects.link(outside)
    bpy.context.view_layer.update()
    assert bake.LIVE.want is None

    light.location.x = -0.4  # a moved light: baked again from its new place
    bpy.context.view_layer.update()
    assert bake.LIVE.want
    _run_pending(bake, bake.LIVE.changed_at)
    assert read_lights(ws / "layers" / "lit" / "light.json")[0]["position"][0] == pytest.approx(-0.4)
    assert len(_argvs(ws)) == 2 and _argvs(ws)[-1][:2] == ["light-bake", str(ws)]

    light.hide_set(True)  # the collection has no visible light: the unlit shading is back, without a job
    bpy.context.view_layer.update()
    _run_pending(bake, bake.LIVE.changed_at)
    shading = bpy.data.objects["IGS shading"]
    assert Path(shading["igs_ply"]) == ws / "layers" / "shading.ply" and not shading.get("igs_lights")
    np.testing.assert_allclose(sub("display").layer_from_object(shading).f_dc, unlit_dc, atol=1e-6)
    assert len(_argvs(ws)) == 2

    light.hide_set(False)  # Bake Lights from the panel, as a script calls it
    bpy.context.view_layer.update()
    bake.LIVE.reset()
    assert bpy.ops.igs.bake_lights() == {"FINISHED"}, props.last_report
    assert Path(bpy.data.objects["IGS shading"]["igs_ply"]).parent.name == "lit"


def test_a_failed_bake_is_one_report_and_not_retried_until_the_lights_change(scene, tmp_path, lights_python):
    ws = _ready_workspace(scene, tmp_path, lights_python)
    bake = sub("light_bake")
    bake.LIVE.reset()
    (ws / "layers" / "shading.ply").write_text("not a ply")  # the double's read fails: a crash
    bpy.ops.igs.add_light(kind="SPOT")
    bpy.context.view_layer.update()
    _run_pending(bake, bake.LIVE.changed_at)
    report = scene.igs.last_report
    assert report.startswith("Light bake failed") and "Traceback" not in report
    bpy.context.view_layer.update()
    assert bake.LIVE.want is None  # the same lights: not started again
    bpy.context.active_object.location.z += 0.5
    bpy.context.view_layer.update()
    assert bake.LIVE.want


def test_real_backend_renders_the_view_lit(scene, tmp_path):
    """``igs render --light`` of the real backend, from Render View: the light brightens the composite."""
    ws = _ready_workspace(scene, tmp_path, Path(PYTHON))
    props = scene.igs
    scene.camera = bpy.data.objects["IGS frame_0001"]
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    unlit = next((ws / "renders").glob("view-2*"))
    bpy.ops.igs.add_light(kind="POINT")
    light = bpy.context.active_object
    light.location = scene.camera.location
    light.data.energy = 200.0
    bpy.context.view_layer.update()
    assert bpy.ops.igs.render_view() == {"FINISHED"}, props.last_report
    lit = next((ws / "renders").glob("view-lit-*"))
    import cv2

    a = cv2.imread(str(unlit / "full" / "view.png")).astype(float)
    b = cv2.imread(str(lit / "full" / "view.png")).astype(float)
    assert a.shape == b.shape and b.mean() > a.mean() + 1.0, (a.mean(), b.mean())


FLOOR_XY = np.arange(-0.6, 0.61, 0.15)
"""The floor's Gaussians: a 9 x 9 grid on z = 0 (x and y in -0.6 .. 0.6), among them (+-0.45, 0, 0)."""
PLATE = (0.15, 0.30, -0.10, 0.10, 0.5)
"""The occluder: an opaque plate over x in 0.15 .. 0.30, y in -0.1 .. 0.1, at z = 0.5."""


def floor_workspace(ws: Path) -> np.ndarray:
    """A workspace whose layers are a floor and a plate above it, seen from above by three views
    (:func:`tests.support.blender.floor_capture`); returns the shading Gaussians' centres (the floor's 81, then
    the plate's)."""
    from backend.splats.ply import write_ply

    floor_capture(ws)
    gx, gy = np.meshgrid(FLOOR_XY, FLOOR_XY, indexing="ij")
    floor = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], 1)
    x0, x1, y0, y1, z = PLATE
    px, py = np.meshgrid(np.linspace(x0, x1, 7), np.linspace(y0, y1, 9), indexing="ij")
    plate = np.stack([px.ravel(), py.ravel(), np.full(px.size, z)], 1)
    both = np.concatenate([floor, plate])
    # Small discs for the plate, so that its shadow is the plate's: a shadow map holds the expected depth of
    # the texel, so a wide disc's faint tail in front of the floor pulls that depth nearer than the depth
    # bias, and the plate's discs as wide as the floor's (0.06 m) shadow the floor under the light too.
    scale = np.concatenate([np.full(len(floor), 0.06), np.full(len(plate), 0.02)])
    write_ply(ws / "layers" / "albedo.ply", flat_layer("albedo", both, scale, 0.6))
    write_ply(ws / "layers" / "shading.ply", flat_layer("shading", both, scale, 0.5))
    write_ply(ws / "layers" / "residual.ply", flat_layer("residual", floor[::4], 0.06, 0.0))
    return both


def _point_light_shading(power: float, light: np.ndarray, at: np.ndarray) -> float:
    """The closed form of a point light's diffuse shading on the floor (normal +z): P / (4 pi r^2) cos / pi."""
    d = light - at
    r2 = float(d @ d)
    return power / (4 * math.pi * r2) * (d[2] / math.sqrt(r2)) / math.pi


def _bake_in_real_time(bake, timeout: float = 300.0) -> float:
    """Run the live bake's timer as Blender does, in real time, from a change the depsgraph handler saw until
    it has nothing left to do; returns the seconds from that change to the swap."""
    assert bake.LIVE.want is not None and bake.bpy.app.timers.is_registered(bake.tick)
    bake.bpy.app.timers.unregister(bake.tick)  # background bpy runs no timers: this loop is the timer
    t0 = bake.LIVE.changed_at
    interval = 0.25
    while interval is not None and time.monotonic() - t0 < timeout:
        time.sleep(interval)
        interval = bake.tick()
    assert interval is None and bake.LIVE.job is None, "the bake did not finish in time"
    return time.monotonic() - t0


def test_real_light_bake_lights_the_floor_with_the_plates_shadow_and_follows_the_light(scene, tmp_path):
    """The live bake runs the real ``light-bake`` through the add-on's jobs: the lit shading replaces the unlit
    one, the floor beside the light brightens as the closed form says, the floor in the plate's shadow does
    not; moved over the plate's other side, the light lights and shadows the other way round."""
    from backend.splats.ply import read_ply

    ws = tmp_path / "ws"
    centres = floor_workspace(ws)
    scene.igs.workspace = str(ws)
    bpy.context.preferences.addons[MOD].preferences.backend_python = PYTHON
    bpy.ops.igs.load_cameras()
    assert bpy.ops.igs.load_layers() == {"FINISHED"}, scene.igs.last_report
    bake = sub("light_bake")
    bake.LIVE.reset()
    props = scene.igs
    left = int(np.argmin(np.linalg.norm(centres - [-0.45, 0.0, 0.0], axis=1)))
    right = int(np.argmin(np.linalg.norm(centres - [0.45, 0.0, 0.0], axis=1)))
    unlit = read_ply(ws / "layers" / "shading.ply", kind="shading")[0].params["colors"].detach().numpy()

    def baked(light_at) -> tuple[np.ndarray, float]:
        light.location = light_at
        bpy.context.view_layer.update()  # the depsgraph handler sees the change
        seconds = _bake_in_real_time(bake)
        shading = bpy.data.objects["IGS shading"]
        assert Path(shading["igs_ply"]) == ws / "layers" / "lit" / "shading.ply", props.last_report
        assert shading["igs_lights"] == bake.wanted_key(scene)  # it shows the lights as they are now
        sent = read_lights(ws / "layers" / "lit" / "light.json")
        np.testing.assert_allclose(sent[0]["position"], light_at, atol=1e-6)
        lit = read_ply(ws / "layers" / "lit" / "shading.ply", kind="shading")[0].params["colors"].detach().numpy()
        ply_io, display = sub("ply_io"), sub("display")
        np.testing.assert_allclose(display.layer_from_object(shading).f_dc,
                                   ply_io.read_splat_ply(ws / "layers" / "lit" / "shading.ply").f_dc, atol=1e-6)
        return (lit - unlit).mean(axis=1), seconds

    bpy.ops.igs.add_light(kind="POINT")
    light = bpy.context.active_object
    light.data.energy, light.data.shadow_soft_size = 100.0, 0.0
    first = np.array([0.0, 0.0, 1.0])  # the plate's shadow falls on x in 0.3 .. 0.6: the right is in it
    added, seconds = baked(first)
    assert "lit by 1 light(s)" in props.last_report and props.job_label == "Light bake"
    expect = _point_light_shading(100.0, first, centres[left])
    assert 0.6 * expect < added[left] < 1.3 * expect, (added[left], expect)
    assert added[right] < 0.1 * expect, (added[right], expect)
    centre = int(np.argmin(np.linalg.norm(centres, axis=1)))  # under the light, beside the plate's shadow
    assert 0.6 * _point_light_shading(100.0, first, centres[centre]) < added[centre]

    second = np.array([0.9, 0.0, 1.0])  # moved: the shadow falls on x in -0.6 .. -0.3, the left is in it
    moved, seconds2 = baked(second)
    expect = _point_light_shading(100.0, second, centres[right])
    assert 0.6 * expect < moved[right] < 1.3 * expect, (moved[right], expect)
    assert moved[left] < 0.1 * expect, (moved[left], expect)
    print(f"\nlight-bake, handler's trigger to swap: {seconds:.2f} s, then {seconds2:.2f} s "
          f"({len(centres)} shading Gaussians, {len(centres)} albedo Gaussians, 3 views of 48x36)")


def test_lights_panel_says_which_lights_light_the_splats(scene, tmp_path, lights_python):
    from tests.support.blender import draw, shown_text

    ws = _ready_workspace(scene, tmp_path, lights_python)
    texts = draw("IGS_PT_lights")
    assert ("operator", "igs.add_light_collection", None, None) in texts
    assert "No lights collection: Add Light Collection makes 'IGS Lights'" in shown_text(texts)
    assert "Viewport shading: the captured light only" in shown_text(texts)
    bpy.ops.igs.add_light_collection()
    texts = draw("IGS_PT_lights")
    assert "'IGS Lights' holds no visible light" in shown_text(texts)
    assert ("operator", "igs.add_light_collection", None, None) not in texts
    assert {p for fn, p, _, _ in texts if fn == "prop"} >= {"use_lights", "live_lights", "light_collection"}
    bpy.ops.igs.add_light(kind="POINT")
    bpy.ops.igs.add_light(kind="AREA")
    sub("light_bake").LIVE.reset()
    assert bpy.ops.igs.bake_lights() == {"FINISHED"}, scene.igs.last_report
    got = shown_text(draw("IGS_PT_lights"))
    assert "'IGS Lights': 1 area, 1 point light(s) light the splats" in got
    assert "Viewport shading: lit by 2 light(s) (layers/lit/shading.ply)" in got
    assert any(t and t.startswith("Shading + lights") for _, _, t, _ in draw("IGS_PT_layers"))
    assert (ws / "layers" / "lit" / "shading.ply").is_file()


@pytest.fixture
def native_scene(addon):
    """Blender 5.3's native splats on (the point-cloud path is the ``scene`` fixture's)."""
    if bpy.app.version < (5, 3, 0):
        pytest.skip(f"native splats need Blender 5.3 (this bpy is {bpy.app.version_string})")
    bpy.ops.wm.read_homefile(use_empty=True)
    prefs = bpy.context.preferences.addons[MOD].preferences
    prefs.backend_python = PYTHON
    prefs.native_splats = True
    return bpy.context.scene


def test_native_f12_multiplies_the_baked_shading_field(native_scene, tmp_path, lights_python):
    """Blender 5.3: the lit shading becomes the shading field's splat object, and F12's Shading output (the
    compositor's) is brighter by what the bake added; emptying the collection puts the captured shading back."""
    from tests.support.blender import load, render_outputs, wall_workspace

    scene = native_scene
    ws, _ = wall_workspace(tmp_path)
    load(scene, ws)
    scene.cycles.samples = 16
    before = render_outputs(scene, tmp_path / "unlit", ("Shading",))["Shading"]
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(lights_python)
    bake = sub("light_bake")
    bake.LIVE.reset()
    bpy.ops.igs.add_light(kind="SUN")
    assert bpy.ops.igs.bake_lights() == {"FINISHED"}, scene.igs.last_report
    shading = bpy.data.objects["IGS shading"]
    assert sub("native.splats").is_native(shading) and Path(shading["igs_ply"]).parent.name == "lit"
    assert shading.name in bpy.data.collections["IGS Field shading"].objects
    after = render_outputs(scene, tmp_path / "lit", ("Shading",))["Shading"]
    covered = before.max(axis=2) > 0.05
    gain = float((after - before)[covered].mean())
    added = 0.25 * C0  # the double adds 0.25 to every shading Gaussian's DC: C0 * 0.25 to its colour
    assert 0.75 * added < gain < 1.05 * added, (gain, added)  # seen through the splats' alpha, above 0.9 here

    for obj in list(scene.igs.light_collection.objects):
        bpy.data.objects.remove(obj)
    assert bpy.ops.igs.bake_lights() == {"FINISHED"}, scene.igs.last_report
    assert Path(bpy.data.objects["IGS shading"]["igs_ply"]) == ws / "layers" / "shading.ply"
    again = render_outputs(scene, tmp_path / "unlit2", ("Shading",))["Shading"]
    np.testing.assert_allclose(again, before, atol=1e-4)
