"""LPIPS (Zhang et al. 2018, AlexNet variant v0.1), loaded only from weights already on disk.

The weights cannot be downloaded by this program. Put two files in ``$IGS_LPIPS_DIR``
(default ``~/.cache/intrinsic-splats/lpips``):

- ``alexnet.pth``: torchvision's ImageNet AlexNet state dict (``alexnet-owt-7be5be79.pth``,
  keys ``features.{0,3,6,8,10}.{weight,bias}``; any ``alexnet*.pth`` file name is accepted);
- ``alex.pth``: the LPIPS v0.1 linear heads from the ``lpips`` package
  (``lpips/weights/v0.1/alex.pth``, keys ``lin{0..4}.model.1.weight``).

When either is missing :func:`load_lpips` returns None and metrics report "n/a".
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import torch
from torch import nn

from backend.core.errors import IGSError

_CHANNELS = (64, 192, 384, 256, 256)
# LPIPS's input normalisation for inputs in [-1, 1]
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)


def lpips_dir() -> Path:
    return Path(os.environ.get("IGS_LPIPS_DIR", Path.home() / ".cache" / "intrinsic-splats" / "lpips"))


def weight_files(folder: Path | None = None) -> tuple[Path, Path] | None:
    """(alexnet features, linear heads) when both are present, else None."""
    folder = folder or lpips_dir()
    heads = folder / "alex.pth"
    nets = sorted(p for p in folder.glob("alexnet*.pth")) if folder.is_dir() else []
    if not heads.exists() or not nets:
        return None
    return nets[0], heads


class LPIPS(nn.Module):
    """LPIPS distance with AlexNet features: mean over pixels of weighted squared feature differences."""

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, 64, 11, stride=4, padding=2), nn.ReLU(),
            nn.MaxPool2d(3, 2), nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(),
            nn.MaxPool2d(3, 2), nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(),
            nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(),
            nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(),
        )
        self.taps = (1, 4, 7, 9, 11)  # outputs of the five ReLUs
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in _CHANNELS)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))

    def _feats(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = (x - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in self.taps:
                out.append(x / (x.square().sum(dim=1, keepdim=True).sqrt() + 1e-10))
        return out

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """a, b: (H, W, 3) in [0, 1] -> scalar distance."""
        x = a.permute(2, 0, 1)[None] * 2 - 1
        y = b.permute(2, 0, 1)[None] * 2 - 1
        total = x.new_zeros(())
        for fa, fb, lin in zip(self._feats(x), self._feats(y), self.lins):
            total = total + lin((fa - fb).square()).mean()
        return total

    def load_files(self, net_path: Path, heads_path: Path) -> LPIPS:
        try:
            net = torch.load(net_path, map_location="cpu", weights_only=True)
            heads = torch.load(heads_path, map_location="cpu", weights_only=True)
        except Exception as e:
            raise IGSError(f"{net_path.parent}: unreadable LPIPS weights ({e})") from e
        convs = [i for i, m in enumerate(self.features) if isinstance(m, nn.Conv2d)]
        state = {}
        for i in convs:
            for p in ("weight", "bias"):
                key = f"features.{i}.{p}"
                if key not in net:
                    raise IGSError(f"{net_path}: not a torchvision AlexNet state dict (no '{key}')")
                state[f"features.{i}.{p}"] = net[key]
        for j in range(len(_CHANNELS)):
            key = f"lin{j}.model.1.weight"
            if key not in heads:
                raise IGSError(f"{heads_path}: not LPIPS v0.1 linear heads (no '{key}')")
            state[f"lins.{j}.weight"] = heads[key]
        state["shift"], state["scale"] = self.shift, self.scale
        try:
            self.load_state_dict(state)
        except RuntimeError as e:
            raise IGSError(f"{net_path.parent}: LPIPS weights have the wrong shapes ({e})") from e
        return self.eval().requires_grad_(False)


@functools.lru_cache(maxsize=2)
def _load(net_path: str, heads_path: str) -> LPIPS:
    return LPIPS().load_files(Path(net_path), Path(heads_path))


def load_lpips() -> LPIPS | None:
    """The LPIPS model when its weights are on disk, else None."""
    files = weight_files()
    if files is None:
        return None
    return _load(str(files[0]), str(files[1]))
