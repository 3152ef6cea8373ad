"""`igs import` keeps frames at a longer side of 1600 px by default and says so, and the step after it
is named: without albedo maps, the import's end and decompose's error name `igs priors ... --albedo`.

The capture is the analytic room of ``_import_scene`` (8 views, 160x120)."""

import json

import pytest

from backend.capture.importer import ImportConfig
from backend.capture.transforms_io import write_transforms
from backend.commands.cli import main
from tests.support.import_scene import write_capture


@pytest.fixture(scope="module")
def transforms(tmp_path_factory):
    root = tmp_path_factory.mktemp("room")
    cams = write_capture(root, n=8)
    write_transforms(root / "transforms.json", cams)
    return root / "transforms.json"


def test_default_size_is_said_and_the_albedo_step_is_named(transforms, tmp_path, capsys):
    assert ImportConfig().selection.max_side == 1600
    ws = tmp_path / "ws"
    assert main(["import", str(transforms), str(ws), "--threads", "2"]) == 0
    err = capsys.readouterr().err
    assert ("import: frames are 160x120, at most 1600 px on the longer side (--max-side; --max-side 0 keeps "
            "the full size)") in err
    assert f"import: no albedo maps yet: `igs decompose` needs them; make them with `igs priors {ws} --albedo " \
           "marigold`" in err
    assert "s per frame on a CPU" in err  # what it costs
    assert main(["decompose", str(ws), "--iterations", "4"]) == 2
    line = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()][-1]
    assert "albedo maps missing for 8 of 8 views" in line and f"`igs priors {ws} --albedo marigold`" in line


def test_max_side_downscales_and_zero_keeps_the_size(transforms, tmp_path, capsys):
    small, full = tmp_path / "small", tmp_path / "full"
    assert main(["import", str(transforms), str(small), "--threads", "2", "--max-side", "80"]) == 0
    assert "import: frames are 80x60, at most 80 px on the longer side" in capsys.readouterr().err
    assert json.loads((small / "import_report.json").read_text())["size"] == [80, 60]
    assert main(["import", str(transforms), str(full), "--threads", "2", "--max-side", "0"]) == 0
    assert "import: frames are 160x120, kept at full size (--max-side 0)" in capsys.readouterr().err
