"""Splat files in and out of Blender, in bpy's background mode (issue #33): Import Splat File (PLY in any
encoding, compressed PLY, .spz through ``igs convert``, the identity dialog), Export Layer PLY keeping a
baked edit's ``eps2d``, Export for Viewers (``igs export``) and Export Distilled Splat (``igs distil``).

The extension is built and installed as ``test_blender_addon.py`` does (its fixtures are reused). The
backend commands are a stand-in interpreter that records its argv and answers as the commands document
(a result event), so these tests do not wait for the commands or train anything.
"""

# ruff: noqa: F811  (test functions take the imported fixtures by name)
from __future__ import annotations

import json
import stat
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from backend.splats.ply import read_ply, write_ply  # noqa: E402
from igs_contract import layer_ply, manifest  # noqa: E402
from tests.support.blender import (  # noqa: E402
    MOD,
    PYTHON,
    ROOT,
    TextProbe,  # noqa: E402
    attr,
)
from tests.support.fake_backend import make_tiny_workspace  # noqa: E402
from tests.support.gaussians import random_gaussians  # noqa: E402
from tests.support.ply_columns import COMPRESSED, ENCODINGS, source_columns  # noqa: E402

STAND_IN = r'''#!{python}
"""python -m backend --events CMD ...: records its argv, writes what CMD writes, sends its result event."""
import json, os, shutil, sys
sys.path.insert(0, {root!r})
import numpy as np
from igs_contract import layer_ply
args = sys.argv[4:]
with open(os.environ["IGS_STAND_IN_LOG"], "a") as f:
    f.write(json.dumps(args) + "\n")
def emit(ev, **f):
    print(json.dumps({{"event": ev, **f}}), flush=True)
def opt(name, default=None):
    return args[args.index(name) + 1] if name in args else default
cmd = args[0]
emit("start", command=cmd, argv=args)
if cmd == "convert":
    out, kind, space = args[2], opt("--kind", "radiance"), opt("--space", "srgb")
    n = 7
    names = layer_ply.property_names(0)
    rec = np.zeros(n, dtype=[(k, "<f4") for k in names])
    rec["x"] = np.arange(n)
    rec["rot_0"] = 1
    comments = layer_ply.header_comments(kind, layer_ply.ENCODINGS[kind], space, 0)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    with open(out, "wb") as f:
        f.write(layer_ply.header_bytes(n, names, comments) + rec.tobytes())
    data = {{"out": out, "count": n, "kind": kind, "space": space,
            "identity": os.environ.get("IGS_STAND_IN_IDENTITY", "unknown")}}
elif cmd == "export":
    out = opt("--out")
    shutil.copy(os.path.join(args[1], "layers", opt("--layer") + ".ply"), out)
    data = {{"out": out, "count": 200, "format": opt("--format"), "clipped": int(os.environ.get("IGS_STAND_IN_CLIPPED", "0"))}}
elif cmd == "distil":
    out = opt("--out")
    shutil.copy(os.path.join(args[1], "layers", "albedo.ply"), out)
    data = {{"ply": out, "psnr": 31.25, "count": 200, "seconds": 12.0}}
else:
    emit("error", message=f"unknown command {{cmd}}")
    sys.exit(2)
emit("result", command=cmd, data=data)
emit("done", command=cmd, seconds=0.1)
'''


@pytest.fixture
def stand_in(tmp_path, monkeypatch, scene) -> Path:
    """The stand-in backend set as the add-on's interpreter; returns its argv log."""
    path = tmp_path / "python"
    path.write_text(STAND_IN.format(python=PYTHON, root=str(ROOT)))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    bpy.context.preferences.addons[MOD].preferences.backend_python = str(path)
    log = tmp_path / "argv.jsonl"
    monkeypatch.setenv("IGS_STAND_IN_LOG", str(log))
    return log


def calls(log: Path) -> list[list[str]]:
    return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []


def interop():
    return sys.modules[f"{MOD}.operators.interop"]


def test_operators_are_registered_with_a_file_import_entry(addon):
    for op in ("import_splat_file", "export_viewer", "export_distilled"):
        assert getattr(bpy.ops.igs, op).get_rna_type() is not None
    entries = bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
    assert sum(getattr(f, "__name__", "") == "menu_import" for f in entries) == 1  # once, after re-registering
    rna = bpy.ops.igs.export_viewer.get_rna_type().properties
    assert {i.identifier for i in rna["format"].enum_items} == {"ply", "compressed-ply", "spz", "splat"}
    assert {i.identifier for i in rna["layer"].enum_items} == {"albedo", "shading", "residual"}


