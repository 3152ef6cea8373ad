"""Contact sheets: a labelled grid of images (report.png of ``igs decompose``), drawn with OpenCV."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from backend.core.imageio import write_image

Row = tuple[str, Sequence[tuple[str, "np.ndarray | None"]]]
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BG = 0.12  # sheet background gray
_TEXT = (0.92, 0.92, 0.92)


def _fit(img: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize (H, W, 3) to the cell size; nearest-neighbour when enlarging, so pixels stay visible."""
    if img.shape[1] == width and img.shape[0] == height:
        return img
    interp = cv2.INTER_NEAREST if width > img.shape[1] else cv2.INTER_AREA
    return cv2.resize(img, (width, height), interpolation=interp)


def _text(canvas: np.ndarray, text: str, x: int, y: int, scale: float) -> None:
    # drawn as an 8-bit coverage mask, then laid over the float sheet: OpenCV 5 draws on 8-bit images only.
    # Only the text's box is touched (the whole sheet's mask and blend were hundreds of MiB a line).
    (tw, th), base = cv2.getTextSize(text, _FONT, scale, 1)
    x0, y0 = max(0, x - 2), max(0, y - th - 2)
    x1, y1 = min(canvas.shape[1], x + tw + 2), min(canvas.shape[0], y + base + 2)
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
    cv2.putText(mask, text, (x - x0, y - y0), _FONT, scale, 255, 1, cv2.LINE_AA)
    a = mask.astype(np.float32)[..., None] / 255.0
    box = canvas[y0:y1, x0:x1]
    box[:] = box * (1.0 - a) + np.asarray(_TEXT, dtype=np.float32) * a


def contact_sheet(rows: Sequence[Row], title: str = "", min_cell_width: int = 192) -> np.ndarray:
    """Rows of labelled cells -> one (H, W, 3) float image in [0, 1] (sRGB-encoded).

    rows: (row label, [(column label, image (h, w, 3) in [0, 1] or None), ...]); every row has the
    columns of the first. ``title`` may hold several lines ("\n"): the first is the heading, the
    others (e.g. mean metrics) are drawn smaller under it. Cells are enlarged to at least
    ``min_cell_width`` pixels wide (integer factor) so that small captures stay readable; a missing
    image is an empty cell marked 'n/a'.
    """
    if not rows:
        raise ValueError("contact_sheet: no rows")
    first = next((img for _, cells in rows for _, img in cells if img is not None), None)
    h, w = (first.shape[:2] if first is not None else (96, 128))
    factor = max(1, -(-min_cell_width // w))
    cw, ch = w * factor, h * factor
    cols = [label for label, _ in rows[0][1]]
    pad, head, side = 4, 22, 0
    titles = title.split("\n") if title else []
    top = 26 + 16 * max(0, len(titles) - 1) if titles else 0
    sheet_w = side + len(cols) * (cw + pad) + pad
    sheet_h = top + head + len(rows) * (ch + pad + 16) + pad
    canvas = np.full((sheet_h, sheet_w, 3), _BG, dtype=np.float32)
    scale = 0.45
    for k, line in enumerate(titles):
        _text(canvas, line, pad, 18 + 16 * k, 0.5 if k == 0 else 0.4)
    for j, label in enumerate(cols):
        _text(canvas, label, side + pad + j * (cw + pad), top + 16, scale)
    for i, (row_label, cells) in enumerate(rows):
        y0 = top + head + i * (ch + pad + 16)
        _text(canvas, row_label, pad, y0 + 12, 0.4)
        y0 += 16
        for j, (_, img) in enumerate(cells):
            x0 = side + pad + j * (cw + pad)
            if img is None:
                canvas[y0:y0 + ch, x0:x0 + cw] = 0.2
                _text(canvas, "n/a", x0 + cw // 2 - 12, y0 + ch // 2, scale)
                continue
            canvas[y0:y0 + ch, x0:x0 + cw] = _fit(np.clip(img[..., :3], 0, 1).astype(np.float32), cw, ch)
    return canvas


def write_report(path: str | Path, rows: Sequence[Row], title: str = "") -> Path:
    """Write :func:`contact_sheet` of ``rows`` as an 8-bit PNG (atomically)."""
    path = Path(path)
    write_image(path, contact_sheet(rows, title))
    return path
