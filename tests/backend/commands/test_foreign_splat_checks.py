"""Splat files from other tools are checked before any arithmetic, and writers clip what a format
cannot store with the warning they promise, never silently (issue #50, reproducers 4-6)."""

import gzip
import struct
import warnings

import numpy as np
import pytest
import torch

from backend.commands.cli import main
from backend.splats.formats import SPLAT_RECORD, read_splat_file
from backend.splats.formats_write import LIMITS, ply_bytes
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import write_ply
from igs_contract import layer_ply, manifest


def run(argv, capfd):
    """``igs ARGV`` in-process: (exit code, stderr lines, warnings raised); stderr is read at the file
    descriptor, so what C libraries print counts too."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main([str(a) for a in argv])
    err = capfd.readouterr().err.strip().splitlines()
    return code, err, [f"{w.category.__name__}: {w.message}" for w in caught]


def refused(argv, capfd, *words):
    code, err, caught = run(argv, capfd)
    assert code == 2, err
    assert len(err) == 1 and err[0].count(": error:") == 1, err
    for w in words:
        assert w in err[0], err
    assert caught == [] and "Warning" not in "\n".join(err)


def splat_records(n=4) -> np.ndarray:
    rec = np.zeros(n, dtype=SPLAT_RECORD)
    rec["pos"] = np.arange(3 * n, dtype=np.float32).reshape(n, 3)
    rec["scale"], rec["rgba"], rec["rot"] = 0.1, 200, [255, 128, 128, 128]
    return rec


def layer(kind="radiance", n=50, sh_degree=0):
    g = torch.Generator().manual_seed(0)
    return GaussianSet.from_activated(kind, torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g),
                                      torch.randn(n, 3, generator=g) - 3, torch.rand(n, generator=g) * 0.9 + 0.05,
                                      sh_degree=sh_degree)


def test_an_spz_with_no_gaussians_is_one_error(tmp_path, capfd):
    empty = tmp_path / "empty.spz"  # header: magic, version 3, 0 points, SH degree 0, 12 fractional bits
    empty.write_bytes(gzip.compress(struct.pack("<IIIBBBB", 0x5053474E, 3, 0, 0, 12, 0, 0)))
    refused(["convert", empty, tmp_path / "o.ply"], capfd, f"{empty}: the file holds no Gaussians")
    refused(["export", "--ply", empty, "--out", tmp_path / "o.splat"], capfd, "holds no Gaussians")


@pytest.mark.parametrize("scale, words", [
    (np.frombuffer(b"\x01\x00\x80\x7f", "<f4")[0], "NaN or infinite values in their scales"),  # a signalling NaN
    (np.float32("inf"), "NaN or infinite values in their scales"),
    (-0.5, "a zero or negative scale"),
    (0.0, "a zero or negative scale"),
])
def test_dot_splat_scales_must_be_finite_and_positive(tmp_path, capfd, scale, words):
    rec = splat_records()
    rec["scale"][2, 1] = scale
    path = tmp_path / "a.splat"
    rec.tofile(path)
    refused(["convert", path, tmp_path / "o.ply"], capfd, str(path), "1 of 4 Gaussians", words, "Gaussian 2")


def test_all_zero_rotations_are_refused_on_the_first_read(tmp_path, capfd):
    rec = splat_records()
    rec["rot"] = 128  # (128 - 128) / 128 = 0 for every component
    path = tmp_path / "a.splat"
    rec.tofile(path)
    refused(["convert", path, tmp_path / "o.ply"], capfd, "4 of 4 Gaussians have a zero rotation quaternion")
    assert not (tmp_path / "o.ply").exists()


def _ply_with(tmp_path, change, name="src.ply"):
    g = layer()
    write_ply(tmp_path / "plain.ply", g)
    a = read_splat_file(tmp_path / "plain.ply").arrays
    change(a)
    path = tmp_path / name
    path.write_bytes(ply_bytes(a, layer_ply.header_comments("radiance", "sh", "srgb", 0)))
    return path


def test_positions_spz_cannot_store_are_clipped_with_the_warning(tmp_path, capfd):
    src = _ply_with(tmp_path, lambda a: a.means.__setitem__((0, 0), 3e38))
    code, err, caught = run(["export", "--ply", src, "--out", tmp_path / "r.spz"], capfd)
    assert code == 0 and caught == [], (err, caught)
    lo, hi = LIMITS["spz"]["means"]
    assert any(f"spz stores positions in [{lo:.3g}, {hi:.3g}]: 1 of 50 Gaussians" in line and "clipped" in line
               for line in err), err
    assert not any("RuntimeWarning" in line or "overflow" in line for line in err), err
    back = read_splat_file(tmp_path / "r.spz").arrays.means
    assert back[0, 0] == pytest.approx(hi, abs=1e-3)  # the largest it stores, not -2048


@pytest.mark.parametrize("ext, fmt", [(".splat", "splat"), (".compressed.ply", "compressed-ply"), (".spz", "spz")])
def test_log_scale_100_is_clipped_with_the_warning_in_every_format(tmp_path, capfd, ext, fmt):
    if fmt == "splat":
        pytest.importorskip("ply2splat", reason="ply2splat has no wheel for this Python")
    src = _ply_with(tmp_path, lambda a: a.log_scales.__setitem__((3, 1), 100.0))
    code, err, caught = run(["export", "--ply", src, "--out", tmp_path / f"r{ext}"], capfd)
    assert code == 0 and caught == [], (err, caught)
    lo, hi = LIMITS[fmt]["log_scale"]
    assert any(f"{fmt} stores log scales in [{lo:.3g}, {hi:.3g}]: 1 of 50 Gaussians" in line for line in err), err
    back = read_splat_file(tmp_path / f"r{ext}").arrays.log_scales  # finite, and read back without an error
    assert np.isfinite(back).all() and back[3, 1] == pytest.approx(hi, abs=0.1)


def test_a_plain_ply_keeps_log_scale_100(tmp_path, capfd):
    src = _ply_with(tmp_path, lambda a: a.log_scales.__setitem__((3, 1), 100.0))
    code, err, _ = run(["export", "--ply", src, "--out", tmp_path / "r.ply"], capfd)
    assert code == 0 and not any("warning" in line for line in err)
    assert read_splat_file(tmp_path / "r.ply").arrays.log_scales[3, 1] == 100.0


def test_an_unknown_colour_space_comment_is_refused_on_both_sides(tmp_path, capfd):
    from intrinsic_splats.igs_blender.errors import UserError
    from intrinsic_splats.igs_blender.ply_io import file_identity

    from tests.support import addon_package  # noqa: F401 (the add-on's reader, as Blender imports it)

    g = layer("albedo")
    write_ply(tmp_path / "a.ply", g)
    a = read_splat_file(tmp_path / "a.ply").arrays
    cmyk = tmp_path / "cmyk.ply"
    cmyk.write_bytes(ply_bytes(a, ["igs_layer albedo", "igs_color rgb01", "igs_space cmyk", "igs_sh_degree 0"]))
    refused(["convert", cmyk, tmp_path / "o.ply"], capfd, "unknown colour space 'cmyk'")
    refused(["export", "--ply", cmyk, "--out", tmp_path / "o.spz"], capfd, "unknown colour space 'cmyk'")
    with pytest.raises(UserError, match="unknown colour space 'cmyk'"):
        file_identity(cmyk)
    assert run(["export", "--ply", tmp_path / "a.ply", "--out", tmp_path / "c.compressed.ply"], capfd)[0] == 0
    compressed = tmp_path / "c.compressed.ply"
    compressed.write_bytes(compressed.read_bytes().replace(b"igs_space srgb", b"igs_space cmyk"))
    refused(["convert", compressed, tmp_path / "o.ply"], capfd, "unknown colour space 'cmyk'")


def test_an_unreadable_manifest_of_the_file_is_an_error(tmp_path, capfd):
    write_ply(tmp_path / "a.ply", layer("albedo"))
    assert run(["export", "--ply", tmp_path / "a.ply", "--out", tmp_path / "a.spz"], capfd)[0] == 0
    own = manifest.manifest_path(tmp_path / "a.spz")
    good = own.read_bytes()
    for broken in (b"{not json", b"\xff\xfe", good.replace(b'"srgb"', b'"cmyk"'), good.replace(b'"count": 50', b'"count": -1')):
        own.write_bytes(broken)
        capfd.readouterr()
        refused(["convert", tmp_path / "a.spz", tmp_path / "o.ply"], capfd, str(own), "fix or delete it")
    # told what the file is, the convert needs no manifest
    code, err, _ = run(["convert", tmp_path / "a.spz", tmp_path / "o.ply", "--kind", "albedo", "--space", "srgb"],
                       capfd)
    assert code == 0, err
    # another file's unreadable manifest (found by stem) is a warning, not an error
    own.write_bytes(good)
    (tmp_path / "a.splat.igs.json").write_text("{")
    code, err, _ = run(["convert", tmp_path / "a.spz", tmp_path / "o2.ply"], capfd)
    assert code == 0 and any(line.startswith("warning: ") and "a.splat.igs.json" in line for line in err), err
