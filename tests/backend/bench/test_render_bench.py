"""The render benchmark runs end to end on a tiny configuration and writes its JSON."""

import json

from backend.bench import bench_render
from backend.bench.bench_scene import room_camera, room_layers


def test_bench_render_writes_table_and_json(tmp_path, capsys):
    out = tmp_path / "bench.json"
    rc = bench_render.main(["--sizes", "40x30", "--counts", "600", "--repeats", "1", "--reference-repeats", "1",
                            "--fused-count", "900", "--profile", "40x30x600", "--out", str(out)])
    assert rc == 0
    result = json.loads(out.read_text())
    row = result["backends"][0]
    assert row["gaussians"] == 600 and row["cpu_fwdbwd_ms"] > 0 and row["reference_fwdbwd_ms"] > 0
    assert result["fused"][0]["layers"] == {"albedo": 549, "shading": 324, "residual": 27}
    assert result["profile"]["forward_evaluations"] > 0
    assert "Three layers" in capsys.readouterr().out


def test_bench_scene_is_a_room_not_noise():
    layers = room_layers(3000)
    cam = room_camera(64, 48)
    albedo = layers["albedo"]
    # Gaussians lie on surfaces: each is flat (smallest scale well below the largest) ...
    s = albedo.scales.sort(dim=1).values
    assert (s[:, 0] < 0.2 * s[:, 2]).float().mean() > 0.9
    # ... most are opaque, and the room surrounds the camera (it sees walls in every direction).
    assert (albedo.opacities > 0.5).float().mean() > 0.5
    from backend.render import render

    o = render(albedo.means, albedo.quats, albedo.scales, albedo.opacities, albedo.colors, cam, backend="cpu")
    assert o.alpha.mean() > 0.9
    assert layers["residual"].sh_degree == 3
