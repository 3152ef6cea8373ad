"""Random Gaussian sets of each layer kind, seeded, for the add-on's file tests."""

from __future__ import annotations


def random_gaussians(kind: str, n: int, sh_degree: int = 0, seed: int = 0):
    import torch

    from backend.splats.gaussians import GaussianSet

    g = torch.Generator().manual_seed(seed)
    t = {"means": torch.randn(n, 3, generator=g), "quats": torch.randn(n, 4, generator=g),
         "log_scales": torch.randn(n, 3, generator=g) - 3, "opacity_logits": torch.randn(n, generator=g)}
    if kind in ("residual", "radiance"):
        t["sh0"] = torch.randn(n, 1, 3, generator=g)
        t["shN"] = torch.randn(n, (sh_degree + 1) ** 2 - 1, 3, generator=g) * 0.1
    else:
        t["colors"] = torch.randn(n, 3, generator=g)
    return GaussianSet(kind, t, sh_degree=sh_degree)
