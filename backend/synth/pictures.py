"""Seeded picture textures for the family's posters: saturated, high-frequency, many-coloured content.

A decomposition is easy to fool where the albedo changes fast and in every hue: its texture can
slip into the shading. These pictures are made of that: a procedural photograph (a landscape or a
still life, drawn from gradients, noise and shapes), a patchwork of patterns (stripes, checks, dots,
zigzags, rings, each cell in its own hues) and a typographic poster (lines of text over coloured
bands, drawn with OpenCV's ``putText``). Nothing is downloaded.

Each function returns an ``(height, width, 3) uint8`` sRGB-encoded image, top row first, like
:mod:`backend.synth.textures` (which re-exports them, so the Blender-binary worker can ask for them
by name). Detail is sized as a fraction of the picture's long side: on a poster about a metre
wide, checks, dots and stripes repeat every 4-10 cm, a few pixels at the `demo` preset from 2-3 m
(finer detail would only blur to its mean colour there). Every value lies in
:data:`PRINT_RANGE`, so the linear albedo stays within 0.005-0.89, inside the family's range (no
pure black, no pure white).
"""

from __future__ import annotations

import cv2
import numpy as np

PRINT_RANGE = (0.06, 0.95)
"""sRGB-encoded bounds of every picture value: linear albedo 0.0048 to 0.89."""

_WORDS = ("GALLERY", "SUMMER", "FESTIVAL", "OCEAN", "JAZZ", "MUSEUM", "NIGHT", "MARKET", "COLOUR", "SPLAT",
          "LIGHT", "GARDEN", "RADIO", "CINEMA", "TOUR", "OPEN", "DANCE", "CIRCUS", "PRISM", "NORTH",
          "VELVET", "ORBIT", "SALON", "ATLAS", "FOLK", "NEON", "OPERA", "HARBOUR", "STUDIO", "EXPO")
_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_PLAIN)


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    """One sRGB colour, (3,) float32, from hue (degrees), saturation and value in [0, 1]."""
    px = np.array([[[h % 360.0, s, v]]], np.float32)
    return cv2.cvtColor(px, cv2.COLOR_HSV2RGB)[0, 0]


def _hues(rng: np.random.Generator, n: int, s=(0.75, 1.0), v=(0.7, 0.95)) -> np.ndarray:
    """``n`` saturated colours with hues spread around the wheel (a random start, even steps, jitter), (n, 3)."""
    start = rng.uniform(0, 360)
    steps = start + np.arange(n) * 360.0 / n + rng.uniform(-12, 12, n)
    return np.stack([_hsv(h, rng.uniform(*s), rng.uniform(*v)) for h in rng.permutation(steps)])


def _finish(img: np.ndarray) -> np.ndarray:
    """Float sRGB in [0, 1] to uint8 within :data:`PRINT_RANGE`."""
    lo, hi = PRINT_RANGE
    return (np.clip(img, lo, hi) * 255.0 + 0.5).astype(np.uint8)


