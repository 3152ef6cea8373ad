"""bench_train: ours and a competing trainer timed from one harness on one exported project.

The competitor here is a small stand-in program that checks what OpenSplat would read (the
transforms.json, the images, the points) and prints OpenSplat's per-step lines; the real OpenSplat
is built by scripts/build_opensplat.sh, which takes minutes, so the suite does not build it."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from backend.bench import bench_train, bench_train_ours
from backend.train.loop import load_checkpoint
from tests.support.train_scene import make_workspace

# Checks the project the way OpenSplat's nerfstudio reader needs it, records what it found, then prints
# a "Step N: loss (pct%)" line per iteration as `opensplat --cpu` does.
STAND_IN = '''#!{python}
import json, sys, time
from pathlib import Path
import cv2
from plyfile import PlyData
args = sys.argv[1:]
project = Path(args[0])
assert "--cpu" in args and args[args.index("-d") + 1] == "1" and args[args.index("--num-downscales") + 1] == "0"
n = int(args[args.index("-n") + 1])
t = json.loads((project / "transforms.json").read_text())
assert t["camera_model"] == "PINHOLE"
sizes = set()
for f in t["frames"]:
    img = cv2.imread(str(project / f["file_path"]))
    assert img.shape[:2] == (f["h"], f["w"]), f
    assert len(f["transform_matrix"]) == 4
    sizes.add((f["w"], f["h"]))
points = len(PlyData.read(str(project / t["ply_file_path"]))["vertex"])
with open("{record}", "a") as rec:
    rec.write(json.dumps({{"points": points, "sizes": sorted(sizes), "frames": len(t["frames"])}}) + "\\n")
if {fail}:
    print("cannot load images", file=sys.stderr)
    sys.exit(1)
for step in range(1, n + 1):
    time.sleep(0.003)
    print(f"Step {{step}}: 0.1 ({{step * 100 // n}}%)", flush=True)
'''


def stand_in(tmp_path: Path, fail: bool = False) -> tuple[Path, Path]:
    record = tmp_path / "stand_in.jsonl"
    exe = tmp_path / ("failing_trainer" if fail else "opensplat_stand_in")
    exe.write_text(STAND_IN.format(python=sys.executable, record=record, fail=fail))
    exe.chmod(0o755)
    return exe, record


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("bench_train") / "ws"
    make_workspace(root, n_views=6, width=48, height=36, n_points=300)
    return root


def test_both_programs_time_the_same_project_alternately(workspace, tmp_path):
    exe, record = stand_in(tmp_path)
    out = tmp_path / "bench_train.json"
    code = bench_train.main([str(workspace), "--opensplat", str(exe), "--copies", "1,2", "--iterations", "10",
                             "--warmup", "4", "--rounds", "2", "--out", str(out)])
    assert code == 0
    result = json.loads(out.read_text())
    assert result["resolution"] == [48, 36] and result["views"] == 6
    assert [r["gaussians"] for r in result["rows"]] == [300, 600]
    for row in result["rows"]:
        for prog in ("ours", "opensplat"):
            s = row[prog]
            assert s["iterations_timed"] == 20 and len(s["round_medians_ms"]) == 2
            assert s["ms_per_iteration"] > 0 and s["peak_rss_mib"] >= s["training_rss_mib"] > 0
            # launch to iteration 1: the interpreter and the loading, then a first step of at least 3 ms
            assert 0.003 < s["startup_s"] < 60
        # the stand-in sleeps 3 ms a step: its median cannot be below that
        assert row["opensplat"]["ms_per_iteration"] >= 3.0
        assert row["ours_over_opensplat"] == pytest.approx(
            row["ours"]["ms_per_iteration"] / row["opensplat"]["ms_per_iteration"], rel=0.01)
    seen = [json.loads(line) for line in record.read_text().splitlines()]
    # two rounds per point count; every image at the size ours trained at; the jittered copies
    assert [s["points"] for s in seen] == [300, 300, 600, 600]
    assert all(s["sizes"] == [[48, 36]] and s["frames"] == 6 for s in seen)


def test_ours_keeps_the_gaussian_count_fixed(workspace, tmp_path, capsys):
    points = tmp_path / "points.ply"
    from backend.capture.load import load_capture
    from backend.capture.transforms_io import write_ply_points

    cap = load_capture(workspace)
    write_ply_points(points, cap.points, cap.colors)
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"workspace": str(workspace), "downscale": 2, "points": str(points), "iterations": 12,
                                "sh_up_every": 2, "checkpoints": str(tmp_path / "ckpt")}))
    assert bench_train_ours.main([str(spec)]) == 0
    lines = capsys.readouterr().out.split()
    assert lines[:2] == ["gaussians", "300"]
    assert [int(x) for x in lines[3::2]] == list(range(1, 13))
    ckpt = load_checkpoint(tmp_path / "ckpt")
    assert ckpt["step"] == 12 and ckpt["params"]["means"].shape[0] == 300 and ckpt["active_sh_degree"] == 3


def test_a_bad_binary_or_a_failing_run_is_one_clear_error(workspace, tmp_path, capsys):
    code = bench_train.main([str(workspace), "--opensplat", str(tmp_path / "nope"), "--out", str(tmp_path / "o.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--opensplat" in err[0] and "nope" in err[0]

    exe, _ = stand_in(tmp_path, fail=True)
    code = bench_train.main([str(workspace), "--opensplat", str(exe), "--iterations", "5", "--warmup", "4",
                             "--rounds", "1", "--out", str(tmp_path / "o.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "failing_trainer exited with status 1" in err[-1] and "cannot load images" in err[-1]
    assert not (tmp_path / "o.json").exists()
