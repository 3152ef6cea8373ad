"""Priors by Hugging Face model id: tiny random checkpoints placed in a temporary hub cache in the
layout huggingface_hub keeps (models--org--name/snapshots/<commit>, refs/main), the hub offline, and
`igs priors` loading them by id end to end. Nothing is downloaded."""

import hashlib
import json
import shutil
from pathlib import Path

import huggingface_hub.constants
import numpy as np
import pytest

from backend.capture.importer import ImportConfig
from backend.capture.load import load_capture
from backend.commands.cli import main
from backend.commands.import_capture import import_with_priors
from backend.core.errors import IGSError
from backend.priors import model_hub
from backend.priors.albedo import MARIGOLD_DEFAULT, make_albedo_predictor
from backend.priors.apply import PriorsConfig, compute_priors
from backend.priors.depth import DEPTH_ANYTHING_DEFAULT, make_depth_predictor
from backend.priors.model_hub import parse_model_arg, select_files
from tests.support.import_scene import write_capture
from tests.support.tiny_priors import tiny_depth_anything, tiny_marigold  # noqa: E402


def place_in_cache(cache, repo_id, built):
    """Copy a built checkpoint folder into the hub cache as the snapshot of refs/main."""
    commit = hashlib.sha1(repo_id.encode()).hexdigest()
    repo = cache / ("models--" + repo_id.replace("/", "--"))
    shutil.copytree(built, repo / "snapshots" / commit)
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(commit)
    return commit


@pytest.fixture
def offline_cache(tmp_path, monkeypatch):
    cache = tmp_path / "hub"
    cache.mkdir()
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(cache))
    # huggingface_hub reads both at import time: its constants are what it uses.
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(cache))
    monkeypatch.setattr(model_hub, "_resolved", {})
    return cache


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    root = tmp_path_factory.mktemp("room")
    write_capture(root / "src", n=6, width=96, height=72)
    import_with_priors(root / "src", root / "ws", ImportConfig())
    return root / "ws"


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    (root / "m").mkdir()
    return tiny_marigold(root / "m" / "marigold"), tiny_depth_anything(root / "dav2")


def test_igs_priors_loads_models_by_id_from_the_hub_cache(workspace, models, offline_cache):
    marigold, dav2 = models
    place_in_cache(offline_cache, "org/tiny-marigold", marigold)
    depth_commit = place_in_cache(offline_cache, DEPTH_ANYTHING_DEFAULT, dav2)
    assert main(["priors", str(workspace), "--albedo", "marigold:org/tiny-marigold", "--depth", "depth-anything",
                 "--albedo-steps", "1"]) == 0
    cap = load_capture(workspace, need_albedo=True, need_depth=True)
    assert cap.meta["priors"] == {"albedo": "marigold", "depth": "depth-anything-v2"}
    settings = cap.meta["prior_settings"]
    assert settings["depth"]["model"] == DEPTH_ANYTHING_DEFAULT and settings["depth"]["revision"] == depth_commit
    assert settings["albedo"]["model"] == "org/tiny-marigold"
    for f in cap.frames:
        d = np.load(f.depth)
        assert d.shape == (72, 96) and np.isfinite(d).all() and (d >= 0).all()
        assert f.albedo is not None and f.albedo.exists()
    # Bare `marigold` is the default id: the tiny pipeline placed under that name is what loads.
    place_in_cache(offline_cache, MARIGOLD_DEFAULT, marigold)
    compute_priors(workspace, PriorsConfig(albedo="marigold"))
    settings = load_capture(workspace, need_albedo=True).meta["prior_settings"]
    assert settings["albedo"]["model"] == MARIGOLD_DEFAULT and settings["albedo"]["spec"] == "marigold"


def test_a_model_missing_offline_is_one_clear_error(offline_cache, tmp_path):
    with pytest.raises(IGSError) as err:
        make_albedo_predictor("marigold:org/absent", None, 3, None)
    assert str(err.value).startswith(
        "model org/absent is not in the cache and the network is unreachable: download it with "
        "`huggingface-cli download org/absent` (or `hf download org/absent`), or point at a folder with "
        "marigold:<dir>")
    with pytest.raises(IGSError, match="model depth-anything/Depth-Anything-V2-Large-hf is not in the cache.*"
                       "depth-anything:<dir>"):
        make_depth_predictor("depth-anything:large", None, 3, None)
    assert main(["priors", str(tmp_path), "--depth", "depth-anything:base"]) == 2  # a user error, not a crash