@pytest.mark.parametrize("encoding", ["le", "be", "ascii"])
def test_standard_plys_import_in_any_encoding(scene, tmp_path, encoding):
    from plyfile import PlyData, PlyElement

    src = source_columns(n=30, sh_degree=1, seed=4)
    path = tmp_path / f"scan_{encoding}.ply"
    PlyData([PlyElement.describe(src, "vertex")], comments=layer_ply.header_comments("residual", "sh", "linear", 1),
            **ENCODINGS[encoding]).write(str(path))
    assert bpy.ops.igs.import_splat_file(filepath=str(path)) == {"FINISHED"}
    obj = bpy.data.objects[f"IGS {path.name}"]
    assert obj["igs_layer"] == "residual" and obj["igs_space"] == "linear" and obj["igs_sh_degree"] == 1
    assert obj["igs_imported_from"] == str(path) and bpy.context.view_layer.objects.active == obj
    np.testing.assert_array_equal(attr(obj, "position", 3, "vector"), np.stack([src[k] for k in "xyz"], 1))
    np.testing.assert_array_equal(attr(obj, "f_rest_01", 3, "vector")[:, 1], src["f_rest_3"])  # green, first
    assert "Imported 30 residual Gaussians" in scene.igs.last_report


def test_a_file_without_identity_is_never_guessed(scene):
    """From a script it has to be named; named, it loads as said."""
    with pytest.raises(RuntimeError, match="records no layer identity.*kind='radiance', space='srgb'"):
        bpy.ops.igs.import_splat_file(filepath=str(COMPRESSED))
    assert "IGS " + COMPRESSED.name not in bpy.data.objects
    assert bpy.ops.igs.import_splat_file(filepath=str(COMPRESSED), kind="radiance", space="srgb") == {"FINISHED"}
    obj = bpy.data.objects["IGS " + COMPRESSED.name]
    assert len(obj.data.points) == 300 and obj["igs_layer"] == "radiance" and obj["igs_space"] == "srgb"
    assert obj["igs_sh_degree"] == 1


def test_unknown_identity_opens_the_dialog_defaulting_to_radiance_srgb(scene, monkeypatch):
    """Invoked from the UI on such a file: the dialog, preset to what other tools write. When the file
    browser closes on one, execute hands over to invoke (background mode has no window, so the operator's
    own functions run here on a stand-in with its properties and a window manager that records the dialog)."""
    from types import SimpleNamespace

    op_cls = interop().IGS_OT_import_splat_file

    class Stand:
        """The operator's properties and its own methods (an operator instance needs a window to invoke)."""

        source, chosen, needs_choice, ask = (op_cls.__dict__[k] for k in ("source", "chosen", "needs_choice", "ask"))

        def __init__(self, **props):
            self.filepath, self.kind, self.space, self.asked, self.handed_over = "", "FROM_FILE", "FROM_FILE", False, False
            self.__dict__.update(props)

        def report(self, level, message):
            raise AssertionError(message)

    dialogs = []
    wm = SimpleNamespace(invoke_props_dialog=lambda op, **kw: dialogs.append((op.kind, op.space, op.asked, kw))
                         or {"RUNNING_MODAL"})
    context = SimpleNamespace(window_manager=wm, window=object(), scene=scene)
    monkeypatch.setattr(interop(), "interactive", lambda context: True)
    assert op_cls.invoke(Stand(filepath=str(COMPRESSED)), context, None) == {"RUNNING_MODAL"}
    ((kind, space, asked, kw),) = dialogs
    assert (kind, space, asked) == ("radiance", "srgb", True) and COMPRESSED.name in kw["title"]

    handed = []
    ops = SimpleNamespace(import_splat_file=lambda *a, **kw: handed.append((a, kw)) or {"FINISHED"})
    monkeypatch.setattr(bpy.ops, "igs", ops, raising=False)  # bpy.ops makes its submodules on each access
    assert op_cls.execute(Stand(filepath=str(COMPRESSED)), context) == {"FINISHED"}  # the file browser closed
    assert handed == [(("INVOKE_DEFAULT",), dict(filepath=str(COMPRESSED), kind="FROM_FILE", space="FROM_FILE",
                                                 handed_over=True))]
    monkeypatch.undo()

    # the dialog's OK: execute with the choice loads the file as chosen, without asking again
    assert bpy.ops.igs.import_splat_file(filepath=str(COMPRESSED), kind="albedo", space="linear") == {"FINISHED"}
    obj = bpy.data.objects["IGS " + COMPRESSED.name]
    assert obj["igs_layer"] == "albedo" and obj["igs_space"] == "linear" and obj["igs_sh_degree"] == 0
    assert len(dialogs) == 1


