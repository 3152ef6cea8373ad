"""Seeded albedo textures for the synthetic room, drawn with numpy.

Every texture is an ``(H, W, 3) uint8`` sRGB-encoded image, top row first, so the same array
goes into Blender (as a byte image in the sRGB colour space) and into a PNG beside an edit's
JSON. The patterns are deliberately high-frequency (stripes, tiles, lattices a few centimetres
wide) so that albedo detail is visible at the preset resolutions. The family's posters (photographs,
pattern patchworks, typography) are in :mod:`backend.synth.pictures`, re-exported here.
"""

from __future__ import annotations

import cv2
import numpy as np

# The family's posters, reachable here by name: the Blender-binary worker asks for ``textures.<name>``.
from backend.synth.pictures import patterns as patterns
from backend.synth.pictures import photo as photo
from backend.synth.pictures import typography as typography


def _smooth_noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Periodic value noise in [0, 1], (size, size): a random ``cells`` grid upsampled smoothly."""
    grid = rng.random((cells, cells)).astype(np.float32)
    tiled = np.tile(grid, (3, 3))  # wrap so that the texture repeats without a seam
    up = cv2.resize(tiled, (3 * size, 3 * size), interpolation=cv2.INTER_CUBIC)
    return np.clip(up[size:2 * size, size:2 * size], 0.0, 1.0)


def _to_u8(rgb: np.ndarray) -> np.ndarray:
    return (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _palette(rng: np.random.Generator, base: list[tuple[float, float, float]], jitter: float = 0.06) -> np.ndarray:
    """Seeded variations of a base palette (sRGB values), (K, 3)."""
    p = np.asarray(base, dtype=np.float32)
    return np.clip(p + rng.uniform(-jitter, jitter, p.shape).astype(np.float32), 0.02, 0.95)


def wallpaper(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Vertical pin stripes with a small diamond motif: one tile, repeated across a wall."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    pal = _palette(rng, [(0.78, 0.72, 0.58), (0.55, 0.42, 0.36), (0.32, 0.45, 0.52)])
    img = np.broadcast_to(pal[0], (size, size, 3)).copy()
    stripes = (np.floor(x * 16) % 2 == 0) & ((x * 16) % 1 < 0.22)
    img[stripes] = pal[1]
    cx, cy = (x * 4) % 1 - 0.5, (y * 8) % 1 - 0.5
    diamond = (np.abs(cx) * 2 + np.abs(cy)) < 0.28
    img[diamond] = pal[2]
    img *= (0.92 + 0.08 * _smooth_noise(rng, size, 8))[..., None]
    return _to_u8(img)


def wood(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """Floor boards: eight planks per tile, each with its own tone and a wavy grain."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    planks = 8
    idx = np.floor(y * planks).astype(int)
    base = _palette(rng, [(0.58, 0.40, 0.24)], jitter=0.04)[0]
    tones = base[None] * rng.uniform(0.7, 1.15, (planks, 1)).astype(np.float32)
    warp = _smooth_noise(rng, size, 6)
    grain = 0.5 + 0.5 * np.sin((y * planks * 7.0 + warp * 3.0) * 2 * np.pi + x * 4.0)
    img = tones[idx] * (0.80 + 0.20 * grain)[..., None]
    seam = (y * planks) % 1 < 0.04
    img[seam] *= 0.45
    return _to_u8(img)


def kilim(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A rug of nested diamonds in four colours with a striped border (one rug per tile)."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    pal = _palette(rng, [(0.70, 0.16, 0.12), (0.90, 0.78, 0.52), (0.14, 0.22, 0.40), (0.20, 0.45, 0.30)])
    d = (np.abs((x * 6) % 1 - 0.5) + np.abs((y * 4) % 1 - 0.5)) * 8
    img = pal[np.floor(d).astype(int) % 4]
    border = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y))
    band = border < 0.07
    img[band] = pal[(np.floor(border[band] * 60).astype(int) % 2) * 2 + 1]
    return _to_u8(img)


def mosaic(rng: np.random.Generator, size: int = 256, tiles: int = 16) -> np.ndarray:
    """Small square tiles of random colours with dark grout lines."""
    pal = _palette(rng, [(0.85, 0.82, 0.74), (0.18, 0.36, 0.58), (0.62, 0.20, 0.18), (0.82, 0.62, 0.22),
                         (0.30, 0.52, 0.40)])
    choice = rng.integers(0, len(pal), (tiles, tiles))
    y, x = np.mgrid[0:size, 0:size] * tiles // size
    img = pal[choice[y, x]]
    frac_y = (np.arange(size) * tiles / size) % 1
    grout = (frac_y < 0.1)[:, None] | (frac_y < 0.1)[None, :]
    img[grout] = (0.25, 0.24, 0.22)
    return _to_u8(img)