def test_folders_stay_folders_and_bad_arguments_are_named(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "org" / "name").mkdir(parents=True)
    (tmp_path / "large").mkdir()
    assert parse_model_arg("--depth depth-anything", "org/name", "a/b").folder == Path("org/name")
    assert parse_model_arg("--depth depth-anything", "large", "a/b", {"large": "x/y"}).folder == Path("large")
    assert parse_model_arg("--depth depth-anything", "", "a/b").repo_id == "a/b"
    assert parse_model_arg("--depth depth-anything", "org/other", "a/b").repo_id == "org/other"
    with pytest.raises(IGSError, match="--albedo marigold:not an id: no such folder"):
        make_albedo_predictor("marigold:not an id", None, 3, None)


def test_one_weight_format_per_folder_without_precision_variants():
    files = {"model_index.json": 1, "README.md": 1, ".gitattributes": 1, "unet/config.json": 1,
             "unet/diffusion_pytorch_model.safetensors": 9, "unet/diffusion_pytorch_model.fp16.safetensors": 5,
             "unet/diffusion_pytorch_model.bin": 9, "vae/diffusion_pytorch_model.fp16.safetensors": 5,
             "text_encoder/pytorch_model.bin": 9, "tokenizer/vocab.json": 1}
    assert select_files(files) == ["model_index.json", "text_encoder/pytorch_model.bin", "tokenizer/vocab.json",
                                   "unet/config.json", "unet/diffusion_pytorch_model.safetensors",
                                   "vae/diffusion_pytorch_model.fp16.safetensors"]


def test_a_missing_model_is_downloaded_with_progress_then_found_offline(offline_cache, models, monkeypatch, capsys):
    """The Hub's two calls stand in for the network (listing, one file): what is fetched, the bytes stage,
    refs/main for later offline runs and cancelling are ours."""
    import huggingface_hub
    from huggingface_hub.file_download import repo_folder_name

    from backend.core import events
    from backend.core.errors import Cancelled

    _, dav2 = models
    repo_id, commit = "org/tiny-depth", "c" * 40
    files = {p.relative_to(dav2).as_posix(): p.stat().st_size for p in dav2.rglob("*") if p.is_file()}
    listed = {**files, "pytorch_model.bin": 7, "README.md": 3}
    info = type("Info", (), {"sha": commit, "siblings": [type("S", (), {"rfilename": n, "size": s})()
                                                         for n, s in listed.items()]})()
    fetched = []

    def fake_download(repo, name, revision, cache_dir, tqdm_class):
        fetched.append(name)
        target = offline_cache / repo_folder_name(repo_id=repo, repo_type="model") / "snapshots" / revision / name
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(dav2 / name, target)
        bar = tqdm_class(total=listed[name])
        bar.update(listed[name] // 2)
        bar.update(listed[name])  # more than the file holds: capped
        return str(target)

    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", False)
    monkeypatch.setattr(huggingface_hub.HfApi, "model_info", lambda self, repo, files_metadata: info)
    monkeypatch.setattr(huggingface_hub, "hf_hub_download", fake_download)
    monkeypatch.setattr(events, "_state", {"json": True})
    pred = make_depth_predictor(f"depth-anything:{repo_id}", None, 3, None)
    assert sorted(fetched) == sorted(files) and pred.stamp()["revision"] == commit
    progress = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    progress = [e for e in progress if e.get("stage") == f"download {repo_id}" and "step" in e]
    assert progress[-1]["step"] == progress[-1]["total"] == sum(files.values())
    assert (offline_cache / "models--org--tiny-depth" / "refs" / "main").read_text() == commit

    # Offline, in a new process (nothing remembered): found in the cache through refs/main.
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", True)
    monkeypatch.setattr(model_hub, "_resolved", {})
    assert model_hub.fetch_model(repo_id, "depth-anything:<dir>") == pred.model_dir

    # A cancel during a download stops it.
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_OFFLINE", False)
    monkeypatch.setattr(model_hub, "_resolved", {})
    monkeypatch.setattr(events, "_cancel", type("Flag", (), {"is_set": lambda self: bool(fetched)})())
    fetched.clear()
    with pytest.raises(Cancelled):
        model_hub.fetch_model(repo_id, "depth-anything:<dir>")
    assert len(fetched) == 1
