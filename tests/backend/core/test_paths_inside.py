"""Names that come from inside files (COLMAP image names, transforms.json paths) or that name a
workspace folder (edit names) never lead outside: each is one clear error, nothing is read or
written elsewhere. Paths the user types are taken as given."""

import json
import shutil

import pytest

from backend.capture.importer import ImportConfig, import_capture
from backend.capture.load import load_capture
from backend.capture.transforms_io import read_transforms, write_transforms
from backend.commands.cli import main
from backend.core.errors import IGSError
from backend.core.paths import inside, plain_name, relative_name
from tests.support.import_scene import write_capture


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("paths") / "proj"
    cams = write_capture(root, n=6, width=48, height=36)
    write_transforms(root / "transforms.json", cams)
    return root


def _copy(project, tmp_path):
    dst = tmp_path / "proj"
    shutil.copytree(project, dst)
    return dst


def test_names_are_checked_on_the_path_as_written(tmp_path):
    assert plain_name("wall_decal-2.v1", "--edit") == "wall_decal-2.v1"
    for bad in ("../x", "..", ".", "a/b", "a\\b", "", "/etc", 5, None):
        with pytest.raises(IGSError, match="--edit must be a plain folder name"):
            plain_name(bad, "--edit")
    assert relative_name("sub/a.png", "m") == "sub/a.png"
    for bad in ("../a.png", "sub/../../a.png", "/etc/passwd", "", "a\0b", 3):
        with pytest.raises(IGSError, match="^m: "):
            relative_name(bad, "m")
    assert inside(tmp_path, "a/b.png", "t") == tmp_path / "a" / "b.png"
    assert inside(tmp_path, str(tmp_path / "c.png"), "t") == tmp_path / "c.png"  # absolute, but inside
    for bad in ("../a.png", "/etc/passwd", "a/../../b"):
        with pytest.raises(IGSError, match="leads outside"):
            inside(tmp_path, bad, "t")


def test_render_edit_names_stay_in_the_workspace(project, tmp_path, capsys):
    ws = tmp_path / "ws"
    import_capture(project, ws, ImportConfig())
    capsys.readouterr()
    victim = tmp_path / "x"
    victim.mkdir()
    for edit in ("../../x", "../x", "/tmp"):
        assert main(["render", str(ws), "--edit", edit, "--turntable", "--frames", "1"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--edit must be a plain folder name" in err[0]
    assert list(victim.iterdir()) == []
    assert main(["edit", "bake", str(ws), "--plane", str(tmp_path / "p.json"), "--name", "../evil"]) == 2
    assert "plain folder name" in capsys.readouterr().err


def test_colmap_image_names_with_dotdot_are_refused(project, tmp_path):
    proj = _copy(project, tmp_path)
    outside = tmp_path / "secret.png"
    shutil.copy(proj / "images" / "frame_0000.png", outside)  # readable, so only the check can stop it
    images_txt = proj / "sparse" / "0" / "images.txt"
    images_txt.write_text(images_txt.read_text().replace(" frame_0000.png", " ../../secret.png"))
    with pytest.raises(IGSError, match=r"sparse/0 \(image name\): the path '../../secret.png' leads outside"):
        import_capture(proj, tmp_path / "ws", ImportConfig())
    # the same name in a workspace's own model
    (proj / "capture.json").write_text(json.dumps({"schema": 1}))
    with pytest.raises(IGSError, match="image name.*leads outside"):
        load_capture(proj)


@pytest.mark.parametrize("key,value", [("file_path", "/etc/passwd"), ("file_path", "../../secret"),
                                       ("ply_file_path", "/etc/passwd"), ("ply_file_path", "../points.ply")])
def test_transforms_paths_pointing_anywhere_are_refused(project, tmp_path, key, value):
    proj = _copy(project, tmp_path)
    (tmp_path / "secret.png").write_bytes((proj / "images" / "frame_0000.png").read_bytes())
    (tmp_path / "points.ply").write_text("ply\n")
    data = json.loads((proj / "transforms.json").read_text())
    if key == "file_path":
        data["frames"][0]["file_path"] = value
    else:
        data["ply_file_path"] = value
    (proj / "transforms.json").write_text(json.dumps(data))
    with pytest.raises(IGSError, match=f"{key}: the path '{value}' leads outside"):
        read_transforms(proj / "transforms.json")
    ws = tmp_path / "ws"
    assert main(["import", str(proj / "transforms.json"), str(ws)]) == 2
    assert not ws.exists() or not (ws / "images").exists()


def test_paths_inside_the_source_still_work(project, tmp_path):
    proj = _copy(project, tmp_path)
    data = json.loads((proj / "transforms.json").read_text())
    data["frames"][0]["file_path"] = str(proj / "images" / "frame_0000.png")  # absolute, inside
    data["frames"][1]["file_path"] = "images/../images/frame_0001.png"
    (proj / "transforms.json").write_text(json.dumps(data))
    ds = read_transforms(proj / "transforms.json")
    assert ds.frames[1].image == proj / "images" / "frame_0001.png"
