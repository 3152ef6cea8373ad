"""igs export: sRGB colours for viewers, every format, clipping warnings, manifests, and its errors."""

import json

import numpy as np
import pytest
import torch

from backend.commands.cli import main
from backend.splats.formats import read_splat_file
from backend.splats.formats_write import LIMITS
from backend.splats.gaussians import C0, GaussianSet
from backend.splats.ply import ply_header_comments, read_ply, write_ply
from backend.splats.viewer_colors import (
    convert_colors,
    dc_from_f_dc,
    sh_display_error,
    srgb_decode,
    srgb_encode,
    srgb_slope,
)
from igs_contract import manifest


def make(kind, n=40, sh_degree=0, seed=0, hi=1.0):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(n, 3, generator=g) * hi
    s = GaussianSet.from_activated(kind, torch.randn(n, 3, generator=g), rgb, torch.randn(n, 3, generator=g) - 3,
                                   torch.rand(n, generator=g) * 0.9 + 0.05, quats=torch.randn(n, 4, generator=g),
                                   sh_degree=sh_degree)
    if sh_degree:
        s.params["shN"].data.normal_(std=0.05, generator=g)
        s.params["sh0"].data = (torch.rand(n, 1, 3, generator=g) * 0.3 - 0.5) / C0  # residual DC in [0, 0.3]
    return s


@pytest.fixture()
def ws(tmp_path):
    root = tmp_path / "ws"
    write_ply(root / "layers" / "albedo.ply", make("albedo"))
    write_ply(root / "layers" / "shading.ply", make("shading", seed=1, hi=4.0))  # unbounded: some > 1
    write_ply(root / "layers" / "residual.ply", make("residual", sh_degree=3, seed=2))
    edited = make("albedo", seed=3)
    write_ply(root / "edits" / "red" / "albedo.ply", edited)
    return root


def run_events(argv, capsys):
    code = main(["--events", *argv])
    captured = capsys.readouterr()
    events = [json.loads(line) for line in captured.out.splitlines()]
    result = next((e["data"] for e in events if e["event"] == "result"), None)
    return code, result, captured.err


def shown(path):
    """(N, 3) the DC colour a standard viewer shows for the PLY at ``path``."""
    f = read_splat_file(path)
    return dc_from_f_dc(f.arrays.f_dc)


def test_srgb_curve_and_its_inverse():
    x = np.array([-0.1, 0.0, 0.002, 0.0031308, 0.18, 0.5, 1.0, 8.0])
    y = srgb_encode(x)
    np.testing.assert_allclose(y[[1, 5, 6]], [0.0, 0.7353569830524495, 1.0], atol=1e-12)
    np.testing.assert_allclose(srgb_decode(y), x, atol=1e-12)
    np.testing.assert_allclose(y[0], -1.292)  # the linear segment continues below 0
    assert y[-1] > 2.4  # shading above 1 follows the power segment
    h = 1e-6  # the slope is the curve's derivative
    np.testing.assert_allclose(srgb_slope(x[4:7]), (srgb_encode(x[4:7] + h) - srgb_encode(x[4:7] - h)) / (2 * h),
                               rtol=1e-5)


@pytest.mark.parametrize("method", ["fit", "slope"])
def test_sh_conversion_goes_back(method):
    g = make("residual", n=200, sh_degree=3, seed=4)
    dc = dc_from_f_dc(g.params["sh0"].detach().numpy()[:, 0]) + 0.2  # positive everywhere: nothing clamps at 0
    rest = g.params["shN"].detach().numpy() * 0.5
    d2, r2 = convert_colors("residual", *convert_colors("residual", dc, rest, "to_srgb", method), "to_linear", method)
    tol = 1e-5 if method == "slope" else 2e-3  # the fit projects a curved function onto SH, both ways
    np.testing.assert_allclose(d2, dc, atol=tol)
    np.testing.assert_allclose(r2, rest, atol=tol)


def test_fit_beats_the_cruder_sh_conversions():
    g = make("residual", n=400, sh_degree=3, seed=5)
    g.params["shN"].data *= 4  # strong view dependence, where the conversions differ
    dirs = np.random.default_rng(0).normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    err = sh_display_error(g.params["sh0"].detach().numpy()[:, 0], g.params["shN"].detach().numpy(), dirs)
    assert err["fit_mean"] < err["keep_mean"] and err["fit_mean"] < err["drop_mean"]
    assert err["fit_p99"] < err["slope_p99"]


