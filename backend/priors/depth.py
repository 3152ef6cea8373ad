"""Depth priors: ground truth (synthetic captures), maps from a folder, Depth Anything V2 (transformers).

Every predictor returns a map plus what it holds (``depth`` or ``disparity`` = inverse depth) and
which fit brings it to SfM units (``scale`` for metric/ground-truth depth, ``scale_shift`` for
relative predictions); :mod:`backend.priors.align` does the fit on the sparse points.

Spec strings (``igs import --depth``): ``none``, ``gt``, ``folder:<path>``, ``depth-anything`` (Small),
``depth-anything:base``, ``depth-anything:large``, ``depth-anything:<org/name>`` (any Hugging Face model id)
or ``depth-anything:<model dir>`` (a transformers checkpoint folder: ``config.json``, weights,
``preprocessor_config.json``). Ids go through the Hugging Face cache (:mod:`backend.priors.model_hub`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from backend.core.errors import IGSError
from backend.priors.folder import FolderMaps, PriorFrame, read_map
from backend.priors.model_hub import fetch_model, parse_model_arg

DEPTH_ANYTHING_DEFAULT = "depth-anything/Depth-Anything-V2-Small-hf"
DEPTH_ANYTHING_NAMED = {"small": DEPTH_ANYTHING_DEFAULT, "base": "depth-anything/Depth-Anything-V2-Base-hf",
                        "large": "depth-anything/Depth-Anything-V2-Large-hf"}
DEPTH_SPECS = ("none, gt, folder:<path>, depth-anything (= Small), depth-anything:base, depth-anything:large, "
               "depth-anything:<org/name>, depth-anything:<model dir>")


@dataclass(frozen=True)
class DepthOptions:
    """How depth maps from a folder are read."""

    folder_kind: Literal["depth", "disparity"] = "depth"
    """What folder maps hold: 'depth' (z-depth, any unit) or 'disparity' (inverse depth)."""
    fit: Literal["auto", "scale", "scale_shift"] = "auto"
    """Alignment model: 'scale', 'scale_shift' or 'auto' (scale for gt, scale_shift otherwise)."""
    device: str = "cpu"
    """Torch device for model predictors ('cpu', 'cuda', 'auto')."""


class DepthPredictor:
    """Per-frame depth prior. ``predict(frame, image)`` -> (H', W') float32, any resolution (resized later).

    ``image``: the undistorted frame, (H, W, 3) uint8 RGB. ``warp``: the map is in the geometry of the
    raw (distorted) frame and must be undistorted like it (maps that came with the capture); model
    predictions are made on the undistorted frame and are only resized.
    """

    label = "depth"
    kind = "depth"
    fit = "scale_shift"
    warp = True

    def predict(self, frame: PriorFrame, image: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def stamp(self) -> dict:
        """What identifies this predictor's output (for reusing cached predictions)."""
        return {"label": self.label, "kind": self.kind, "fit": self.fit}


class FolderDepth(DepthPredictor):
    """Depth (or inverse depth) maps from a folder: .npy, .exr, 16-bit PNG/TIFF, matched to frames."""

    label = "folder"

    def __init__(self, maps: FolderMaps, kind: str, fit: str):
        if kind not in ("depth", "disparity"):
            raise IGSError(f"--depth-kind must be 'depth' or 'disparity' (got '{kind}')")
        self.maps, self.kind, self.fit = maps, kind, fit

    def predict(self, frame: PriorFrame, image: np.ndarray) -> np.ndarray:
        path = self.maps.find(frame)
        m = read_map(path)
        self.maps.check_size(path, m, frame)
        if m.ndim == 3:
            m = m[:, :, 0]
        if (m < 0).any():
            raise IGSError(f"{path}: negative values in a {self.kind} map")
        return m

    def stamp(self) -> dict:
        return {**super().stamp(), "folder": str(self.maps.folder.resolve())}


class GroundTruthDepth(FolderDepth):
    """A synthetic capture's gt/depth maps (z-depth in the scene's units: only a scale to SfM's)."""

    label = "gt"


