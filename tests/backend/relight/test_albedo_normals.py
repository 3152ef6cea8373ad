"""``igs normals`` and the end of ``igs decompose``: the albedo Gaussians' normals for Blender's native lighting,
``layers/albedo_normals.npz`` (the contract's reader, its tie to the albedo PLY, errors, the lock)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from backend.capture.load import load_capture
from backend.commands.cli import main
from backend.relight.albedo_normals import normals_current, normals_path
from backend.relight.relight import RelightConfig
from backend.relight.shading_bake import LightBakeConfig, gaussian_normals, spread_views
from backend.render import Splats
from backend.splats.ply import read_ply
from igs_contract import albedo_normals as contract
from igs_contract.exit_codes import EXIT_BUSY, EXIT_USER
from tests.support.train_scene import make_layered_workspace

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("normals") / "ws", n_per_face=120)


def test_the_file_holds_the_blended_depth_normals_tied_to_the_albedo_ply(box, capsys):
    assert not normals_current(box)  # decomposed before the file existed
    assert main(["normals", str(box), "--backend", "cpu", "--views", "8"]) == 0
    out = capsys.readouterr().out
    assert '"gaussians": ' in out and str(normals_path(box)) in out
    ply = box / "layers" / "albedo.ply"
    g, _ = read_ply(ply, kind="albedo")
    got, why = contract.read(normals_path(box), ply, len(g))
    assert why == "" and got.shape == (len(g), 3) and got.dtype == np.float32
    assert normals_current(box)
    # the estimate light-bake makes with --normals blended (the depth normals where each Gaussian colours)
    capture = load_capture(box)
    cams = [f.camera for f in capture.frames]
    splats = Splats(**g.render_args())
    cfg = LightBakeConfig(normals="blended", views=8, relight=RelightConfig(backend="cpu"))
    with torch.no_grad():
        want, seen = gaussian_normals(splats, splats, spread_views(cams, 8), cfg, cams)
    np.testing.assert_allclose(got, want.numpy(), atol=1e-5)
    assert seen.float().mean() > 0.3
    # unit normals; the box's Gaussians seen by a view face that view (depth normals, not an axis sign)
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-4)
    # a file of the centres' normals (written before the blended ones) is read, but igs decompose writes it again
    assert main(["normals", str(box), "--backend", "cpu", "--views", "8", "--normals", "depth"]) == 0
    assert contract.source_of(normals_path(box)) == "depth" and contract.read(normals_path(box), ply)[0] is not None
    assert not normals_current(box)


def test_a_changed_albedo_or_count_is_refused_by_the_reader(box, tmp_path):
    assert main(["normals", str(box), "--backend", "cpu", "--views", "4"]) == 0
    ply = box / "layers" / "albedo.ply"
    g, _ = read_ply(ply, kind="albedo")
    assert contract.read(normals_path(box), ply, len(g) + 1)[0] is None
    other = tmp_path / "albedo.ply"
    other.write_bytes(ply.read_bytes() + b"\0")
    normals, why = contract.read(normals_path(box), other, len(g))
    assert normals is None and "another albedo.ply" in why
    broken = tmp_path / contract.FILE
    broken.write_bytes(b"not a zip")
    normals, why = contract.read(broken, ply, len(g))
    assert normals is None and "cannot be read" in why


def test_a_missing_albedo_is_one_error_line(tmp_path, capsys):
    ws = make_layered_workspace(tmp_path / "ws", n_per_face=10)
    (ws / "layers" / "albedo.ply").unlink()
    assert main(["normals", str(ws), "--backend", "cpu"]) == EXIT_USER
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "albedo.ply" in err[0] and "igs decompose" in err[0], err
    assert not normals_path(ws).exists()


_HOLDER = """
import sys, time
from backend.core.workspace_lock import hold
with hold(sys.argv[1], "decompose"):
    print("held", flush=True)
    time.sleep(60)
"""


def test_the_workspace_lock_is_respected(box, capsys):
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER, str(box)], stdout=subprocess.PIPE, cwd=REPO,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        assert proc.stdout.readline().strip() == b"held"
        before = normals_path(box).stat().st_mtime_ns if normals_path(box).exists() else None
        assert main(["normals", str(box), "--backend", "cpu", "--views", "2"]) == EXIT_BUSY
        assert f"in use by `igs decompose` (PID {proc.pid}" in capsys.readouterr().err
        assert (normals_path(box).stat().st_mtime_ns if normals_path(box).exists() else None) == before
    finally:
        proc.kill()
        proc.wait()


def test_a_failed_write_keeps_the_old_file(box, monkeypatch, capsys):
    assert main(["normals", str(box), "--backend", "cpu", "--views", "4"]) == 0
    before = normals_path(box).read_bytes()

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", boom)
    assert main(["normals", str(box), "--backend", "cpu", "--views", "4"]) == EXIT_USER
    assert normals_path(box).read_bytes() == before
    assert torch.isfinite(torch.as_tensor(np.load(normals_path(box))[contract.NORMALS])).all()