def _grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Pixel centres (y, x), each (H, W) float64 in units of the long side, and the long side in pixels.

    Float64, so that numpy 1 and 2 compute the same picture: with float32 coordinates a numpy scalar
    (a cosine, a cut) would keep float32 under numpy 1 and promote to float64 under numpy 2 (NEP 50).
    """
    long = float(max(height, width))
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    return (y + 0.5) / long, (x + 0.5) / long, long


def _noise1d(rng: np.random.Generator, n: int, knots: int) -> np.ndarray:
    """Smooth noise in [-1, 1] over ``n`` samples, from ``knots`` random values (cubic)."""
    k = rng.uniform(-1, 1, (1, knots)).astype(np.float32)
    return cv2.resize(k, (n, 1), interpolation=cv2.INTER_CUBIC)[0].clip(-1, 1)


def _noise2d(rng: np.random.Generator, height: int, width: int, cells: int) -> np.ndarray:
    """Smooth noise in [0, 1], (H, W), from a random ``cells``-wide grid (cubic)."""
    g = rng.random((max(2, cells * height // max(height, width)), cells)).astype(np.float32)
    return cv2.resize(g, (width, height), interpolation=cv2.INTER_CUBIC).clip(0, 1)


# --------------------------------------------------------------------------------------------
# patterns


def _pattern(kind: str, y: np.ndarray, x: np.ndarray, period: float, angle: float) -> np.ndarray:
    """Integer labels (H, W) of a two- or three-colour pattern with ``period`` (long-side units)."""
    c, s = np.cos(angle), np.sin(angle)
    u, v = (c * x + s * y) / period, (-s * x + c * y) / period
    if kind == "stripes":
        return (np.floor(u * 3) % 3).astype(int)  # three bands per period
    if kind == "checks":
        return ((np.floor(u) + np.floor(v)) % 2).astype(int)
    if kind == "dots":  # big dots in two colours, alternating cell by cell
        alt = (np.floor(u) + np.floor(v)) % 2 == 0
        return np.where(np.hypot(u % 1 - 0.5, v % 1 - 0.5) < 0.3, np.where(alt, 1, 2), 0)
    if kind == "zigzag":
        return (np.floor(2 * v + np.abs(u % 1 - 0.5) * 2) % 3).astype(int)
    if kind == "rings":
        return (np.floor(np.hypot(u % 4 - 2, v % 4 - 2) * 1.5) % 3).astype(int)
    # plaid: two crossing stripe sets, three colours
    return ((u % 1 < 0.35).astype(int) + (v % 1 < 0.35)).astype(int)


PATTERN_KINDS = ("stripes", "checks", "dots", "zigzag", "rings", "plaid")


def patterns(rng: np.random.Generator, width: int = 512, height: int = 384) -> np.ndarray:
    """A patchwork poster: a grid of cells, each a pattern of :data:`PATTERN_KINDS` in two or three
    saturated hues of its own, repeating every 4.5-9 % of the long side, between thin dark bars."""
    y, x, long = _grid(height, width)
    cols, rows = int(rng.integers(3, 6)), int(rng.integers(2, 5))
    xs = np.sort(rng.uniform(0.15, 0.85, cols - 1)) if cols > 1 else np.zeros(0)
    ys = np.sort(rng.uniform(0.15, 0.85, rows - 1)) if rows > 1 else np.zeros(0)
    col, row = np.searchsorted(xs * width / long, x), np.searchsorted(ys * height / long, y)
    img = np.zeros((height, width, 3), np.float32)
    for r in range(rows):
        for c in range(cols):
            cell = (row == r) & (col == c)
            kind = PATTERN_KINDS[int(rng.integers(len(PATTERN_KINDS)))]
            labels = _pattern(kind, y, x, float(rng.uniform(0.045, 0.09)), float(rng.uniform(0, np.pi)))
            pal = _hues(rng, 3)
            img[cell] = pal[labels[cell] % 3]
    bar = 0.006
    lines = np.zeros((height, width), bool)
    for cut in xs * width / long:
        lines |= np.abs(x - cut) < bar
    for cut in ys * height / long:
        lines |= np.abs(y - cut) < bar
    edge = np.minimum(np.minimum(x, width / long - x), np.minimum(y, height / long - y))
    img[lines | (edge < 0.015)] = (0.08, 0.07, 0.07)
    return _finish(img)


# --------------------------------------------------------------------------------------------
# typography


def _words(rng: np.random.Generator, n: int) -> str:
    return " ".join(_WORDS[int(i)] for i in rng.integers(len(_WORDS), size=n))


def _fit_scale(text: str, font: int, thickness: int, width_px: float) -> float:
    """The putText scale at which ``text`` is ``width_px`` wide."""
    (w, _), _ = cv2.getTextSize(text, font, 1.0, thickness)
    return width_px / max(w, 1)


def typography(rng: np.random.Generator, width: int = 512, height: int = 384) -> np.ndarray:
    """A typographic poster: four to six horizontal bands of saturated colour, a headline across the
    top band and lines of smaller text in other hues on the rest, a row of coloured squares and a
    checkered strip along the top and the bottom."""
    img = np.zeros((height, width, 3), np.uint8)
    n_bands = int(rng.integers(4, 7))
    cuts = np.r_[0, (np.arange(1, n_bands) + rng.uniform(-0.3, 0.3, n_bands - 1)) / n_bands, 1.0] * height
    band_cols = _hues(rng, n_bands, v=(0.55, 0.9))
    text_cols = _hues(rng, 6, s=(0.6, 1.0), v=(0.75, 0.95))
    light, dark = np.array([0.95, 0.93, 0.88]), np.array([0.08, 0.07, 0.07])
    for b in range(n_bands):
        img[int(cuts[b]):int(cuts[b + 1])] = (band_cols[b] * 255).astype(np.uint8)
    cell = max(3, int(0.03 * max(width, height)))  # a checkered strip along the top and the bottom, two hues
    pair = (_hues(rng, 2) * 255).astype(np.uint8)
    ys, xs = np.mgrid[0:cell, 0:width]
    strip = pair[((xs // cell) + (ys // cell)) % 2]
    img[:cell], img[height - cell:] = strip, strip
    side = max(4, int(0.04 * max(width, height)))  # a row of squares along the bottom, one per hue, under the text
    for i, col in enumerate(_hues(rng, 8)):
        x0 = int(0.03 * width) + i * int(1.4 * side)
        if x0 + side < width:
            img[height - 2 * side:height - side, x0:x0 + side] = (col * 255).astype(np.uint8)
    for b in range(n_bands):
        y0, y1 = int(cuts[b]), int(cuts[b + 1])
        band_h = y1 - y0
        if band_h < 12:
            continue
        font = _FONTS[int(rng.integers(len(_FONTS)))]
        if b == 0:  # the headline: one or two words across the width
            text, lines = _words(rng, int(rng.integers(1, 3))), 1
        else:  # small text: several lines a few percent of the long side high
            lines = max(1, int(band_h / (0.06 * max(width, height))))
            text = None
        line_h = band_h / lines
        for k in range(lines):
            words = text or _words(rng, int(rng.integers(2, 5)))
            scale = min(_fit_scale(words, font, 2, 0.92 * width), 0.8 * line_h / 22.0)
            thick = max(1, round(1.6 * scale))
            (tw, th), _ = cv2.getTextSize(words, font, scale, thick)
            # colour: another hue, or near white / black, whichever differs most from the band
            options = np.vstack([text_cols, light, dark])
            col = options[int(np.argmax(np.abs(options - band_cols[b]).sum(axis=1) + rng.uniform(0, 0.3, len(options))))]
            org = (int(rng.uniform(0.02, 0.98) * max(1, width - tw)), int(y0 + (k + 0.5) * line_h + th / 2))
            cv2.putText(img, words, org, font, scale, tuple(int(v * 255) for v in col), thick, cv2.LINE_AA)
    return _finish(img.astype(np.float32) / 255.0)


# --------------------------------------------------------------------------------------------
# photographs


def _landscape(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Sky gradient with clouds, a sun and striped balloons, three mountain ranges with jagged ridges,
    and rows of flowers in many colours running to a vanishing point."""
    y, x, long = _grid(height, width)
    H = height / long
    horizon = H * rng.uniform(0.4, 0.52)
    top, low = _hsv(rng.uniform(190, 290), 0.8, 0.75), _hsv(rng.uniform(10, 60), 0.7, 0.95)
    t = np.clip(y / horizon, 0, 1)[..., None]
    img = top * (1 - t) + low * t
    clouds = _noise2d(rng, height, width, 12) * _noise2d(rng, height, width, 40)
    img = np.where((clouds > 0.35)[..., None] & (y < horizon)[..., None], 0.92 * img + 0.08, img)
    sx, sy, sr = rng.uniform(0.2, 0.8) * width / long, horizon * rng.uniform(0.3, 0.7), rng.uniform(0.04, 0.07)
    img[np.hypot(x - sx, y - sy) < sr] = _hsv(rng.uniform(30, 60), 0.6, 0.95)
    for _ in range(int(rng.integers(3, 7))):  # balloons: discs of vertical stripes in three hues, a basket below
        bx, by, br = rng.uniform(0.05, 0.95) * width / long, rng.uniform(0.25, 0.75) * horizon, rng.uniform(0.025, 0.05)
        pal = _hues(rng, 3)
        inside = np.hypot(x - bx, (y - by) * 0.85) < br
        img[inside] = pal[(np.floor((x[inside] - bx + br) / (br / 3)) % 3).astype(int)]
        img[(np.abs(x - bx) < br * 0.2) & (y > by + 1.1 * br) & (y < by + 1.4 * br)] = (0.35, 0.2, 0.1)
    for layer in range(3):  # far to near: lower, darker, more saturated, more jagged
        ridge = horizon - H * (0.25 - 0.07 * layer) * (0.6 + 0.4 * _noise1d(rng, width, 6))
        ridge += H * 0.02 * _noise1d(rng, width, 60 + 40 * layer)
        below = y > ridge[None, :]
        col = _hsv(rng.uniform(0, 360), 0.45 + 0.2 * layer, 0.75 - 0.15 * layer)
        shade = (1.0 - 0.35 * np.clip((y - ridge[None, :]) / (0.2 * H), 0, 1))[..., None]
        img = np.where(below[..., None], col * shade, img)
    field = y > horizon
    vx = rng.uniform(0.3, 0.7) * width / long
    rows = (x - vx) / np.maximum(y - horizon, 1e-3)  # constant along a row running to the vanishing point
    idx = np.floor(rows * rng.uniform(5, 9)).astype(int)
    pal = _hues(rng, 6)
    flowers = pal[idx % 6] * (0.55 + 0.45 * ((y * rng.uniform(60, 90)) % 1 > 0.35))[..., None]
    gaps = (rows * rng.uniform(5, 9)) % 1 < 0.18
    flowers[gaps] = _hsv(rng.uniform(80, 140), 0.7, 0.4)
    return np.where(field[..., None], flowers, img)


