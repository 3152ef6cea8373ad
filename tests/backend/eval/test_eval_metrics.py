import math

import torch

from backend.train import lpips as lpips_mod
from backend.train.image_metrics import image_metrics, lpips_or_none, mean_metrics, psnr


def test_psnr_of_known_error():
    a = torch.zeros(8, 8, 3)
    b = torch.full((8, 8, 3), 0.1)
    assert abs(psnr(b, a) - 20.0) < 1e-6
    assert psnr(a, a) == math.inf
    assert abs(psnr(torch.full((8, 8, 3), 2.0), torch.ones(8, 8, 3))) == math.inf  # clipped to [0, 1]


def test_lpips_is_na_without_weights(tmp_path, monkeypatch):
    monkeypatch.setenv("IGS_LPIPS_DIR", str(tmp_path / "nothing"))
    a = torch.rand(64, 64, 3)
    assert lpips_or_none(a, a) is None
    m = mean_metrics([image_metrics(a, a * 0.5)])
    assert m["lpips"] == "n/a" and m["psnr"] > 0 and 0 < m["ssim"] < 1


def test_lpips_loads_weight_files_from_disk(tmp_path, monkeypatch):
    # random weights in the two on-disk formats: checks the loading and the distance's basic properties
    torch.manual_seed(0)
    model = lpips_mod.LPIPS()
    net = {f"features.{k}": v for k, v in model.features.state_dict().items()}
    heads = {f"lin{j}.model.1.weight": torch.rand_like(lin.weight) for j, lin in enumerate(model.lins)}
    torch.save(net, tmp_path / "alexnet-owt-7be5be79.pth")
    torch.save(heads, tmp_path / "alex.pth")
    monkeypatch.setenv("IGS_LPIPS_DIR", str(tmp_path))
    lpips_mod._load.cache_clear()
    a, b = torch.rand(64, 80, 3), torch.rand(64, 80, 3)
    assert lpips_or_none(a, a) == 0.0
    d = lpips_or_none(a, b)
    assert d is not None and d > 0 and abs(d - lpips_or_none(b, a)) < 1e-6
    torch.save({"lin0.model.1.weight": torch.zeros(1)}, tmp_path / "alex.pth")
    lpips_mod._load.cache_clear()
    try:
        lpips_or_none(a, b)
    except Exception as e:
        assert "alex.pth" in str(e)
    else:
        raise AssertionError("malformed LPIPS heads were accepted")
    lpips_mod._load.cache_clear()
