"""The ground-truth edits of a synthetic capture: each edited view rendered inside its mask's box, and
``gt_edit/<edit>/edit.json`` with the training view that best shows the edit.

Edits only differ where camera rays hit the edit region (:mod:`backend.synth.scene`), so each edited
view renders just the bounding box of its mask with a render border and takes every other pixel from
the original view: Cycles' sampling depends on the pixel, not on the border, so this is
bit-identical to a full render.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from backend.core import events
from backend.core.atomic_io import atomic_path, write_json
from backend.core.cameras import Camera
from backend.core.imageio import linear_to_srgb, read_exr, read_image, write_exr, write_image
from backend.core.workspace import Workspace
from backend.synth.module_renderer import ViewRenderer
from backend.synth.scene import EditSpec, SynthScene
from backend.synth.settings import HOLD_EVERY
from backend.synth.views import residual_from_passes


def _edit_files(ws: Workspace, edit: str, name: str) -> list[Path]:
    """The edited view's image and albedo (PNG) and its own shading and residual passes (EXR)."""
    stem = Path(name).stem
    return [ws.gt_edit / edit / "images" / name, ws.gt_edit / edit / "albedo" / name,
            ws.gt_edit / edit / "shading" / f"{stem}.exr", ws.gt_edit / edit / "residual" / f"{stem}.exr"]


def write_edit_definitions(ws: Workspace, scene: SynthScene) -> None:
    for e in scene.edits:
        if e.texture is not None:
            write_image(ws.gt_edit / e.name / "texture.png", e.texture.astype(np.float32) / 255.0)


def render_edits(ws: Workspace, scene: SynthScene, renderer: ViewRenderer, cameras: list[Camera],
                  tmp: Path) -> int:
    jobs = [(e.name, i) for e in scene.edits for i, c in enumerate(cameras)
            if not all(p.exists() for p in _edit_files(ws, e.name, c.name))]
    total = len(scene.edits) * len(cameras)
    rendered = 0
    with events.stage("render edits", total=total, initial=total - len(jobs), unit="view") as bar:
        for edit, i in jobs:
            cam = cameras[i]
            mask = read_image(ws.gt_edit / edit / "mask" / cam.name)[..., 0] > 0.5
            outs = _edit_files(ws, edit, cam.name)
            if not mask.any():  # camera rays never meet the region: the render would be identical
                for src, dst in zip(_edit_sources(ws, cam.name), outs):
                    _copy(src, dst)
            else:
                ys, xs = np.nonzero(mask)
                box = (int(xs.min()), int(ys.min()), int(xs.max()) + 1, int(ys.max()) + 1)
                scene.set_edit(edit)
                try:
                    P = renderer.render(cam, tmp / f"edit_{edit}_{i:04d}.exr", border=box)
                finally:
                    scene.set_edit(None)
                _write_edited_view(ws, cam, P, box, outs)
                rendered += 1
            bar.update(1, edit=edit)
    return rendered


def _edit_sources(ws: Workspace, name: str) -> list[Path]:
    """The unedited view's files that :func:`_edit_files` are edited copies of, in the same order."""
    stem = Path(name).stem
    return [ws.images / name, ws.gt_pass("albedo") / name, ws.gt_pass("shading") / f"{stem}.exr",
            ws.gt_pass("residual") / f"{stem}.exr"]