def _still_life(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A wall of small dots, a gingham cloth on a table, shaded fruit and a striped vase."""
    y, x, long = _grid(height, width)
    H, W = height / long, width / long
    wall_a, wall_b, cloth_a, cloth_b = _hues(rng, 4, s=(0.55, 0.9), v=(0.65, 0.95))
    per = rng.uniform(0.045, 0.07)
    dots = np.hypot((x / per) % 1 - 0.5, ((y / per) + 0.5 * np.floor(x / per)) % 1 - 0.5) < 0.25
    img = np.where(dots[..., None], wall_b, wall_a)
    table = H * rng.uniform(0.55, 0.68)
    gp = rng.uniform(0.04, 0.07)
    u, v = x / gp, (y - table) / gp
    gingham = ((np.floor(u) % 2) + (np.floor(v) % 2)).astype(int)  # 0, 1, 2: light, mid, dark
    cloth = np.stack([np.full(3, 0.93, np.float32), cloth_a, cloth_b])[gingham]
    img = np.where((y > table)[..., None], cloth, img)
    vx, vw = rng.uniform(0.15, 0.85) * W, rng.uniform(0.1, 0.16)  # the vase, standing on the table
    vtop = table - H * rng.uniform(0.3, 0.45)
    vase = (np.abs(x - vx) < vw / 2 * (0.7 + 0.3 * np.sin(np.pi * np.clip((y - vtop) / (table - vtop), 0, 1)))) & \
        (y > vtop) & (y < table + 0.01)
    stripes = _hues(rng, 3)[(np.floor((y - vtop) / rng.uniform(0.025, 0.04)) % 3).astype(int)]
    img = np.where(vase[..., None], stripes * (0.6 + 0.4 * np.cos((x - vx) / vw * np.pi))[..., None], img)
    for _ in range(int(rng.integers(5, 9))):  # fruit: shaded discs, lit from the upper left
        r = rng.uniform(0.04, 0.08)
        cx, cy = rng.uniform(0.08, 0.92) * W, table + rng.uniform(0.0, 0.6) * (H - table) - r * 0.3
        d = np.hypot(x - cx, y - cy)
        lit = np.clip(1 - np.hypot(x - cx + 0.4 * r, y - cy + 0.4 * r) / (1.6 * r), 0, 1)
        col = _hsv(rng.uniform(0, 360), rng.uniform(0.7, 1.0), 0.9)
        shadow = (np.hypot((x - cx - 0.3 * r) / 1.3, (y - cy - 0.8 * r) * 2.5) < r) & (d >= r)
        img = np.where(shadow[..., None], img * 0.55, img)
        img = np.where((d < r)[..., None], col * (0.35 + 0.65 * lit)[..., None] + 0.3 * (lit > 0.85)[..., None], img)
    return img


PHOTO_SCENES = ("landscape", "still_life")


def photo(rng: np.random.Generator, width: int = 512, height: int = 384) -> np.ndarray:
    """A procedural photograph: a landscape or a still life (:data:`PHOTO_SCENES`, drawn), with a
    white border and, on half of them, a caption of coloured text below."""
    scene = PHOTO_SCENES[int(rng.integers(len(PHOTO_SCENES)))]
    img = (_landscape if scene == "landscape" else _still_life)(rng, height, width)
    img = np.clip(img, 0, 1)
    y, x, long = _grid(height, width)
    edge = np.minimum(np.minimum(x, width / long - x), np.minimum(y, height / long - y))
    img[edge < 0.02] = 0.93
    out = _finish(img)
    if rng.random() < 0.5:  # a caption band
        band = int(0.12 * height)
        out[height - band:] = _finish(np.broadcast_to(_hsv(rng.uniform(0, 360), 0.8, 0.35), (band, width, 3)))
        text = _words(rng, 2)
        font = _FONTS[int(rng.integers(len(_FONTS)))]
        scale = min(_fit_scale(text, font, 2, 0.9 * width), 0.7 * band / 22.0)
        (tw, th), _ = cv2.getTextSize(text, font, scale, 2)
        col = tuple(int(v * 255) for v in _hsv(rng.uniform(0, 360), 0.5, 0.95))
        cv2.putText(out, text, ((width - tw) // 2, height - (band - th) // 2), font, scale, col, 2, cv2.LINE_AA)
        out = _finish(out.astype(np.float32) / 255.0)
    return out
