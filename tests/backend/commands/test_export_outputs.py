"""Where exports and converts may write: never over a workspace's own files, never one format under
another's name, and a splat with its manifest appears whole or not at all (issue #50, reproducers
2 and 3)."""


import pytest
import torch

from backend.commands.cli import main
from backend.core.atomic_io import is_tmp_name
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import write_ply
from igs_contract import manifest
from tests.support.small_disk import fill, small_tmpfs  # noqa: E402
from tests.support.train_scene import make_layered_workspace


@pytest.fixture(scope="module")
def wl(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("out") / "wl", n_per_face=30)


def files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def one_error(capsys) -> str:
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ": error:" in ln]
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("argv", [
    ["--layer", "residual", "--out", "layers/albedo.ply"],
    ["--layer", "albedo", "--out", "transforms.json"],
    ["--layer", "albedo", "--out", "metrics.json", "--format", "spz"],
    ["--layer", "albedo", "--out", "checkpoints/x.ply"],
    ["--layer", "albedo", "--out", "edits/e/albedo.ply"],
    ["--layer", "albedo", "--out", "capture.json.ply"],
])
def test_export_never_writes_over_the_workspaces_own_files(wl, capsys, argv):
    (wl / "metrics.json").write_text('{"decompose": {"psnr": 30}}')
    (wl / "transforms.json").write_text("{}")
    before = files(wl)
    argv = [str(wl / a) if i and argv[i - 1] == "--out" else a for i, a in enumerate(argv)]
    assert main(["export", str(wl), *argv]) == 2
    line = one_error(capsys)
    assert f"lies in the workspace {wl}, among the files igs keeps there; write it under {wl}/exports/" in line
    assert files(wl) == before


def test_a_symlink_into_the_workspace_counts_as_the_workspace(wl, tmp_path, capsys):
    (tmp_path / "link").symlink_to(wl / "layers")
    before = files(wl)
    assert main(["export", str(wl), "--layer", "residual", "--out", str(tmp_path / "link" / "albedo.ply")]) == 2
    assert f"lies in the workspace {wl}" in one_error(capsys)
    assert files(wl) == before


def test_convert_distil_and_render_outputs_stay_out_of_the_workspace_files(wl, capsys):
    before = files(wl)
    src = str(wl / "layers" / "albedo.ply")
    for argv in (["convert", src, str(wl / "layers" / "shading.ply")],
                 ["distil", str(wl), "--out", str(wl / "layers" / "d.ply"), "--iterations", "1"],
                 ["render", str(wl), "--turntable", "--out", str(wl / "layers")]):
        assert main(argv) == 2, argv
        assert "lies in the workspace" in one_error(capsys)
    assert files(wl) == before
    # exports/ (and renders/ for images) are where outputs go
    assert main(["convert", src, str(wl / "exports" / "a.ply")]) == 0
    assert main(["export", "--ply", src, "--format", "spz"]) == 0  # beside --ply would be layers/: exports/ instead
    assert (wl / "exports" / "albedo-export.spz").is_file() and not (wl / "layers" / "albedo-export.spz").exists()


@pytest.mark.parametrize("out, fmt", [("x.ply", "spz"), ("x.spz", "ply"), ("x.splat", "spz"), ("x.bin", "spz"),
                                      ("x.compressed.ply", "ply")])
def test_a_format_is_never_written_under_another_formats_name(wl, tmp_path, capsys, out, fmt):
    assert main(["export", str(wl), "--layer", "albedo", "--out", str(tmp_path / out), "--format", fmt]) == 2
    line = one_error(capsys)
    assert f"a {fmt} file must end in" in line and str(tmp_path / out) in line
    assert list(tmp_path.iterdir()) == []


def test_a_compressed_ply_may_be_named_ply(wl, tmp_path, capsys):
    assert main(["export", str(wl), "--layer", "albedo", "--out", str(tmp_path / "x.ply"),
                 "--format", "compressed-ply"]) == 0
    assert manifest.read(manifest.manifest_path(tmp_path / "x.ply")).format == "compressed-ply"


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB tmpfs (root only; skipped where the machine does not allow mounting one)."""
    with small_tmpfs(tmp_path / "disk", "1m") as mnt:
        yield mnt




def test_on_a_full_disk_a_splat_and_its_manifest_appear_together_or_not_at_all(tmp_path, small_disk, capsys):
    """Issue #50, reproducer 3: `export --out full/r.spz` exited 2 on the manifest and left r.spz alone."""
    g = torch.Generator().manual_seed(0)
    n = 3000
    layer = GaussianSet.from_activated("radiance", torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g),
                                       torch.randn(n, 3, generator=g) - 3, torch.rand(n, generator=g) * 0.9 + 0.05)
    src = tmp_path / "src.ply"
    write_ply(src, layer)
    assert main(["export", "--ply", str(src), "--out", str(tmp_path / "r.spz")]) == 0
    size = (tmp_path / "r.spz").stat().st_size
    # an older pair on the small disk, which a failed export must leave as it was
    write_ply(src, GaussianSet.from_activated("radiance", torch.zeros(5, 3), torch.rand(5, 3), torch.zeros(5, 3) - 3,
                                              torch.full((5,), 0.5)))
    assert main(["export", "--ply", str(src), "--out", str(small_disk / "r.spz")]) == 0
    old = files(small_disk)
    write_ply(src, layer)
    capsys.readouterr()
    outcomes = []
    for leave in range(size - 4096, size + 32768, 1024):
        fill(small_disk, leave)
        code = main(["export", "--ply", str(src), "--out", str(small_disk / "r.spz")])
        err = capsys.readouterr().err
        now = {k: v for k, v in files(small_disk).items() if k != "filler"}
        assert not [p for p in small_disk.iterdir() if is_tmp_name(p.name)]
        if code == 0:
            info = manifest.read(small_disk / "r.spz.igs.json")
            assert info.sha256 == manifest.sha256_file(small_disk / "r.spz") and info.count == n
            outcomes.append("whole")
            break  # from here on everything fits
        assert code == 2 and "no space left on the device" in err, err
        assert now == old  # neither file changed: no splat without its manifest
        outcomes.append("manifest" if "r.spz.igs.json" in err else "splat")
    assert outcomes[-1] == "whole" and "manifest" in outcomes, outcomes  # the manifest ran out of space, too


def test_a_failed_import_on_a_full_disk_leaves_no_folder(small_disk, tmp_path, capsys):
    """Issue #50, reproducer 3: a failed import left an empty workspace folder."""
    from tests.support.import_scene import write_capture

    write_capture(tmp_path / "proj", n=4, width=64, height=48)
    fill(small_disk, 8 * 1024)
    code = main(["import", str(tmp_path / "proj"), str(small_disk / "ws")])
    assert code == 2 and "no space left" in one_error(capsys)
    assert sorted(p.name for p in small_disk.iterdir()) == ["filler"]
