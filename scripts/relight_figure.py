"""The README's relighting figure: a held-out view of a synthetic capture before and after adding lights.

    .venv/bin/python scripts/relight_figure.py WS OUT.jpg [--view frame_0008.png] [--scale 2]

``WS`` is a decomposed workspace whose capture has added lights (``igs synth --lights``). Three panels,
each with its PSNR in the lit region against the truth where it applies:

1. the captured view (no added light);
2. ``igs render --light WS/gt_light/lights.json`` of that view (A * (S + S_new) + R, ours);
3. Cycles with the lights added (the captured view plus each light-only render: the truth).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.capture.load import load_capture  # noqa: E402
from backend.core.errors import IGSError  # noqa: E402
from backend.core.imageio import linear_to_srgb, read_exr, read_image, srgb_psnr, srgb_to_linear  # noqa: E402
from backend.scene_render.render_workspace import RenderConfig, render_workspace  # noqa: E402
from igs_contract.camera_json import camera_entry, cameras_document  # noqa: E402


def figure(ws: Path, view: str, out: Path, scale: int) -> dict[str, float]:
    capture = load_capture(ws)
    frame = capture.frame(view)
    lights_file = ws / "gt_light" / "lights.json"
    if not lights_file.is_file():
        raise IGSError(f"{lights_file}: missing (igs synth --lights adds the lights to a synthetic capture)")
    names = [li["name"] for li in json.loads(lights_file.read_text())["lights"]]
    captured = srgb_to_linear(read_image(frame.image))
    truth = captured + sum(read_exr(ws / "gt_light" / n / "images" / f"{Path(view).stem}.exr") for n in names)
    c = frame.camera
    with tempfile.TemporaryDirectory() as tmp:
        cams = Path(tmp) / "cams.json"
        cams.write_text(json.dumps(cameras_document([camera_entry(c.name, c.width, c.height, c.fx, c.fy, c.cx, c.cy,
                                                                  c.R.tolist(), c.t.tolist())])))
        render_workspace(ws, RenderConfig(cameras=str(cams), light=str(lights_file), layers="full",
                                          out=str(Path(tmp) / "lit")))
        (png,) = sorted((Path(tmp) / "lit" / "full").glob("*.png"))
        ours = srgb_to_linear(read_image(png))
    lit = np.abs(truth - captured).mean(-1) > 0.02  # where the added light shows
    scores = {"captured": srgb_psnr(captured[lit], truth[lit]), "ours": srgb_psnr(ours[lit], truth[lit])}
    panels = []
    for img, text in ((captured, f"captured  {scores['captured']:.1f} dB"), (ours, f"ours, lights added  {scores['ours']:.1f} dB"),
                      (truth, "Cycles, lights added (truth)")):
        p = (np.clip(linear_to_srgb(img), 0, 1) * 255).astype(np.uint8)[..., ::-1]
        p = cv2.resize(p, (p.shape[1] * scale, p.shape[0] * scale), interpolation=cv2.INTER_LANCZOS4)
        cv2.putText(p, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 2, cv2.LINE_AA)
        cv2.putText(p, text, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (20, 20, 20), 1, cv2.LINE_AA)
        panels.append(p)
    out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out), np.concatenate(panels, axis=1), [cv2.IMWRITE_JPEG_QUALITY, 90])
    return scores


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("workspace")
    p.add_argument("out")
    p.add_argument("--view", default="frame_0008.png", help="a held-out view with light renders (default frame_0008.png)")
    p.add_argument("--scale", type=int, default=2, help="upscale each panel by this factor (default 2)")
    a = p.parse_args()
    try:
        scores = figure(Path(a.workspace), a.view, Path(a.out), a.scale)
    except IGSError as e:
        print(f"relight_figure: error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {a.out}; lit-region PSNR against Cycles: captured {scores['captured']:.2f} dB, ours {scores['ours']:.2f} dB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