def test_a_sidecar_manifest_gives_the_identity(scene, tmp_path):
    """A foreign PLY (SH degree 1) whose manifest says albedo/linear loads as such, without a question."""
    src = source_columns(n=12, sh_degree=1, seed=5)
    path = tmp_path / "wall.ply"
    path.write_bytes(layer_ply.header_bytes(12, list(src.dtype.names), ["made by another tool"]) + src.tobytes())
    m = manifest.build(path, format="ply", kind="albedo", space="linear", encoding="rgb01", sh_degree=0, count=12)
    manifest.manifest_path(path).write_text(manifest.to_json(m))
    assert bpy.ops.igs.import_splat_file(filepath=str(path)) == {"FINISHED"}
    obj = bpy.data.objects["IGS wall.ply"]
    assert obj["igs_layer"] == "albedo" and obj["igs_space"] == "linear" and obj["igs_sh_degree"] == 0
    assert json.loads(obj["igs_comments"]) == ["made by another tool"]


def test_spz_is_converted_by_the_backend_then_loaded(scene, tmp_path, stand_in, monkeypatch):
    spz = tmp_path / "garden.spz"
    spz.write_bytes(b"stand-in bytes")
    with pytest.raises(RuntimeError, match="records no layer identity"):
        bpy.ops.igs.import_splat_file(filepath=str(spz))
    assert calls(stand_in) == []  # nothing started for a file that needs a choice first
    assert bpy.ops.igs.import_splat_file(filepath=str(spz), kind="shading", space="linear") == {"FINISHED"}
    (argv,) = calls(stand_in)
    assert argv[:2] == ["convert", str(spz)] and argv[2].endswith(".ply") and "intrinsic_splats_imports" in argv[2]
    assert argv[3:] == ["--kind", "shading", "--space", "linear"]
    obj = bpy.data.objects["IGS garden.spz"]
    assert obj["igs_layer"] == "shading" and len(obj.data.points) == 7 and obj["igs_ply"] == argv[2]

    # with a sidecar manifest the backend decides (no --kind/--space); a rewritten file is a warning
    m = manifest.Manifest(file=spz.name, format="spz", kind="residual", space="srgb", encoding="sh", sh_degree=0,
                          count=7, sha256="0" * 64, size=1)
    manifest.manifest_path(spz).write_text(manifest.to_json(m))
    monkeypatch.setenv("IGS_STAND_IN_IDENTITY", "manifest-changed")
    assert bpy.ops.igs.import_splat_file(filepath=str(spz)) == {"FINISHED"}
    argv = calls(stand_in)[-1]
    assert "--kind" not in argv and "--space" not in argv
    assert "manifest was written for other content" in scene.igs.last_report


def test_export_layer_keeps_a_baked_edits_eps2d(scene, tmp_path):
    g = random_gaussians("albedo", 60, 0, 9).with_filter(0.3)
    g.params["eps2d"].data[:20] = 0.05  # the edit's sharp Gaussians
    src = write_ply(tmp_path / "edited.ply", g)
    assert bpy.ops.igs.import_splat_file(filepath=str(src)) == {"FINISHED"}
    obj = bpy.data.objects["IGS edited.ply"]
    np.testing.assert_array_equal(attr(obj, "eps2d", 1, "value"), g.eps2d.detach().numpy())
    out = tmp_path / "back.ply"
    assert bpy.ops.igs.export_layer(filepath=str(out)) == {"FINISHED"}
    back, _ = read_ply(out)
    np.testing.assert_array_equal(back.eps2d.detach().numpy(), g.eps2d.detach().numpy())
    np.testing.assert_allclose(back.means.detach().numpy(), g.means.detach().numpy())

    plain = write_ply(tmp_path / "plain.ply", random_gaussians("albedo", 10, 0, 1))
    bpy.ops.igs.import_splat_file(filepath=str(plain))
    assert "eps2d" not in bpy.data.objects["IGS plain.ply"].data.attributes
    bpy.ops.igs.export_layer(filepath=str(tmp_path / "plain_back.ply"))
    assert b"eps2d" not in (tmp_path / "plain_back.ply").read_bytes()[:2000]  # the standard layout stays standard


@pytest.fixture
def workspace(scene, tmp_path) -> Path:
    ws = tmp_path / "ws"
    make_tiny_workspace(ws)
    for kind in ("albedo", "shading", "residual"):
        write_ply(ws / "layers" / f"{kind}.ply", random_gaussians(kind, 200, 0, 1))
    return ws


def test_exports_poll_on_a_workspace_and_a_backend(scene, workspace, stand_in):
    prefs = bpy.context.preferences.addons[MOD].preferences
    scene.igs.workspace = ""
    assert not bpy.ops.igs.export_viewer.poll() and not bpy.ops.igs.export_distilled.poll()
    scene.igs.workspace = str(workspace)
    assert bpy.ops.igs.export_viewer.poll() and bpy.ops.igs.export_distilled.poll()
    interpreter = prefs.backend_python
    prefs.backend_python = ""
    try:
        assert not bpy.ops.igs.export_viewer.poll()
    finally:
        prefs.backend_python = interpreter