class DepthAnythingV2(DepthPredictor):
    """Depth Anything V2 through transformers, loaded from a checkpoint on disk (a folder, or the Hugging
    Face cache's snapshot of ``model_id``).

    Relative checkpoints predict affine-invariant inverse depth (fit scale and shift in disparity);
    metric checkpoints (``depth_estimation_type: metric``) predict metres (fit a scale in depth).
    """

    label = "depth-anything-v2"
    warp = False

    def __init__(self, model_dir: str | Path, device: str = "cpu", fit: str = "auto", model_id: str | None = None):
        self.model_dir, self.model_id = Path(model_dir), model_id
        config = self.model_dir / "config.json"
        if not config.exists():
            raise IGSError(f"{self.model_dir}: not a Depth Anything V2 checkpoint folder (no config.json); give a "
                           f"model id (e.g. depth-anything:{DEPTH_ANYTHING_DEFAULT}) or its downloaded folder")
        if not (self.model_dir / "preprocessor_config.json").exists():
            raise IGSError(f"{self.model_dir}: preprocessor_config.json missing (download the whole checkpoint folder)")
        try:
            cfg = json.loads(config.read_text())
        except json.JSONDecodeError as e:
            raise IGSError(f"{config}: not valid JSON ({e})") from e
        if cfg.get("model_type") != "depth_anything":
            raise IGSError(f"{config}: model_type is '{cfg.get('model_type')}', not 'depth_anything'")
        metric = cfg.get("depth_estimation_type", "relative") == "metric"
        self.kind = "depth" if metric else "disparity"
        self.fit = ("scale" if metric else "scale_shift") if fit == "auto" else fit
        self.device_name = device
        self.model = None  # loaded on first use: specs are validated before any long work starts

    def _load(self) -> None:
        import torch
        from transformers import AutoImageProcessor, DepthAnythingForDepthEstimation
        from transformers.utils import logging as hf_logging

        hf_logging.set_verbosity_error()  # our own progress bars and messages only
        hf_logging.disable_progress_bar()
        try:
            self.model = DepthAnythingForDepthEstimation.from_pretrained(str(self.model_dir), local_files_only=True)
            self.processor = AutoImageProcessor.from_pretrained(str(self.model_dir), local_files_only=True)
        except Exception as e:
            raise IGSError(f"{self.model_dir}: could not load the Depth Anything checkpoint ({e})") from e
        device = self.device_name
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() else "cpu"
        self.device = torch.device(device)
        self.model.to(self.device).eval()

    def predict(self, frame: PriorFrame, image: np.ndarray) -> np.ndarray:
        import torch

        if self.model is None:
            self._load()
        inputs = self.processor(images=image, return_tensors="pt")
        with torch.no_grad():
            out = self.model(pixel_values=inputs["pixel_values"].to(self.device)).predicted_depth
        return out[0].float().cpu().numpy()

    def stamp(self) -> dict:
        # By id: the id and the snapshot's commit, wherever the cache is; a folder: its path.
        if self.model_id:
            return {**super().stamp(), "model": self.model_id, "revision": self.model_dir.name}
        return {**super().stamp(), "model": str(self.model_dir.resolve())}


def make_depth_predictor(spec: str, gt_dir: Path | None, num_frames: int, num_video_frames: int | None,
                         options: DepthOptions = DepthOptions()) -> DepthPredictor | None:
    """The predictor named by ``spec`` (see :data:`DEPTH_SPECS`), or None for 'none'."""
    fit = options.fit
    if fit not in ("auto", "scale", "scale_shift"):
        raise IGSError(f"--depth-fit must be auto, scale or scale_shift (got '{fit}')")
    if spec in ("", "none"):
        return None
    if spec == "gt":
        if gt_dir is None or not gt_dir.is_dir():
            raise IGSError(f"--depth gt: the source has no ground-truth depth folder ({gt_dir or 'gt/depth'}); "
                           "gt is for synthetic captures made with `igs synth`")
        return GroundTruthDepth(FolderMaps(gt_dir, "ground-truth depth", num_frames, num_video_frames), "depth",
                                "scale" if fit == "auto" else fit)
    kind, _, arg = spec.partition(":")
    if kind == "folder" and arg:
        return FolderDepth(FolderMaps(Path(arg).expanduser(), "depth", num_frames, num_video_frames),
                           options.folder_kind, "scale_shift" if fit == "auto" else fit)
    if kind in ("depth-anything", "dav2"):
        source = parse_model_arg(f"--depth {kind}", arg, DEPTH_ANYTHING_DEFAULT, DEPTH_ANYTHING_NAMED)
        if source.folder is not None:
            return DepthAnythingV2(source.folder, options.device, fit)
        return DepthAnythingV2(fetch_model(source.repo_id, "depth-anything:<dir>"), options.device, fit,
                               source.repo_id)
    raise IGSError(f"--depth '{spec}': expected one of {DEPTH_SPECS}")
