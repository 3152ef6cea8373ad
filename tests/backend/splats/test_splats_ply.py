import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from backend.core.errors import IGSError
from backend.splats.gaussians import C0, GaussianSet
from backend.splats.ply import ply_header_comments, read_ply, write_ply

STANDARD = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
TAIL = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]


def make(kind, n=12, sh_degree=0, seed=0):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(n, 3, generator=g) * (4 if kind == "shading" else 1)
    s = GaussianSet.from_activated(kind, torch.randn(n, 3, generator=g), rgb, torch.randn(n, 3, generator=g) - 3,
                                   torch.rand(n, generator=g) * 0.9 + 0.05, quats=torch.randn(n, 4, generator=g),
                                   sh_degree=sh_degree)
    if sh_degree:
        s.params["shN"].data.normal_(generator=g)
    return s


@pytest.mark.parametrize("kind,deg", [("albedo", 0), ("shading", 0), ("residual", 3), ("radiance", 1),
                                      ("radiance", 0)])
def test_round_trip_every_kind(tmp_path, kind, deg):
    g = make(kind, sh_degree=deg)
    path = write_ply(tmp_path / f"{kind}.ply", g)
    h, info = read_ply(path)
    assert info.kind == kind and not info.foreign and info.space == "linear"
    assert h.kind == kind and h.sh_degree == deg and len(h) == len(g)
    for name, p in g.params.items():
        torch.testing.assert_close(h.params[name], p.detach(), atol=1e-5, rtol=1e-5)
    assert {"igs_layer " + kind, "igs_space linear"} <= set(ply_header_comments(path))


def test_standard_layout_and_viewer_colours(tmp_path):
    g = make("albedo")
    path = write_ply(tmp_path / "a.ply", g)
    v = PlyData.read(str(path))["vertex"].data
    assert list(v.dtype.names) == STANDARD + TAIL
    assert all(v.dtype[name] == np.dtype("<f4") for name in v.dtype.names)
    shown = np.stack([v[f"f_dc_{i}"] for i in range(3)], 1) * C0 + 0.5  # what a 3DGS viewer displays
    np.testing.assert_allclose(shown, g.colors.detach().numpy(), atol=1e-6)
    np.testing.assert_allclose(v["opacity"], g.params["opacity_logits"].detach().numpy())
    np.testing.assert_allclose(np.stack([v[f"scale_{i}"] for i in range(3)], 1), g.params["log_scales"].detach().numpy())
    assert "igs_color rgb01" in ply_header_comments(path)


def test_f_rest_is_channel_major_as_3dgs(tmp_path):
    g = make("radiance", n=3, sh_degree=1)
    path = write_ply(tmp_path / "r.ply", g)
    v = PlyData.read(str(path))["vertex"].data
    shn = g.params["shN"].detach().numpy()  # (N, 3 coeffs, 3 channels)
    for c in range(3):
        for k in range(3):
            np.testing.assert_allclose(v[f"f_rest_{c * 3 + k}"], shn[:, k, c])


def _write_foreign(path, n=5, n_rest=9, drop=(), extra=True, text=False, values=None):
    names = [p for p in STANDARD + [f"f_rest_{i}" for i in range(n_rest)] + TAIL if p not in drop]
    if extra:
        names.append("some_tool_field")
    rng = np.random.default_rng(0)
    rec = np.empty(n, dtype=[(p, "<f4") for p in names])
    for p in names:
        rec[p] = rng.normal(size=n)
    if values:
        for p, (i, val) in values.items():
            rec[p][i] = val
    PlyData([PlyElement.describe(rec, "vertex")], text=text).write(str(path))
    return rec


@pytest.mark.parametrize("text", [False, True])
def test_reads_ply_written_by_another_tool(tmp_path, text):
    rec = _write_foreign(tmp_path / "other.ply", text=text)
    g, info = read_ply(tmp_path / "other.ply")
    assert info.foreign and info.kind == "radiance" and g.sh_degree == 1 and len(g) == 5
    np.testing.assert_allclose(g.params["sh0"][:, 0, 1].detach().numpy(), rec["f_dc_1"], rtol=1e-6)
    np.testing.assert_allclose(g.params["shN"][:, 2, 1].detach().numpy(), rec["f_rest_5"], rtol=1e-6)
    a, info = read_ply(tmp_path / "other.ply", kind="albedo")  # the DC colour as an albedo layer
    assert a.kind == "albedo" and torch.all((a.colors >= 0) & (a.colors <= 1))


def test_ply_without_normals_reads(tmp_path):
    _write_foreign(tmp_path / "nonormals.ply", n_rest=0, drop=("nx", "ny", "nz"), extra=False)
    g, _ = read_ply(tmp_path / "nonormals.ply")
    assert g.sh_degree == 0 and len(g) == 5


