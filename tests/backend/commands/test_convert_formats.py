"""igs convert: every readable format into a layer PLY, and identity from header, manifest or options."""

import json

import numpy as np
import pytest
import torch
from plyfile import PlyData

from backend.commands.cli import main
from backend.splats.formats import SPLAT_RECORD, detect_format, read_splat_file
from backend.splats.gaussians import C0, GaussianSet
from backend.splats.ply import read_ply, write_ply
from igs_contract import manifest


def make(kind, n=30, sh_degree=0, seed=0):
    g = torch.Generator().manual_seed(seed)
    s = GaussianSet.from_activated(kind, torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g) * 0.8 + 0.1,
                                   torch.randn(n, 3, generator=g) - 3, torch.rand(n, generator=g) * 0.9 + 0.05,
                                   quats=torch.randn(n, 4, generator=g), sh_degree=sh_degree)
    if sh_degree:
        s.params["shN"].data.normal_(std=0.02, generator=g)
    return s


def convert(argv, capsys):
    code = main(["--events", "convert", *map(str, argv)])
    out = capsys.readouterr()
    result = next((json.loads(x)["data"] for x in out.out.splitlines() if json.loads(x)["event"] == "result"), None)
    return code, result, out.err


def export(src, out, capsys):
    assert main(["export", "--ply", str(src), "--out", str(out)]) == 0
    capsys.readouterr()


@pytest.mark.parametrize("ext", [".ply", ".compressed.ply", ".spz", ".splat"])
def test_export_then_convert_round_trip(tmp_path, capsys, ext):
    if ext == ".splat":
        pytest.importorskip("ply2splat", reason="ply2splat has no wheel for this Python")
    src = tmp_path / "albedo.ply"
    g = make("albedo")
    write_ply(src, g)
    export(src, tmp_path / f"view{ext}", capsys)
    code, res, _ = convert([tmp_path / f"view{ext}", tmp_path / "back.ply"], capsys)
    assert code == 0 and res["count"] == 30 and res["kind"] == "albedo" and res["space"] == "linear"
    assert res["identity"] == ("file" if ext in (".ply", ".compressed.ply") else "manifest")
    back, info = read_ply(tmp_path / "back.ply")
    assert info.kind == "albedo" and info.space == "linear" and not info.foreign
    # within one 8-bit step of the sRGB colour (compressed PLY: of its per-chunk range), in linear terms
    np.testing.assert_allclose(back.colors.detach().numpy(), g.colors.detach().numpy(),
                               atol=1e-5 if ext == ".ply" else 0.012)
    np.testing.assert_allclose(back.params["means"].detach().numpy(), g.params["means"].detach().numpy(),
                               atol=1e-3 if ext == ".spz" else 2e-2 if ext == ".compressed.ply" else 1e-6)


def test_residual_round_trip_keeps_sh(tmp_path, capsys):
    src = tmp_path / "residual.ply"
    g = make("residual", sh_degree=3)
    write_ply(src, g)
    export(src, tmp_path / "r.ply", capsys)
    code, res, _ = convert([tmp_path / "r.ply", tmp_path / "back.ply"], capsys)
    assert code == 0 and res["sh_degree"] == 3 and res["space"] == "linear"
    back, _ = read_ply(tmp_path / "back.ply")
    np.testing.assert_allclose(back.params["sh0"].detach().numpy(), g.params["sh0"].detach().numpy(), atol=0.01)


def test_identity_manifest_changed_and_unknown(tmp_path, capsys):
    src = tmp_path / "shading.ply"
    write_ply(src, make("shading"))
    out = tmp_path / "s.spz"
    export(src, out, capsys)
    assert manifest.identify(out).status == "manifest"
    (tmp_path / "tool").mkdir()  # a tool rewrites the file (floaters removed): same name, other Gaussians
    write_ply(tmp_path / "tool" / "fewer.ply", make("shading", n=20, seed=1))
    export(tmp_path / "tool" / "fewer.ply", tmp_path / "tool" / "s.spz", capsys)
    out.write_bytes((tmp_path / "tool" / "s.spz").read_bytes())
    ident = manifest.identify(out)
    assert ident.status == "manifest-changed" and ident.manifest.kind == "shading" and ident.manifest.count == 30
    code, res, _ = convert([out, tmp_path / "c.ply"], capsys)
    assert code == 0 and res["identity"] == "manifest-changed" and res["kind"] == "shading" and res["count"] == 20
    out.rename(tmp_path / "other.spz")  # renamed and changed: nothing says what it is
    code, res, _ = convert([tmp_path / "other.spz", tmp_path / "b.ply"], capsys)
    assert code == 0 and res["identity"] == "unknown" and res["kind"] == "radiance" and res["space"] == "srgb"
    code, res, _ = convert([tmp_path / "other.spz", tmp_path / "b.ply", "--kind", "shading", "--space", "srgb"], capsys)
    assert code == 0 and res["kind"] == "shading" and res["space"] == "linear"


