"""The contract the add-on and the backend share (igs_contract): what it may import, and that what one
side writes with it the other side reads back the same."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from intrinsic_splats.igs_blender.cameras import SfmView  # noqa: E402
from intrinsic_splats.igs_contract import camera_json  # noqa: E402

from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)

ROOT = Path(__file__).resolve().parents[2]


def test_the_contract_imports_neither_side_nor_torch_nor_bpy():
    """Standard library only, but for layer_values' numpy (both sides have it)."""
    probe = ("import json, sys; top = lambda: {m.split('.')[0] for m in sys.modules}; start = top(); "
             "import igs_contract.events, igs_contract.exit_codes, igs_contract.ply_header, igs_contract.layer_ply, "
             "igs_contract.camera_json, igs_contract.light_json; plain = top() - start; import igs_contract.layer_values; "
             "print(json.dumps([sorted(plain), sorted(top() - start)]))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, check=True)
    plain, with_values = json.loads(out.stdout)
    assert not {"numpy", "torch", "bpy", "backend", "igs_blender", "plyfile"} & set(plain), plain
    assert "numpy" in with_values and not {"torch", "bpy", "backend", "igs_blender"} & set(with_values)


def test_cameras_json_written_by_the_addon_reads_back_in_the_backend(tmp_path):
    from backend.core.cameras import Camera
    from backend.scene_render.render_views import read_cameras

    cam = Camera.look_at("v.png", [1.0, -2.0, 0.5], [0, 0, 0], [0, 0, 1], 64, 48, 55)
    view = SfmView("v.png", 64, 48, 50.0, 52.0, 30.5, 20.25, cam.R, cam.t)
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(camera_json.cameras_document([view.to_json()])))
    (back,) = read_cameras(path)
    assert (back.name, back.width, back.height) == ("v.png", 64, 48)
    np.testing.assert_allclose([back.fx, back.fy, back.cx, back.cy], [50.0, 52.0, 30.5, 20.25])
    np.testing.assert_allclose(back.R, cam.R, atol=1e-12)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-12)
    again = SfmView.from_json(view.to_json())
    np.testing.assert_array_equal(again.R, view.R)
    assert (again.name, again.fx, again.cy) == (view.name, view.fx, view.cy)


def test_exit_codes_and_event_names_are_the_backends():
    from backend.core import signals
    from igs_contract import events, exit_codes

    assert signals.EXIT_CANCELLED == exit_codes.EXIT_CANCELLED == 130
    assert (exit_codes.EXIT_OK, exit_codes.EXIT_INTERNAL, exit_codes.EXIT_USER) == (0, 1, 2)
    assert set(events.FIELDS) == {events.START, events.STAGE, events.PROGRESS, events.LOG, events.OUTPUT,
                                  events.RESULT, events.DONE, events.ERROR, events.CANCELLED}
