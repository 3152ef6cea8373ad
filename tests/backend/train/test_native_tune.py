"""``igs native-tune`` (backend.train.native_tune): copies of the layers tuned for Blender's ray-cast drawing,
on a tiny decomposed workspace: the files, the rows kept, the originals untouched, the agreement raised,
the errors."""

from __future__ import annotations

import json

import pytest
import torch

from backend.commands.cli import main
from backend.splats.ply import read_ply
from backend.train.native_tune import KINDS, NativeTuneConfig, native_dir, native_tune
from igs_contract.albedo_normals import sha256_16
from igs_contract.exit_codes import EXIT_USER
from tests.support.train_scene import make_layered_workspace


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("native_tune") / "ws", n_per_face=120)


def test_the_command_writes_tuned_copies_and_leaves_the_originals(box):
    before = {k: sha256_16(box / "layers" / f"{k}.ply") for k in KINDS}
    assert main(["native-tune", str(box), "--iterations", "40"]) == 0
    out = native_dir(box)
    report = json.loads((out / "native.json").read_text())
    for k in KINDS:
        assert sha256_16(box / "layers" / f"{k}.ply") == before[k]
        assert report["sources"][k]["sha256_16"] == before[k]
        tuned, orig = read_ply(out / f"{k}.ply", kind=k)[0], read_ply(box / "layers" / f"{k}.ply", kind=k)[0]
        assert len(tuned) == len(orig)  # row for row: the albedo's normals file still indexes it
        moved = (tuned.params["means"] - orig.params["means"]).detach().norm(dim=-1)
        assert float(moved.max()) < 0.05 and not torch.equal(tuned.params["opacity_logits"],
                                                              orig.params["opacity_logits"])
    psnr = report["psnr_against_rasteriser"]
    assert psnr["after"]["composite"] > psnr["before"]["composite"] + 0.5, psnr


def test_a_second_run_replaces_the_first_whole(box):
    first = sha256_16(native_dir(box) / "albedo.ply") if (native_dir(box) / "albedo.ply").exists() else None
    result = native_tune(box, NativeTuneConfig(iterations=2, seed=3, crop=16))  # windows of the 32x24 views
    assert result["iterations"] == 2
    assert sha256_16(native_dir(box) / "albedo.ply") != first
    assert sorted(p.name for p in native_dir(box).iterdir()) == ["albedo.ply", "native.json", "residual.ply",
                                                                  "shading.ply"]


def test_bad_input_is_one_line(tmp_path, capsys):
    ws = make_layered_workspace(tmp_path / "ws", n_per_face=10)
    (ws / "layers" / "shading.ply").unlink()
    assert main(["native-tune", str(ws)]) == EXIT_USER
    err = capsys.readouterr().err
    assert "shading.ply missing" in err and "Traceback" not in err
    assert not native_dir(ws).exists()
    assert main(["native-tune", str(ws), "--supersample", "9"]) == EXIT_USER
    assert "--supersample" in capsys.readouterr().err


def test_over_the_memory_limit_is_one_line_naming_the_crop_that_fits(box, monkeypatch, capsys):
    """The estimate: 0.98 GiB, 200 kB a pixel of the window (32x24 here), 400 B a pixel, 600 B a Gaussian."""
    monkeypatch.setenv("IGS_MEMORY_LIMIT", "1.0G")
    assert main(["native-tune", str(box), "--iterations", "1"]) == EXIT_USER
    err = capsys.readouterr().err
    assert "over the limit 1.0 GiB (IGS_MEMORY_LIMIT); use --crop 10" in err and err.count("\n") == 1
    monkeypatch.setenv("IGS_MEMORY_LIMIT", "0.5G")
    assert main(["native-tune", str(box), "--iterations", "1"]) == EXIT_USER
    assert "free memory" in capsys.readouterr().err
