"""The intrinsic image model ``I = A * S + R`` (paper 3.2), written once for every place that composes it."""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import torch

Image = TypeVar("Image", np.ndarray, torch.Tensor)


def compose(albedo: Image, shading: Image, residual: Image | None = None) -> Image:
    """Linear image from the layers, (..., 3) each (numpy arrays or torch tensors alike): the diffuse
    model ``A * S`` without ``residual``, the full model ``A * S + R`` with it."""
    diffuse = albedo * shading
    return diffuse if residual is None else diffuse + residual