def test_albedo_ply_export_is_srgb_and_keeps_comments(ws, capsys):
    code, res, _ = run_events(["export", str(ws), "--layer", "albedo"], capsys)
    assert code == 0
    out = ws / "exports" / "albedo.ply"
    assert res["out"] == str(out) and res["format"] == "ply" and res["count"] == 40 and res["clipped"] == 0
    linear = read_ply(ws / "layers" / "albedo.ply")[0].colors.detach().numpy()
    np.testing.assert_allclose(shown(out), srgb_encode(linear), atol=2e-6)
    assert {"igs_layer albedo", "igs_space srgb", "igs_color rgb01"} <= set(ply_header_comments(out))
    m = manifest.read(manifest.manifest_path(out))
    assert (m.kind, m.space, m.format, m.count, m.sh_degree) == ("albedo", "srgb", "ply", 40, 0)
    assert m.sha256 == manifest.sha256_file(out) and m.source["layer"] == "albedo"


def test_residual_export_converts_sh(ws, capsys):
    code, res, _ = run_events(["export", str(ws), "--layer", "residual", "--sh-method", "slope"], capsys)
    assert code == 0 and res["sh_degree"] == 3
    src = read_splat_file(ws / "layers" / "residual.ply").arrays
    out = read_splat_file(res["out"]).arrays
    dc = dc_from_f_dc(src.f_dc)
    np.testing.assert_allclose(dc_from_f_dc(out.f_dc), srgb_encode(dc), atol=1e-5)
    np.testing.assert_allclose(out.f_rest, src.f_rest * srgb_slope(dc)[:, None, :], atol=1e-5)


def test_edit_albedo_export_default_name(ws, capsys):
    code, res, _ = run_events(["export", str(ws), "--edit", "red"], capsys)
    assert code == 0 and res["out"] == str(ws / "exports" / "albedo-red.ply")
    assert manifest.read(res["manifest"]).source["edit"] == "red"


@pytest.mark.parametrize("fmt,ext", [("compressed-ply", ".compressed.ply"), ("spz", ".spz"), ("splat", ".splat")])
def test_other_formats_warn_about_clipped_shading(ws, capsys, fmt, ext):
    if fmt == "splat":
        pytest.importorskip("ply2splat", reason="ply2splat has no wheel for this Python")
    code, res, err = run_events(["export", str(ws), "--layer", "shading", "--format", fmt], capsys)
    assert code == 0 and res["out"] == str(ws / "exports" / f"shading{ext}") and res["count"] == 40
    dc = srgb_encode(read_ply(ws / "layers" / "shading.ply")[0].colors.detach().numpy())
    lo, hi = LIMITS[fmt].get("dc", (-np.inf, np.inf))
    expected = int(((dc < lo) | (dc > hi)).any(axis=1).sum())
    assert res["clipped"] == expected
    if expected:
        assert f"{expected} of 40 Gaussians lie outside" in err
        assert expected > 0 and fmt != "compressed-ply"
    back = read_splat_file(res["out"])
    assert len(back.arrays) == 40 and back.identity.kind == "shading" and back.identity.space == "srgb"
    got = dc_from_f_dc(back.arrays.f_dc)
    if fmt != "compressed-ply":  # per-Gaussian 8-bit colours, clipped to the format's range
        step = C0 / (0.15 * 255) if fmt == "spz" else 1 / 255  # one 8-bit step of the stored colour
        np.testing.assert_allclose(got, np.clip(dc, lo, hi), atol=1.01 * step)  # ply2splat truncates


def test_export_format_follows_out_name_and_ply_source(tmp_path, capsys):
    src = tmp_path / "scan.ply"
    write_ply(src, make("albedo"))
    code, res, _ = run_events(["export", "--ply", str(src), "--out", str(tmp_path / "x.spz")], capsys)
    assert code == 0 and res["format"] == "spz" and manifest.identify(tmp_path / "x.spz").status == "manifest"
    code, res, _ = run_events(["export", "--ply", str(src)], capsys)
    assert code == 0 and res["out"] == str(tmp_path / "scan-export.ply")


@pytest.mark.parametrize("argv,words", [
    (["export", "{ws}", "--layer", "shading", "--edit", "red"], "--edit holds an edited albedo only"),
    (["export", "{ws}", "--edit", "nope"], "nope/albedo.ply: --edit nope has no baked albedo"),
    (["export", "{ws}"], "--layer is needed"),
    (["export", "--ply", "{ws}/missing.ply"], "missing.ply: --ply file not found"),
    (["export", "--ply", "{ws}/layers/albedo.ply", "--layer", "albedo"], "give one or the other"),
    (["export"], "give a workspace folder"),
    (["export", "{ws}/../nows", "--layer", "albedo"], "workspace folder not found"),
    (["export", "{ws}", "--edit", "../x"], "--edit must be a plain folder name"),
])
def test_bad_input_is_one_error_line(ws, capsys, argv, words):
    code = main([a.format(ws=ws) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and words in err[0] and err[0].startswith("igs export: error: ")


def test_empty_shading_file_error_names_it(ws, capsys):
    (ws / "layers" / "shading.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\n")
    code = main(["export", str(ws), "--layer", "shading"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "shading.ply" in err[0]
