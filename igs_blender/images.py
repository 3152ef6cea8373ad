"""Backend renders brought back as Blender images (a still, an image sequence, a movie)."""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np


def load_image(path: Path, name: str, *, sequence_length: int = 0, movie: bool = False) -> bpy.types.Image:
    """Load ``path`` as the image ``name`` (replacing what that image showed before).

    ``sequence_length`` > 0 makes it an image sequence starting at ``path`` (numbered files);
    ``movie`` loads a video file.
    """
    old = bpy.data.images.get(name)
    if old is not None:
        bpy.data.images.remove(old)
    image = bpy.data.images.load(str(path), check_existing=False)
    image.name = name
    if sequence_length > 0:
        image.source = "SEQUENCE"
        image["igs_frames"] = sequence_length
    elif movie:
        image.source = "MOVIE"
    image.reload()
    return image


def pixels(image: bpy.types.Image) -> np.ndarray:
    """(H, W, C) float32 pixels of a still image, top row first."""
    w, h = image.size
    buf = np.empty(w * h * image.channels, dtype=np.float32)
    image.pixels.foreach_get(buf)
    return buf.reshape(h, w, image.channels)[::-1]
