"""Bad inputs of the workspace and of its sources end in one line naming the file, before the work
they would spoil (issue #50, reproducers 4-6): a metrics.json that is not UTF-8, a truncated JPEG in a
photo folder, prior maps of another shape than their frames, a depth map with NaN."""

import json

import numpy as np
import pytest

from backend.capture.importer import ImportConfig, import_capture
from backend.commands.cli import main
from backend.core.atomic_io import encode_image
from backend.core.errors import IGSError
from backend.core.imageio import check_image_file
from backend.eval.metrics_file import merge_metrics
from tests.support.import_scene import write_capture
from tests.support.train_scene import make_workspace


def one_error(capfd) -> str:
    err = capfd.readouterr().err
    lines = [ln for ln in err.splitlines() if ": error:" in ln]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "Warning" not in err, err
    return lines[0]


def test_a_metrics_file_that_is_not_utf8_stops_training_before_it_starts(tmp_path, capfd):
    ws = make_workspace(tmp_path / "ws", n_views=4, width=16, height=12)
    ws.metrics_json.write_bytes(b'{"decompose": "\xff\xfe caf\xe9"}')
    for argv in (["train-3dgs", str(ws.root), "--iterations", "2"], ["decompose", str(ws.root), "--iterations", "2"]):
        assert main(argv) == 2
        line = one_error(capfd)
        assert f"{ws.metrics_json}: the metrics file is not UTF-8 text" in line and "fix or delete it" in line
    assert not ws.checkpoints.exists() and not ws.layers.exists()  # stopped before training
    with pytest.raises(IGSError, match="not UTF-8"):
        merge_metrics(ws.metrics_json, "x", {})


def test_a_truncated_jpeg_in_a_photo_folder_is_one_error_naming_it(tmp_path, capfd):
    """libjpeg printed a bare "Premature end of JPEG file" from C above the error, naming no file."""
    photos = tmp_path / "photos"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for i in range(4):
        img = (rng.random((48, 64, 3)) * 255).astype(np.uint8)
        data = encode_image(photos / f"p{i}.jpg", img)
        (photos / f"p{i}.jpg").write_bytes(data[: len(data) // 2] if i == 2 else data)
    assert main(["import", str(photos), str(tmp_path / "ws")]) == 2
    err_line = one_error(capfd)
    assert f"{photos / 'p2.jpg'}: unreadable image (truncated JPEG" in err_line
    assert not (tmp_path / "ws").exists()


def test_a_complete_jpeg_passes_and_every_cut_of_it_is_refused(tmp_path):
    img = (np.random.default_rng(1).random((40, 56, 3)) * 255).astype(np.uint8)
    path = tmp_path / "a.jpg"
    data = encode_image(path, img)
    path.write_bytes(data + b"trailing bytes a camera appended")
    check_image_file(path)
    for cut in range(3, len(data) - 1, 37):
        path.write_bytes(data[:cut])
        with pytest.raises(IGSError, match="truncated JPEG"):
            check_image_file(path)


@pytest.fixture(scope="module")
def imported(tmp_path_factory):
    """A COLMAP project of 6 frames, 64x48, imported (a workspace with the frames' import records)."""
    root = tmp_path_factory.mktemp("maps")
    write_capture(root / "proj", n=6, width=64, height=48)
    import_capture(root / "proj", root / "ws", ImportConfig())
    return root / "ws"


def _maps(folder, ws, shape, suffix=".npy", value=None):
    folder.mkdir(exist_ok=True)
    for f in sorted((ws / "images").iterdir()):
        m = np.full(shape, 2.0 if value is None else value, np.float32)
        if suffix == ".npy":
            np.save(folder / f"{f.stem}.npy", m)
        else:
            (folder / f.name).write_bytes(encode_image(folder / f.name, (m * 60).astype(np.uint8)))
    return folder


@pytest.mark.parametrize("kind, shape, words", [
    ("depth", (1, 1), "too small for its 64x48 frame"),
    ("depth", (64, 10), "is 10x64, but its frame frame_0000.png is 64x48"),
    ("albedo", (200, 10, 3), "is 10x200, but its frame frame_0000.png is 64x48"),
    ("albedo", (6, 8, 3), "too small for its 64x48 frame"),
])
def test_prior_maps_must_have_their_frames_aspect_ratio_and_a_minimum_size(imported, tmp_path, capfd, kind, shape,
                                                                          words):
    before = json.loads((imported / "capture.json").read_text())
    folder = _maps(tmp_path / "maps", imported, shape, ".npy" if kind == "depth" else ".png")
    assert main(["priors", str(imported), f"--{kind}", f"folder:{folder}"]) == 2
    line = one_error(capfd)
    assert str(folder) in line and words in line, line
    assert json.loads((imported / "capture.json").read_text()) == before


def test_smaller_maps_of_the_right_shape_are_resized_and_said_so(imported, tmp_path, capfd):
    folder = _maps(tmp_path / "maps", imported, (24, 32))
    assert main(["priors", str(imported), "--depth", f"folder:{folder}"]) == 0
    err = capfd.readouterr().err
    assert f"depth: maps of 32x24 in {folder} are resized to their frames' 64x48" in err
    assert err.count("are resized") == 1


def test_a_depth_map_with_nan_is_refused_for_its_nan(imported, tmp_path, capfd):
    folder = _maps(tmp_path / "maps", imported, (48, 64))
    m = np.full((48, 64), 2.0, np.float32)
    m[3, 4] = np.nan
    np.save(folder / "frame_0001.npy", m)
    assert main(["priors", str(imported), "--depth", f"folder:{folder}"]) == 2
    line = one_error(capfd)
    assert "frame_0001.npy: the map holds 1 NaN value" in line and "shape" not in line