def test_export_for_viewers_sends_the_choice_and_warns_about_clipping(scene, workspace, stand_in, monkeypatch,
                                                                       tmp_path):
    scene.igs.workspace = str(workspace)
    out = tmp_path / "out" / "wall.spz"
    out.parent.mkdir()
    assert bpy.ops.igs.export_viewer(filepath=str(out), layer="albedo", format="spz", edit="wall") == {"FINISHED"}
    assert calls(stand_in)[-1] == ["export", str(workspace), "--layer", "albedo", "--format", "spz",
                                   "--edit", "wall", "--out", str(out)]
    assert "Exported the albedo layer with wall" in scene.igs.last_report and "clipped" not in scene.igs.last_report
    monkeypatch.setenv("IGS_STAND_IN_CLIPPED", "12")
    # the file ending follows the format
    assert bpy.ops.igs.export_viewer(filepath=str(tmp_path / "out" / "a.ply"), layer="shading",
                                     format="compressed-ply") == {"FINISHED"}
    argv = calls(stand_in)[-1]
    assert argv[argv.index("--out") + 1] == str(tmp_path / "out" / "a.compressed.ply") and "--edit" not in argv
    assert "12 Gaussians had values outside what compressed-ply stores" in scene.igs.last_report
    with pytest.raises(RuntimeError, match="edit name"):
        bpy.ops.igs.export_viewer(filepath=str(out), edit="../x")


def test_export_distilled_runs_igs_distil_and_reports_its_psnr(scene, workspace, stand_in, tmp_path):
    scene.igs.workspace = str(workspace)
    out = tmp_path / "scene-distilled.ply"
    assert bpy.ops.igs.export_distilled(filepath=str(out), edit="wall", iterations=500) == {"FINISHED"}
    assert calls(stand_in)[-1] == ["distil", str(workspace), "--edit", "wall", "--out", str(out),
                                   "--iterations", "500"]
    assert out.is_file() and "31.25 dB PSNR" in scene.igs.last_report and "200 Gaussians" in scene.igs.last_report


def operators_drawn(panel: str) -> list[str]:
    """The operators the panel draws (into a stand-in layout checked against the real UILayout API)."""
    from types import SimpleNamespace

    cls = getattr(bpy.types, panel)

    class Self(SimpleNamespace):
        def __getattr__(self, name):  # the panel's own helpers
            return getattr(cls, name)

    texts: list = []
    cls.draw(Self(layout=TextProbe([], texts)), bpy.context)
    return [t[1] for t in texts if t[0] == "operator"]


def test_the_buttons_are_where_an_artist_looks(scene, workspace):
    scene.igs.workspace = str(workspace)
    assert {"igs.import_splat_file", "igs.export_viewer", "igs.export_distilled",
            "igs.export_layer"} <= set(operators_drawn("IGS_PT_layers"))
    assert {"igs.export_viewer", "igs.export_distilled"} <= set(operators_drawn("IGS_PT_edit"))


def test_round_trip_through_the_real_backend_export_and_convert(scene, workspace, tmp_path):
    """Export for Viewers writes an SPZ and its manifest with ``igs export``; Import Splat File brings it back
    through ``igs convert`` as the albedo it was, without a question (the manifest names its content)."""
    from tests.support.blender import need_command

    need_command("export")
    need_command("convert")
    scene.igs.workspace = str(workspace)
    out = tmp_path / "viewer" / "albedo.spz"
    out.parent.mkdir()
    assert bpy.ops.igs.export_viewer(filepath=str(out), layer="albedo", format="spz") == {"FINISHED"}
    assert out.is_file() and manifest.manifest_path(out).is_file()
    assert "200 Gaussians" in scene.igs.last_report
    assert bpy.ops.igs.import_splat_file(filepath=str(out)) == {"FINISHED"}
    obj = bpy.data.objects["IGS albedo.spz"]
    assert obj["igs_layer"] == "albedo" and obj["igs_space"] == "linear" and len(obj.data.points) == 200
    src, _ = read_ply(workspace / "layers" / "albedo.ply")
    got = attr(obj, "position", 3, "vector")
    want = src.means.detach().numpy()
    # Pair each centre with its nearest source centre: SPZ's fixed point moves them by < 1e-3, which can swap
    # the order of two centres with nearly equal x, so sorting by one coordinate does not pair them.
    from scipy.spatial import cKDTree

    dist, nearest = cKDTree(want).query(got)
    assert sorted(nearest) == list(range(len(want)))  # a one-to-one pairing
    np.testing.assert_allclose(got, want[nearest], atol=1e-3)  # SPZ's fixed-point centres