def test_manifest_found_by_stem_without_tool_suffix(tmp_path, capsys):
    src = tmp_path / "albedo.ply"
    write_ply(src, make("albedo"))
    export(src, tmp_path / "scene.spz", capsys)
    (tmp_path / "scene.spz").rename(tmp_path / "scene.compressed.spz")  # name as SuperSplat would add it
    ident = manifest.identify(tmp_path / "scene.compressed.spz")
    assert ident.status == "manifest" and ident.manifest.kind == "albedo"
    assert manifest.stems("a.compressed.ply") == ["a.compressed", "a"]
    assert manifest.stems("b_cleaned.spz") == ["b_cleaned", "b"]


def test_a_bad_manifest_is_skipped_and_read_names_it(tmp_path):
    f = tmp_path / "x.spz"
    f.write_bytes(b"data")
    manifest.manifest_path(f).write_text("{not json")
    assert manifest.identify(f).status == "unknown"
    with pytest.raises(manifest.ManifestError, match="x.spz.igs.json"):
        manifest.read(manifest.manifest_path(f))


@pytest.mark.parametrize("text,byte_order", [(True, "="), (False, ">")])
def test_foreign_ascii_and_big_endian_ply(tmp_path, capsys, text, byte_order):
    src = tmp_path / "a.ply"
    write_ply(src, make("radiance", sh_degree=1))
    ply = PlyData.read(str(src))
    ply.comments = []
    ply.text, ply.byte_order = text, byte_order
    ply.write(str(tmp_path / "foreign.ply"))
    code, res, _ = convert([tmp_path / "foreign.ply", tmp_path / "b.ply"], capsys)
    assert code == 0 and res["identity"] == "unknown" and res["count"] == 30 and res["sh_degree"] == 1


def test_dot_splat_reader_decodes_records(tmp_path):
    rec = np.zeros(3, dtype=SPLAT_RECORD)
    rec["pos"] = [[1, 2, 3], [0, 0, 0], [-1, 0, 1]]
    rec["scale"] = 0.1
    rec["rgba"] = [[255, 0, 128, 255], [10, 20, 30, 128], [0, 0, 0, 0]]
    rec["rot"] = [[255, 128, 128, 128]] * 3
    path = tmp_path / "a.splat"
    rec.tofile(path)
    a = read_splat_file(path).arrays
    np.testing.assert_allclose(0.5 + C0 * a.f_dc[0], [1, 0, 128 / 255], atol=1e-6)
    np.testing.assert_allclose(np.exp(a.log_scales), 0.1, rtol=1e-6)
    np.testing.assert_allclose(1 / (1 + np.exp(-a.opacity_logits[1])), 128 / 255, atol=1e-6)
    np.testing.assert_allclose(a.quats[0], [127 / 128, 0, 0, 0])


@pytest.mark.parametrize("name,data,words", [
    ("a.splat", b"x" * 33, "not a whole number of 32-byte .splat records"),
    ("a.spz", b"\x1f\x8b garbage", "a.spz: unreadable splat file"),
    ("a.txt", b"hello", "not a splat file"),
    ("a.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n", "a.ply"),
])
def test_bad_files_are_one_error_line(tmp_path, capsys, name, data, words):
    (tmp_path / name).write_bytes(data)
    code = main(["convert", str(tmp_path / name), str(tmp_path / "out.ply")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0], err


def test_output_must_be_ply_and_formats_are_detected(tmp_path, capsys):
    write_ply(tmp_path / "a.ply", make("albedo"))
    assert main(["convert", str(tmp_path / "a.ply"), str(tmp_path / "out.spz")]) == 2
    assert "give it a .ply name" in capsys.readouterr().err
    assert detect_format(tmp_path / "a.ply") == "ply"


@pytest.mark.parametrize("ext", [".ply", ".spz"])
def test_raster_mode_survives_export_and_convert(tmp_path, capsys, ext):
    """The raster mode a layer was trained in goes into the export's header (PLY) and its manifest,
    and converting the export back gives a layer of the same mode: through the manifest where the
    format has no comments (SPZ)."""
    src = tmp_path / "albedo.ply"
    g = make("albedo")
    g.raster_mode = "antialiased"
    write_ply(src, g)
    export(src, tmp_path / f"view{ext}", capsys)
    assert manifest.read(manifest.manifest_path(tmp_path / f"view{ext}")).raster == "antialiased"
    assert read_splat_file(tmp_path / f"view{ext}").identity.raster == "antialiased"
    code, res, _ = convert([tmp_path / f"view{ext}", tmp_path / "back.ply"], capsys)
    assert code == 0 and res["raster"] == "antialiased"
    assert read_ply(tmp_path / "back.ply")[0].raster_mode == "antialiased"
    # a manifest written before the field existed reads as classic; a wrong value is named
    m = manifest.manifest_path(tmp_path / f"view{ext}")
    data = json.loads(m.read_text())
    del data["raster"]
    m.write_text(json.dumps(data))
    assert manifest.read(m).raster == "classic"
    data["raster"] = "fuzzy"
    m.write_text(json.dumps(data))
    with pytest.raises(manifest.ManifestError, match="field 'raster' must be one of classic, antialiased"):
        manifest.read(m)
