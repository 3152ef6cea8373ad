"""A decomposition's layer set is always consistent (issue #59, I): the stages' layers wait in a pending
set and replace ``layers/`` as one group with ``set.json``, which names the run; a run killed during a
``--restart`` leaves the previous complete set, and the same command without ``--restart`` continues."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from backend.commands.cli import main
from backend.core import layer_set
from backend.train.checkpoint import settings_diff
from backend.train.intrinsic import run as run_mod
from tests.support.synth_capture import needs_synth_renderer

ARGS = ["--albedo-iterations", "30", "--shading-iterations", "16", "--residual-iterations", "16",
        "--checkpoint-every", "8", "--max-gaussians", "3000", "--residual-points", "200", "--backend", "cpu"]
NAMES = ("albedo.ply", "shading.ply", "residual.ply", "set.json")


class Killed(BaseException):
    """Stands for a SIGKILL: nothing of the run's own clean-up runs (no except clause catches it)."""


@pytest.fixture(scope="module")
def decomposed(tmp_path_factory):
    needs_synth_renderer()
    synth = pytest.importorskip("backend.synth.run")
    ws = tmp_path_factory.mktemp("layerset") / "ws"
    synth.synthesize(ws, preset="test", seed=0)
    assert main(["decompose", str(ws), *ARGS]) == 0
    return ws


def files(ws: Path) -> dict[str, bytes]:
    return {n: (ws / "layers" / n).read_bytes() for n in NAMES}


def info_line(ws: Path, capsys) -> str:
    capsys.readouterr()
    assert main(["info", str(ws)]) == 0
    (line,) = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("layers ")]
    return line


def test_the_set_names_its_run_and_every_layer(decomposed, capsys):
    record = json.loads((decomposed / "layers" / "set.json").read_text())
    assert record["mode"] == "three-set" and set(record["layers"]) == {"albedo", "shading", "residual"}
    for kind, entry in record["layers"].items():
        assert entry["sha256_16"] == layer_set.file_hash(decomposed / "layers" / f"{kind}.ply")
    assert f"set of run {record['run']}, written {record['written']}" in info_line(decomposed, capsys)
    assert not list((decomposed / "checkpoints" / "decompose" / "pending").glob("*.ply"))  # all committed


def test_a_restart_killed_after_the_albedo_leaves_the_previous_set_and_a_rerun_continues(
        decomposed, tmp_path, monkeypatch, capsys):
    """Reproducer I: killed once albedo.ply had changed, layers/ held the new albedo with the old shading
    and residual; the rerun without --restart was refused with a line printing two settings dicts."""
    ws = tmp_path / "ws"
    shutil.copytree(decomposed, ws)
    before = files(ws)
    old_run = json.loads(before["set.json"])["run"]
    changed = [*ARGS, "--albedo-iterations", "24"]  # the restart trains another albedo
    real = run_mod.run_stage

    def killed_in_shading(name, *a, **k):
        if name == "shading":
            raise Killed
        return real(name, *a, **k)

    monkeypatch.setattr(run_mod, "run_stage", killed_in_shading)
    with pytest.raises(Killed):
        main(["decompose", str(ws), *changed, "--restart"])
    monkeypatch.setattr(run_mod, "run_stage", real)
    (ws / ".igs.lock").unlink(missing_ok=True)  # a killed process's lock file: free (no flock behind it)
    pending = ws / "checkpoints" / "decompose" / "pending" / "albedo.ply"
    new_albedo = pending.read_bytes()
    assert new_albedo != before["albedo.ply"]  # the new albedo waits in the pending set
    assert files(ws) == before  # readers still see the previous complete set, and info says which
    line = info_line(ws, capsys)
    assert f"set of run {old_run}" in line and "differ" not in line

    capsys.readouterr()
    assert main(["decompose", str(ws), *changed]) == 0  # the same command without --restart continues
    err = capsys.readouterr().err
    assert "albedo: finished earlier on the same inputs" in err
    after = files(ws)
    assert after["albedo.ply"] == new_albedo
    assert all(after[n] != before[n] for n in NAMES)  # a whole new set
    record = json.loads(after["set.json"])
    assert record["run"] != old_run and not pending.exists()
    assert f"set of run {record['run']}" in info_line(ws, capsys)


def test_a_layer_replaced_behind_the_sets_back_is_reported(decomposed, tmp_path, capsys):
    ws = tmp_path / "ws"
    shutil.copytree(decomposed, ws)
    run = json.loads((ws / "layers" / "set.json").read_text())["run"]
    render = ["render", str(ws), "--turntable", "--frames", "1", "--size", "16", "12", "--layers", "A",
              "--out", str(tmp_path / "r")]
    assert main(render) == 0  # a reader says which run's set it reads
    assert f"layers: set of run {run}" in capsys.readouterr().err
    (ws / "layers" / "residual.ply").write_bytes((ws / "layers" / "shading.ply").read_bytes())
    assert "the files differ from the set's record" in info_line(ws, capsys)
    assert main(render) == 0
    assert "warning: the files differ from the set's record" in capsys.readouterr().err


def test_a_settings_mismatch_is_one_short_line():
    """The refusal printed two whole settings dicts; now it names the keys that differ."""
    then = {"iterations": 75, "densify": {"max_gaussians": 1126, "grad_threshold": 2e-4, "floaters": False}}
    now = {"iterations": 300, "densify": {"max_gaussians": 27673, "grad_threshold": 2e-4, "floaters": False}}
    assert settings_diff(then, now) == "iterations: 75 -> 300, densify.max_gaussians: 1126 -> 27673"
    many = settings_diff({f"k{i}": i for i in range(9)}, {f"k{i}": -i for i in range(9)})
    assert many.endswith("and 5 more") and len(many) < 120


def test_the_single_set_baseline_writes_its_three_files_as_one_set(decomposed, tmp_path):
    ws = tmp_path / "ws"
    shutil.copytree(decomposed, ws)
    assert main(["decompose", str(ws), *ARGS, "--single-set"]) == 0
    folder = ws / "layers" / "single_set"
    record = json.loads((folder / "set.json").read_text())
    assert record["mode"] == "single-set"
    assert {k: v["sha256_16"] for k, v in record["layers"].items()} == \
        {k: layer_set.file_hash(folder / f"{k}.ply") for k in ("albedo", "shading", "residual")}
    assert not list((ws / "checkpoints" / "decompose" / "pending").rglob("*.ply"))


def test_decompose_leaves_the_albedos_normals_for_blender(decomposed):
    from igs_contract import albedo_normals

    record = json.loads((decomposed / "layers" / "set.json").read_text())
    normals, why = albedo_normals.read(decomposed / "layers" / albedo_normals.FILE, decomposed / "layers" / "albedo.ply",
                                       record["layers"]["albedo"]["gaussians"])
    assert why == "" and normals.shape == (record["layers"]["albedo"]["gaussians"], 3)