def _write_edited_view(ws: Workspace, cam: Camera, P: dict[str, np.ndarray], box: tuple[int, int, int, int],
                       outs: list[Path]) -> None:
    """The unedited view's files with the border render ``P`` pasted into ``box``: the edited image,
    albedo, and the edited render's own shading and residual (where a pixel mixes the region with its
    surroundings, or the region's old albedo was near black, the capture's shading does not give the
    edited image; these do, exactly)."""
    x0, y0, x1, y1 = box
    # Every rendered pixel, the world background included (film not transparent), has alpha 1; pixels
    # outside the render border are left 0. (Depth cannot tell: Cycles writes 1e10 for the background.)
    if not (P["Combined"][y0:y1, x0:x1, 3] > 0).all():
        raise RuntimeError(f"the border render of {cam.name} does not cover the pixels {box}")
    img_src, alb_src, sh_src, res_src = _edit_sources(ws, cam.name)
    img_out, alb_out, sh_out, res_out = outs
    crop = {k: v[y0:y1, x0:x1] for k, v in P.items()}
    image = read_image(img_src)
    image[y0:y1, x0:x1] = linear_to_srgb(crop["Combined"][..., :3])
    albedo = read_image(alb_src)
    albedo[y0:y1, x0:x1] = linear_to_srgb(crop["Diffuse Color"])
    shading = read_exr(sh_src)[..., :3]
    shading[y0:y1, x0:x1] = crop["Diffuse Direct"] + crop["Diffuse Indirect"]
    residual = read_exr(res_src)[..., :3]
    residual[y0:y1, x0:x1] = residual_from_passes(crop)
    write_image(alb_out, albedo, bits=16)
    write_exr(sh_out, shading)
    write_exr(res_out, residual)
    write_image(img_out, image)


def _copy(src: Path, dst: Path) -> None:
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)


def choose_edit_view(ws: Workspace, edit: str, cameras: list[Camera]) -> tuple[str, list[int]]:
    """The training view with the largest rectangle fully inside the edit region, and that rectangle.

    The mask is eroded by 2 pixels first, so that the rectangle holds only fully covered pixels.
    """
    import cv2

    scored = []
    for i, cam in enumerate(cameras):
        if i % HOLD_EVERY == 0 and len(cameras) > 1:
            continue
        mask = (read_image(ws.gt_edit / edit / "mask" / cam.name)[..., 0] > 0.5).astype(np.uint8)
        inner = cv2.erode(mask, np.ones((5, 5), np.uint8), borderValue=0)
        scored.append((int(inner.sum()), i, inner))
    scored.sort(key=lambda s: (-s[0], s[1]))
    best = (0, cameras[scored[0][1]].name if scored else cameras[0].name, [0, 0, 0, 0])
    for area, i, inner in scored[:6]:  # the largest rectangle usually lives in the largest region
        if area == 0:
            break
        rect = _largest_rectangle(inner.astype(bool))
        rect_area = (rect[2] - rect[0]) * (rect[3] - rect[1])
        if rect_area > best[0]:
            best = (rect_area, cameras[i].name, rect)
    if best[0] == 0:
        events.log(f"warning: the edit '{edit}' is not fully visible in any training view")
    return best[1], best[2]


def _largest_rectangle(mask: np.ndarray) -> list[int]:
    """Largest axis-aligned all-True rectangle of a boolean (H, W) mask: [x0, y0, x1, y1], x1/y1 exclusive."""
    h, w = mask.shape
    heights = np.zeros(w, dtype=int)
    best = (0, [0, 0, 0, 0])
    for y in range(h):
        heights = np.where(mask[y], heights + 1, 0)
        stack: list[int] = []
        for x in range(w + 1):
            cur = heights[x] if x < w else 0
            while stack and heights[stack[-1]] >= cur:
                top = stack.pop()
                left = stack[-1] + 1 if stack else 0
                area = int(heights[top]) * (x - left)
                if area > best[0]:
                    best = (area, [left, y - int(heights[top]) + 1, x, y + 1])
            stack.append(x)
    return best[1]


def write_edit_json(ws: Workspace, edit: EditSpec, edit_view: str, rect: list[int]) -> None:
    write_json(ws.gt_edit / edit.name / "edit.json", {
        "name": edit.name,
        "kind": edit.kind,
        "surface": edit.surface.to_json(),
        "texture": "texture.png" if edit.texture is not None else None,
        "color": list(edit.color) if edit.color is not None else None,
        "color_space": "texture: sRGB PNG; color: linear RGB albedo",
        "edit_view": edit_view,
        "rect": rect,
        "rect_convention": "[x0, y0, x1, y1] pixels of edit_view, x1 and y1 exclusive, all inside the region",
        "masks": "mask/NAME.png: white where any camera sample of the pixel hits the edited region",
        "lighting": "the edit is seen by camera rays only, so the light is the original capture's; shading/ "
                    "and residual/ are the edited render's own passes (albedo * shading + residual = images "
                    "exactly, also in pixels that mix the region with its surroundings)",
    })
