"""Our exports through the ecosystem's own tools and back: PlayCanvas splat-transform (npm) and gsply (pip).

splat-transform is found as backend.splats.formats_tools finds it (``./dev.sh test`` installs the
pinned version into the venv when npm exists); without it those tests skip with one line.
"""

import numpy as np
import pytest
import torch

from backend.commands.cli import main
from backend.splats.formats import read_splat_file
from backend.splats.formats_tools import SPLAT_TRANSFORM_VERSION, splat_transform
from backend.splats.gaussians import GaussianSet
from backend.splats.ply import read_ply, write_ply
from backend.splats.viewer_colors import dc_from_f_dc, srgb_encode

N = 300  # more than one chunk of 256 in a compressed PLY


@pytest.fixture()
def exported(tmp_path, capsys):
    g = torch.Generator().manual_seed(0)
    s = GaussianSet.from_activated("albedo", torch.randn(N, 3, generator=g), torch.rand(N, 3, generator=g),
                                   torch.randn(N, 3, generator=g) - 3, torch.rand(N, generator=g) * 0.9 + 0.05,
                                   quats=torch.randn(N, 4, generator=g))
    s.params["opacity_logits"].data[:3] = 30.0  # opaque: splat-transform writes these back as infinite logits
    write_ply(tmp_path / "albedo.ply", s)
    assert main(["export", "--ply", str(tmp_path / "albedo.ply"), "--out", str(tmp_path / "view.ply")]) == 0
    capsys.readouterr()
    return tmp_path, srgb_encode(s.colors.detach().numpy())


@pytest.fixture()
def tool():
    t = splat_transform()
    if t is None:
        pytest.skip("splat-transform not installed (./dev.sh test installs it when npm exists)")
    return t


def test_gsply_reads_our_export_exactly(exported):
    gsply = pytest.importorskip("gsply")
    tmp, shown = exported
    data = gsply.plyread(str(tmp / "view.ply"))
    assert len(data.means) == N
    np.testing.assert_allclose(dc_from_f_dc(np.asarray(data.sh0)), shown, atol=1e-6)


@pytest.mark.parametrize("ext,step", [(".compressed.ply", 1 / 255), (".spz", 0.2821 / 38.25), (".ply", 1e-6)])
def test_splat_transform_round_trip(exported, tool, ext, step, capsys):
    tmp, shown = exported
    assert tool.version() == SPLAT_TRANSFORM_VERSION
    tool.run([str(tmp / "view.ply"), str(tmp / f"tool{ext}")], what="test")
    tool.run([str(tmp / f"tool{ext}"), str(tmp / "tool-back.ply")], what="test")  # its own reader, back to PLY
    assert main(["convert", str(tmp / "tool-back.ply"), str(tmp / "ours.ply"), "--kind", "albedo",
                 "--space", "srgb"]) == 0
    capsys.readouterr()
    back = read_splat_file(tmp / "tool-back.ply").arrays
    assert len(back) == N
    got = dc_from_f_dc(back.f_dc)
    order = _match(read_splat_file(tmp / "view.ply").arrays.means, back.means)  # tools may reorder
    span = 1.0 if ext != ".compressed.ply" else np.ptp(shown, axis=0).max()  # per-chunk range, at most this
    np.testing.assert_allclose(got, shown[order], atol=1.01 * step * span + 1e-6)
    assert len(read_ply(tmp / "ours.ply")[0]) == N


def test_splat_transform_reads_dot_splat_and_spz_we_write(exported, tool, capsys):
    pytest.importorskip("ply2splat", reason="ply2splat has no wheel for this Python")
    tmp, _ = exported
    for ext in (".splat", ".spz"):
        assert main(["export", "--ply", str(tmp / "albedo.ply"), "--out", str(tmp / f"v{ext}")]) == 0
        tool.run([str(tmp / f"v{ext}"), str(tmp / f"v{ext}.ply")], what="test")
        assert len(read_splat_file(tmp / f"v{ext}.ply").arrays) == N
    capsys.readouterr()


def _match(ref: np.ndarray, other: np.ndarray) -> np.ndarray:
    """Indices into ``ref`` of each row of ``other`` (nearest position)."""
    d = ((other[:, None, :] - ref[None, :, :]) ** 2).sum(-1)
    return d.argmin(axis=1)