def test_missing_property_is_named(tmp_path):
    _write_foreign(tmp_path / "bad.ply", drop=("scale_1", "opacity"))
    with pytest.raises(IGSError, match=r"bad\.ply.*missing.*opacity.*scale_1"):
        read_ply(tmp_path / "bad.ply")


def test_wrong_f_rest_count_is_rejected(tmp_path):
    _write_foreign(tmp_path / "rest.ply", n_rest=10)
    with pytest.raises(IGSError, match="10 f_rest"):
        read_ply(tmp_path / "rest.ply")


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_nan_and_inf_are_rejected(tmp_path, value):
    _write_foreign(tmp_path / "nan.ply", values={"scale_2": (3, value)})
    with pytest.raises(IGSError, match=r"NaN/inf values in 'scales'.*vertex 3"):
        read_ply(tmp_path / "nan.ply")


def test_truncated_file_is_rejected(tmp_path):
    path = write_ply(tmp_path / "t.ply", make("shading", n=50))
    data = path.read_bytes()
    (tmp_path / "cut.ply").write_bytes(data[: len(data) - 37])
    with pytest.raises(IGSError, match="cut.ply.*truncated"):
        read_ply(tmp_path / "cut.ply")


def test_not_a_ply_or_missing_or_empty(tmp_path):
    (tmp_path / "junk.ply").write_text("hello world\n")
    with pytest.raises(IGSError, match="junk.ply"):
        read_ply(tmp_path / "junk.ply")
    with pytest.raises(IGSError, match="not found"):
        read_ply(tmp_path / "nope.ply")
    _write_foreign(tmp_path / "empty.ply", n=0)
    with pytest.raises(IGSError, match="no Gaussians"):
        read_ply(tmp_path / "empty.ply")


def test_unknown_kind_comment_is_rejected(tmp_path):
    path = write_ply(tmp_path / "k.ply", make("albedo"))
    path.write_bytes(path.read_bytes().replace(b"igs_layer albedo", b"igs_layer diffuse", 1))
    with pytest.raises(IGSError, match="unknown layer kind 'diffuse'"):
        read_ply(path)


def test_per_gaussian_low_pass_round_trips_and_plain_sets_stay_standard(tmp_path):
    g = make("albedo")
    plain = write_ply(tmp_path / "plain.ply", g)
    assert "eps2d" not in PlyData.read(str(plain))["vertex"].data.dtype.names  # standard 3DGS layout
    sharp = g.with_filter(0.3)
    sharp.params["eps2d"].data[:3] = 0.1
    assert not sharp.params["eps2d"].requires_grad  # fixed, never trained
    path = write_ply(tmp_path / "sharp.ply", sharp)
    h, _ = read_ply(path)
    torch.testing.assert_close(h.eps2d, sharp.eps2d.detach())
    assert h.render_args()["eps2d"] is not None and g.render_args()["eps2d"] is None
    both = GaussianSet.concat([g, h])  # a set without values gets the renderer's default
    assert torch.equal(both.eps2d[: len(g)], torch.full((len(g),), 0.3)) and torch.equal(both.eps2d[len(g):], h.eps2d)


def test_raster_mode_is_written_and_read_back_and_old_files_are_classic(tmp_path):
    """A set's raster mode travels in ``comment igs_raster``; files without it (written before it
    existed, or by other tools) are read as classic, and copies of a set keep its mode."""
    g = make("residual", sh_degree=2)
    g.raster_mode = "antialiased"
    path = write_ply(tmp_path / "aa.ply", g)
    assert "igs_raster antialiased" in ply_header_comments(path)
    h, _ = read_ply(path)
    assert h.raster_mode == "antialiased" and h.render_args()["raster_mode"] == "antialiased"
    assert {h.clone().raster_mode, h.index(torch.arange(3)).raster_mode, h.with_filter(0.1).raster_mode} == {"antialiased"}
    old = tmp_path / "old.ply"
    old.write_bytes(path.read_bytes().replace(b"comment igs_raster antialiased\n", b"", 1))
    assert "igs_raster antialiased" not in ply_header_comments(old)
    assert read_ply(old)[0].raster_mode == "classic"
    assert "igs_raster classic" in ply_header_comments(write_ply(tmp_path / "c.ply", make("albedo")))
    with pytest.raises(ValueError, match="different raster modes"):
        GaussianSet.concat([h, read_ply(old)[0]])
    # an antialiased set without per-Gaussian values gets its own mode's default when concatenated
    sharp = h.with_filter(0.05)
    both = GaussianSet.concat([h, sharp])
    assert torch.equal(both.eps2d[: len(h)], torch.full((len(h),), 0.17))


def test_unknown_raster_mode_comment_is_rejected(tmp_path):
    path = write_ply(tmp_path / "r.ply", make("albedo"))
    path.write_bytes(path.read_bytes().replace(b"igs_raster classic", b"igs_raster mipmap", 1))
    with pytest.raises(IGSError, match=r"r.ply: unknown raster mode 'mipmap' in 'comment igs_raster'"):
        read_ply(path)
