"""Viewport splats benchmark, in the real Blender window of the GUI tests: agreement, FPS, re-sort cost.

    .venv/bin/python tests_blender/bench_viewport.py [--workspace workspaces/demo] [--counts 100000,500000]

Needs root (the Debian root of ``./dev.sh test-blender``) and a decomposed workspace (``./dev.sh
demo`` makes ``workspaces/demo``). On the host it renders three capture views with ``igs render``
(the backend, timed: the baseline an artist had before, a PNG per view); in Blender 5.2 under Xvfb
(Mesa llvmpipe) ``viewport_bench_driver.py`` draws the same views with the viewport engine and
compares, times N splats against Blender's own N-point cloud, and times a re-sort. Prints a table,
writes ``artifacts/bench/viewport.json`` and the screenshots beside it.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from blender_session import DISPLAY, REPO, Mounts, build_root, copy_driver, copy_sources, in_root, why_not

RUN = "/root/igs-bench"


def capture_views(ws: Path, count: int) -> tuple[list[dict], str | None]:
    """The first ``count`` capture cameras (and the demo edit's view) in ``igs render --cameras`` form."""
    sys.path.insert(0, str(REPO))
    from backend.capture.load import load_capture

    frames = load_capture(str(ws)).frames
    edit_json = next(iter(sorted((ws / "gt_edit").glob("*/edit.json"))), None) if (ws / "gt_edit").is_dir() else None
    edit_view = json.loads(edit_json.read_text())["edit_view"] if edit_json else None
    chosen = frames[:count] + [f for f in frames if edit_view and f.camera.name == edit_view][:1]
    return [{"name": f.camera.name, "width": f.camera.width, "height": f.camera.height, "fx": f.camera.fx,
             "fy": f.camera.fy, "cx": f.camera.cx, "cy": f.camera.cy, "R": f.camera.R.tolist(),
             "t": f.camera.t.tolist()} for f in chosen], edit_view


def copy_workspace(ws: Path, dst: Path, root: Path) -> None:
    """The layers, cameras and edits the driver reads; absolute texture paths of the edits are mirrored."""
    dst.mkdir(parents=True)
    for name in ("layers", "edits", "sparse"):
        if (ws / name).is_dir():
            shutil.copytree(ws / name, dst / name)
    for name in ("transforms.json", "capture.json"):
        if (ws / name).is_file():
            shutil.copy2(ws / name, dst / name)
    for proxy in (ws / "edits").glob("*/proxy.json"):
        tex = json.loads(proxy.read_text()).get("texture")
        if tex and Path(tex).is_absolute() and Path(tex).is_file():
            (root / tex.lstrip("/")).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(tex, root / tex.lstrip("/"))


def table(res: dict, backend_s: float) -> str:
    lines = ["agreement with igs render (PSNR dB, 8-bit sRGB)", "| view | size | A | S | R | A*S+R |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['view']} | {r['size'][0]}x{r['size'][1]} | {r['A']} | {r['S']} | {r['R']} | {r['full']} |"
              for r in res["agreement"]]
    lines += ["", f"frames per second in the window ({res['gpu']})",
              "| splats | viewport | splats still | splats orbiting | Blender point cloud (baseline) | re-sort | order upload |",
              "|---|---|---|---|---|---|---|"]
    sort = {s["splats"]: s for s in res["sort"]}
    for r in res["fps"]:
        s = sort.get(r["splats"], {})
        lines.append(f"| {r['splats']:,} | {r['viewport'][0]}x{r['viewport'][1]} | {1 / r['splats_s']:.2f} | "
                     f"{1 / r['splats_orbit_s']:.2f} | {1 / r['points_s']:.2f} | {1000 * s.get('sort_s', 0):.0f} ms | "
                     f"{1000 * s.get('upload_s', 0):.0f} ms |")
    c = res.get("composite")
    if c:
        lines += ["", f"composite A*S+R, {c['splats']:,} splats in three layers, {c['viewport'][0]}x{c['viewport'][1]}: "
                      f"{1 / c['still_s']:.2f} fps still, {1 / c['orbit_s']:.2f} fps orbiting"]
    lines.append(f"backend `igs render` (CPU, 2 cores) of the same views: {backend_s:.2f} s a view")
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(prog="bench_viewport", description=__doc__.split("\n")[0])
    p.add_argument("--workspace", default=str(REPO / "workspaces" / "demo"))
    p.add_argument("--counts", default="100000,500000")
    p.add_argument("--views", type=int, default=2, help="capture views compared (plus the demo edit's view)")
    p.add_argument("--frames", type=int, default=5, help="frames timed per figure")
    p.add_argument("--out", default=str(REPO / "artifacts" / "bench"))
    args = p.parse_args()
    ws = Path(args.workspace)
    if not (ws / "layers" / "shading.ply").is_file():
        print(f"bench_viewport: error: {ws}: no decomposed layers (run ./dev.sh demo first)", file=sys.stderr)
        return 2
    why = why_not()
    if why:
        print(f"bench_viewport: error: {why}", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    views, edit_view = capture_views(ws, args.views)
    cams = out / "viewport-cameras.json"
    cams.write_text(json.dumps(views))
    refs = out / "viewport-refs"
    shutil.rmtree(refs, ignore_errors=True)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "backend", "render", str(ws), "--cameras", str(cams), "--out", str(refs)],
                   cwd=REPO, check=True, capture_output=True)
    backend_s = (time.perf_counter() - t0) / len(views)  # includes the process start, as a user pays it

    root = build_root()
    run = root / RUN.lstrip("/")
    shutil.rmtree(run, ignore_errors=True)
    (run / "out").mkdir(parents=True)
    copy_sources(run / "pkg" / "intrinsic_splats")
    copy_workspace(ws, run / "ws", root)
    shutil.copytree(refs, run / "refs")
    copy_driver("viewport_bench_driver.py", run)
    config = {"pkg": f"{RUN}/pkg", "workspace": f"{RUN}/ws", "refs": f"{RUN}/refs", "views": views,
              "edit_view": edit_view, "counts": [int(c) for c in args.counts.split(",")], "frames": args.frames,
              "out": f"{RUN}/out"}
    (run / "config.json").write_text(json.dumps(config))
    script = (f"Xvfb {DISPLAY} -screen 0 1600x1000x24 -nolisten tcp >{RUN}/xvfb.log 2>&1 & XP=$!; "
              f"for i in $(seq 50); do [ -e /tmp/.X11-unix/X{DISPLAY[1:]} ] && break; sleep 0.2; done; "
              f"DISPLAY={DISPLAY} timeout 3000 blender --factory-startup --python {RUN}/driver.py "
              f">{RUN}/blender.log 2>&1; rc=$?; kill $XP; exit $rc")
    with Mounts(root):
        in_root(root, script, 3100, {"IGS_BENCH_CONFIG": f"{RUN}/config.json", "TMPDIR": f"{RUN}",
                                     "BLENDER_USER_RESOURCES": f"{RUN}/user"})
    res_path = run / "out" / "viewport.json"
    if not res_path.is_file():
        print(f"bench_viewport: error: the Blender session wrote no result; log:\n"
              f"{(run / 'blender.log').read_text(errors='replace')[-3000:]}", file=sys.stderr)
        return 1
    res = json.loads(res_path.read_text())
    for f in (run / "out").glob("*.png"):
        shutil.copy2(f, out / f.name)
    res["backend_render_s_per_view"] = backend_s
    res["date"] = time.strftime("%Y-%m-%d")
    res["workspace"] = str(ws)
    (out / "viewport.json").write_text(json.dumps(res, indent=1))
    print(table(res, backend_s))
    if not res.get("done"):
        print(f"bench_viewport: the session stopped early:\n{res.get('fatal', '')}", file=sys.stderr)
        return 1
    print(f"wrote {out / 'viewport.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