def poster(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """The wall decal: a graphic poster (sunburst, rings and bars) that is unlike the wallpaper."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    pal = _palette(rng, [(0.95, 0.85, 0.25), (0.10, 0.12, 0.35), (0.90, 0.30, 0.15), (0.95, 0.95, 0.92)])
    r = np.hypot(x - 0.5, y - 0.42)
    ang = np.arctan2(y - 0.42, x - 0.5)
    img = np.where((np.floor(ang / (2 * np.pi) * 24) % 2 == 0)[..., None], pal[0], pal[2])
    img = np.where(((r < 0.28) & (np.floor(r * 40) % 2 == 0))[..., None], pal[1], img)
    bars = (y > 0.80) & (y < 0.92) & (np.floor(x * 20) % 3 != 0) & (x > 0.08) & (x < 0.92)
    img = np.where(bars[..., None], pal[1], img)
    corner = (x < 0.32) & (y < 0.16)  # breaks the symmetry: a flipped decal is visibly wrong
    img = np.where(corner[..., None], pal[3], img)
    frame = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y)) < 0.035
    img = np.where(frame[..., None], pal[3], img)
    return _to_u8(img)


def label(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """The column decal: a wrapped label with chevrons, dots and a band on its left edge."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    pal = _palette(rng, [(0.12, 0.50, 0.55), (0.96, 0.92, 0.80), (0.85, 0.25, 0.45)])
    chevron = (np.abs((x * 8) % 1 - 0.5) + y * 6) % 1 < 0.5
    img = np.where(chevron[..., None], pal[0], pal[1])
    dots = np.hypot((x * 10) % 1 - 0.5, (y * 10) % 1 - 0.5) < 0.18
    img = np.where((dots & (y > 0.7))[..., None], pal[2], img)
    img = np.where((x < 0.3)[..., None], pal[2] * (0.75 + 0.25 * chevron)[..., None], img)  # left band: shows orientation
    return _to_u8(img)


def painting(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A framed abstract painting for the side wall: overlapping soft blobs in strong colours."""
    img = np.zeros((size, size, 3), np.float32) + _palette(rng, [(0.85, 0.80, 0.70)])[0]
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    for _ in range(7):
        c = rng.uniform(0.15, 0.85, 2).astype(np.float32)  # x - c[0] in float32 under numpy 1 and 2 (NEP 50)
        rad = rng.uniform(0.08, 0.22)
        col = rng.uniform(0.05, 0.9, 3).astype(np.float32)
        inside = np.hypot(x - c[0], y - c[1]) < rad
        img[inside] = col
    frame = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y)) < 0.05
    img[frame] = (0.15, 0.10, 0.06)
    return _to_u8(img)


def tiles(rng: np.random.Generator, size: int = 256, tiles_per_side: int = 4) -> np.ndarray:
    """Floor tiles: a checker of two mottled stone tones with dark grout, ``tiles_per_side`` per tile side."""
    pal = _palette(rng, [(0.80, 0.76, 0.68), (0.42, 0.36, 0.32)], jitter=0.08)
    y, x = np.mgrid[0:size, 0:size] * tiles_per_side // size
    img = pal[(x + y) % 2] * (0.85 + 0.15 * _smooth_noise(rng, size, 16))[..., None]
    frac = (np.arange(size) * tiles_per_side / size) % 1
    grout = (frac < 0.04)[:, None] | (frac < 0.04)[None, :]
    img[grout] = (0.20, 0.19, 0.18)
    return _to_u8(img)


def mondrian(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A canvas of hard-edged rectangles (white, red, blue, yellow, black) between black bars, with a black
    border: every edge is sharp, so a recolour must follow it exactly."""
    pal = _palette(rng, [(0.93, 0.92, 0.88), (0.80, 0.10, 0.08), (0.10, 0.20, 0.60), (0.95, 0.80, 0.10),
                         (0.05, 0.05, 0.05)], jitter=0.04)
    def cuts(k: int) -> np.ndarray:  # jittered but evenly spread: no sliver cells
        return (np.arange(1, k + 1) + rng.uniform(-0.3, 0.3, k)) / (k + 1)

    xs, ys = cuts(int(rng.integers(2, 4))), cuts(int(rng.integers(2, 4)))
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    col, row = np.searchsorted(xs, x), np.searchsorted(ys, y)
    cells = rng.choice(len(pal), size=(len(ys) + 1, len(xs) + 1), p=[0.40, 0.20, 0.15, 0.15, 0.10])
    img = pal[cells[row, col]]
    bar = 0.018
    lines = (np.abs(x[..., None] - xs).min(axis=-1) < bar) | (np.abs(y[..., None] - ys).min(axis=-1) < bar)
    lines |= np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y)) < 0.03
    img[lines] = (0.04, 0.04, 0.04)
    return _to_u8(img)


def bands(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A rug of bold saturated stripes inside a solid border band with a thin contrasting line (one rug per tile)."""
    pal = _palette(rng, [(0.85, 0.12, 0.10), (0.95, 0.85, 0.55), (0.08, 0.30, 0.55), (0.15, 0.12, 0.10)])
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    stripes = int(rng.integers(5, 9))
    img = pal[np.floor(x * stripes).astype(int) % 3]
    edge = np.minimum(np.minimum(x, 1 - x), np.minimum(y, 1 - y))
    img[edge < 0.10] = pal[3]
    img[(edge >= 0.06) & (edge < 0.075)] = pal[1]
    return _to_u8(img)
