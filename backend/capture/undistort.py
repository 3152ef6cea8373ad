"""Undistortion to PINHOLE, one resampling map per camera applied alike to images, albedo and depth.

COLMAP chooses the undistorted camera (``pycolmap.undistort_camera``: same focal lengths, the
largest image without blank borders); we build the pixel map ourselves so that the very same
warp is applied to the frames and to every per-frame prior that comes with them (albedo maps are
resampled bilinearly like the images; depth maps by nearest neighbour, so that no depth is invented
between a foreground and a background surface). Undistortion keeps the camera's rotation and centre,
so a z-depth value stays valid at its new pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.cameras import Camera
from backend.core.errors import IGSError

PINHOLE_MODELS = ("PINHOLE", "SIMPLE_PINHOLE")


@dataclass(frozen=True)
class Intrinsics:
    """A COLMAP camera model by name with its parameters (COLMAP's order) and image size."""

    model: str
    width: int
    height: int
    params: tuple[float, ...]

    def to_pycolmap(self):
        import pycolmap

        try:
            return pycolmap.Camera(model=self.model, width=self.width, height=self.height, params=list(self.params))
        except Exception as e:
            raise IGSError(f"camera model {self.model} with parameters {[float(p) for p in self.params]}: {e}") from e

    @staticmethod
    def from_pycolmap(cam) -> Intrinsics:
        return Intrinsics(cam.model_name, int(cam.width), int(cam.height), tuple(float(p) for p in cam.params))


@dataclass
class Undistorter:
    """Warps images of one distorted camera to its PINHOLE counterpart.

    ``map_x``, ``map_y``: (H', W') float32 source pixel positions (OpenCV convention, pixel centres at
    integers) for every pixel of the undistorted image; ``None`` when the camera has no distortion.
    """

    source: Intrinsics
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    map_x: np.ndarray | None = None
    map_y: np.ndarray | None = None

    @property
    def identity(self) -> bool:
        return self.map_x is None

    def camera(self, name: str, R: np.ndarray, t: np.ndarray) -> Camera:
        """The undistorted camera with a given world-to-camera pose."""
        return Camera(name, self.width, self.height, self.fx, self.fy, self.cx, self.cy, R, t)

    def _fit(self, img: np.ndarray, interpolation: int) -> np.ndarray:
        """Resize a map made at another resolution (e.g. a predictor's output) to the source size."""
        h, w = img.shape[:2]
        if (w, h) == (self.source.width, self.source.height):
            return img
        return cv2.resize(img, (self.source.width, self.source.height), interpolation=interpolation)

    def image(self, img: np.ndarray) -> np.ndarray:
        """Undistort an image or albedo map (H, W[, C]), any dtype OpenCV remaps; bilinear."""
        img = self._fit(img, cv2.INTER_AREA if img.shape[1] > self.source.width else cv2.INTER_LINEAR)
        if self.identity:
            return img
        return cv2.remap(img, self.map_x, self.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """Undistort a z-depth map (H, W) float32; nearest neighbour, 0 (no data) outside the source."""
        depth = self._fit(np.asarray(depth, dtype=np.float32), cv2.INTER_NEAREST)
        if self.identity:
            return depth
        return cv2.remap(depth, self.map_x, self.map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=0.0)


def make_undistorter(intr: Intrinsics) -> Undistorter:
    """The undistortion of a camera: identity for pinhole models (or all-zero distortion), else COLMAP's choice."""
    import pycolmap

    cam = intr.to_pycolmap()
    extra = [intr.params[i] for i in cam.extra_params_idxs()]
    # A perspective model whose distortion terms are all zero is already a pinhole: keep every pixel
    # (COLMAP's undistortion would still crop a one-pixel border).
    if intr.model in PINHOLE_MODELS or (cam.is_perspective_pinhole() and not any(extra)):
        return Undistorter(intr, float(cam.focal_length_x), float(cam.focal_length_y),
                           float(cam.principal_point_x), float(cam.principal_point_y), intr.width, intr.height)
    und = pycolmap.undistort_camera(pycolmap.UndistortCameraOptions(), cam)
    fx, fy, cx, cy = (float(p) for p in und.params)
    w, h = int(und.width), int(und.height)
    # COLMAP pixel coordinates put the centre of the top-left pixel at (0.5, 0.5); OpenCV's at (0, 0).
    jj, ii = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(jj + 0.5 - cx) / fx, (ii + 0.5 - cy) / fy, np.ones_like(jj)], axis=-1).reshape(-1, 3)
    uv = np.asarray(cam.img_from_cam(rays, check_cheirality=False), dtype=np.float64).reshape(h, w, 2)
    map_x = (uv[..., 0] - 0.5).astype(np.float32)
    map_y = (uv[..., 1] - 0.5).astype(np.float32)
    return Undistorter(intr, fx, fy, cx, cy, w, h, map_x, map_y)


@dataclass
class FrameWarp:
    """From a frame as captured to its workspace image: undistortion, then a resize to the output size.

    Every per-frame map that comes with the capture goes through the same warp as the frame.
    """

    undistorter: Undistorter
    width: int
    height: int

    def _resize(self, img: np.ndarray, interp: int) -> np.ndarray:
        if (img.shape[1], img.shape[0]) == (self.width, self.height):
            return img
        return cv2.resize(img, (self.width, self.height), interpolation=interp)

    def image(self, img: np.ndarray) -> np.ndarray:
        """A frame or an albedo map (H, W[, C]) in the captured geometry -> the workspace geometry."""
        return self._resize(self.undistorter.image(img), cv2.INTER_AREA)

    def depth(self, depth: np.ndarray) -> np.ndarray:
        """A z-depth map (H, W) in the captured geometry -> the workspace geometry (nearest neighbour)."""
        return self._resize(self.undistorter.depth(depth), cv2.INTER_NEAREST)

    def resize(self, pred: np.ndarray) -> np.ndarray:
        """A map predicted from the workspace image itself, at another resolution: only resized (bilinear)."""
        return self._resize(np.asarray(pred, dtype=np.float32), cv2.INTER_LINEAR)

    @staticmethod
    def identity(camera: Camera) -> FrameWarp:
        """The warp of a frame that is already the undistorted workspace image."""
        intr = Intrinsics("PINHOLE", camera.width, camera.height, (camera.fx, camera.fy, camera.cx, camera.cy))
        return FrameWarp(make_undistorter(intr), camera.width, camera.height)
