"""Albedo priors: ground truth (synthetic captures), maps from a folder, and Marigold-IID (diffusers).

A predictor returns an sRGB-*encoded* albedo map in [0, 1] (H', W', 3), any resolution: the paper
(Implementation) treats predicted albedo like the input photos, inverse-gamma'd to pseudo-linear
when used, so the workspace stores albedo/NAME.png sRGB-encoded like images/.

Spec strings (``igs import --albedo``): ``none``, ``gt``, ``folder:<path>``, ``marigold`` (the default
model id), ``marigold:<org/name>`` (any Hugging Face model id) or ``marigold:<model dir>`` (a folder).

``folder:`` is how DiffusionRenderer's output comes in (run it on the video elsewhere, for long videos
with the brick-window schedule of :mod:`backend.priors.brick`); maps are matched by name or index.
``marigold`` loads a diffusers ``MarigoldIntrinsicsPipeline`` checkpoint, e.g.
``prs-eth/marigold-iid-appearance-v1-1`` (the default; targets albedo, roughness, metallicity) or
``prs-eth/marigold-iid-lighting-v1-1`` (albedo, shading, residual), from a folder or by id through the
Hugging Face cache (:mod:`backend.priors.model_hub`); it is a single-image model, so its maps are less
consistent across frames than a video model's.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from backend.core.errors import IGSError
from backend.core.imageio import linear_to_srgb
from backend.priors.folder import FolderMaps, PriorFrame, read_map
from backend.priors.model_hub import fetch_model, parse_model_arg

MARIGOLD_DEFAULT = "prs-eth/marigold-iid-appearance-v1-1"
ALBEDO_SPECS = "none, gt, folder:<path>, marigold (= marigold:" + MARIGOLD_DEFAULT + "), marigold:<org/name>, " \
    "marigold:<model dir>"


@dataclass(frozen=True)
class AlbedoOptions:
    """Settings of model-based albedo predictors."""

    device: str = "cpu"
    """Torch device ('cpu', 'cuda', 'auto')."""
    steps: int = 0
    """Denoising steps (0: the checkpoint's default)."""
    ensemble: int = 1
    """Predictions averaged per frame (Marigold's ensembling)."""
    resolution: int = 0
    """Processing resolution, longer side (0: the checkpoint's default)."""
    seed: int = 0
    """Noise seed, the same for every frame (steadier across frames)."""
    folder_space: Literal["srgb", "linear"] = "srgb"
    """What 8/16-bit folder maps hold: 'srgb' (encoded, like photos) or 'linear'. EXR maps are always linear."""


class AlbedoPredictor:
    """Per-frame albedo prior. ``predict(frame, image)`` -> (H', W', 3) float32 sRGB-encoded in [0, 1].

    ``image``: the undistorted frame, (H, W, 3) uint8 RGB. ``warp``: as for depth priors, maps that
    came with the capture are undistorted like the frames; model predictions are made on the
    undistorted frames.
    """

    label = "albedo"
    warp = True

    def predict(self, frame: PriorFrame, image: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def stamp(self) -> dict:
        return {"label": self.label}


class FolderAlbedo(AlbedoPredictor):
    """Albedo maps from a folder (PNG/JPEG/TIFF sRGB-encoded or linear, EXR linear), matched to frames."""

    label = "folder"

    def __init__(self, maps: FolderMaps, space: str = "srgb"):
        if space not in ("srgb", "linear"):
            raise IGSError(f"--albedo-space must be 'srgb' or 'linear' (got '{space}')")
        self.maps, self.space = maps, space

    def predict(self, frame: PriorFrame, image: np.ndarray) -> np.ndarray:
        path = self.maps.find(frame)
        m = read_map(path)
        self.maps.check_size(path, m, frame)
        if m.ndim == 2:
            m = np.repeat(m[:, :, None], 3, axis=2)
        if m.shape[2] != 3:
            raise IGSError(f"{path}: albedo map must have 1 or 3 channels, got {m.shape[2]}")
        if path.suffix.lower() == ".exr" or self.space == "linear":
            m = linear_to_srgb(m)
        return np.clip(m, 0.0, 1.0)

    def stamp(self) -> dict:
        return {"label": self.label, "folder": str(self.maps.folder.resolve()), "space": self.space}


class GroundTruthAlbedo(FolderAlbedo):
    """A synthetic capture's gt/albedo maps (16-bit sRGB-encoded PNG)."""

    label = "gt"


class MarigoldAlbedo(AlbedoPredictor):
    """Marigold intrinsic image decomposition (diffusers), the 'albedo' target, from a checkpoint on disk
    (a folder, or the Hugging Face cache's snapshot of ``model_id``)."""

    label = "marigold"
    warp = False

    def __init__(self, model_dir: str | Path, options: AlbedoOptions = AlbedoOptions(), model_id: str | None = None):
        self.model_dir, self.model_id = Path(model_dir), model_id
        index = self.model_dir / "model_index.json"
        if not index.exists():
            raise IGSError(f"{self.model_dir}: not a diffusers checkpoint folder (no model_index.json); give a "
                           f"Marigold model id (e.g. marigold:{MARIGOLD_DEFAULT}) or its downloaded folder")
        try:
            info = json.loads(index.read_text())
        except json.JSONDecodeError as e:
            raise IGSError(f"{index}: not valid JSON ({e})") from e
        if info.get("_class_name") != "MarigoldIntrinsicsPipeline":
            raise IGSError(f"{index}: a {info.get('_class_name')} checkpoint, not a MarigoldIntrinsicsPipeline")
        props = info.get("target_properties") or {}
        names = list(props.get("target_names", []))
        if "albedo" not in names:
            raise IGSError(f"{self.model_dir}: this Marigold checkpoint predicts {names or 'no named targets'}, "
                           "not 'albedo'")
        self.target = names.index("albedo")
        self.space = (props.get("albedo") or {}).get("prediction_space", "srgb")
        self.options = options
        self.pipe = None  # loaded on first use: specs are validated before any long work starts

    def _load(self) -> None:
        import torch
        from diffusers import MarigoldIntrinsicsPipeline
        from diffusers.utils import logging as df_logging
        from transformers.utils import logging as hf_logging

        for lib in (df_logging, hf_logging):  # our own progress bars and messages only
            lib.set_verbosity_error()
            lib.disable_progress_bar()
        try:
            self.pipe = MarigoldIntrinsicsPipeline.from_pretrained(str(self.model_dir), local_files_only=True)
        except Exception as e:
            raise IGSError(f"{self.model_dir}: could not load the Marigold intrinsics checkpoint ({e})") from e
        device = self.options.device
        if device == "auto":
            device = "cuda" if torch.cuda.is_available() else "cpu"
        self.device = torch.device(device)
        self.pipe.to(self.device)
        self.pipe.set_progress_bar_config(disable=True)

    def predict(self, frame: PriorFrame, image: np.ndarray) -> np.ndarray:
        import torch

        if self.pipe is None:
            self._load()
        gen = torch.Generator(device=self.device).manual_seed(self.options.seed)
        out = self.pipe(image.astype(np.float32)[None] / 255.0,
                        num_inference_steps=self.options.steps or None,
                        ensemble_size=self.options.ensemble,
                        processing_resolution=self.options.resolution or None,
                        generator=gen, output_type="np")
        pred = np.asarray(out.prediction)  # (num_targets, H, W, 3) for one image
        albedo = pred[self.target].astype(np.float32)
        if self.space == "linear":
            albedo = linear_to_srgb(albedo)
        return np.clip(albedo, 0.0, 1.0)

    def stamp(self) -> dict:
        o = self.options
        # By id: the id and the snapshot's commit, wherever the cache is; a folder: its path.
        model = ({"model": self.model_id, "revision": self.model_dir.name} if self.model_id
                 else {"model": str(self.model_dir.resolve())})
        return {"label": self.label, **model, "steps": o.steps,
                "ensemble": o.ensemble, "resolution": o.resolution, "seed": o.seed}


def make_albedo_predictor(spec: str, gt_dir: Path | None, num_frames: int, num_video_frames: int | None,
                          options: AlbedoOptions = AlbedoOptions()) -> AlbedoPredictor | None:
    """The predictor named by ``spec`` (see :data:`ALBEDO_SPECS`), or None for 'none'."""
    if spec in ("", "none"):
        return None
    if spec == "gt":
        if gt_dir is None or not gt_dir.is_dir():
            raise IGSError(f"--albedo gt: the source has no ground-truth albedo folder ({gt_dir or 'gt/albedo'}); "
                           "gt is for synthetic captures made with `igs synth`")
        return GroundTruthAlbedo(FolderMaps(gt_dir, "ground-truth albedo", num_frames, num_video_frames))
    kind, _, arg = spec.partition(":")
    if kind == "folder" and arg:
        return FolderAlbedo(FolderMaps(Path(arg).expanduser(), "albedo", num_frames, num_video_frames),
                            options.folder_space)
    if kind == "marigold":
        source = parse_model_arg("--albedo marigold", arg, MARIGOLD_DEFAULT)
        if source.folder is not None:
            return MarigoldAlbedo(source.folder, options)
        return MarigoldAlbedo(fetch_model(source.repo_id, "marigold:<dir>"), options, source.repo_id)
    raise IGSError(f"--albedo '{spec}': expected one of {ALBEDO_SPECS}")
