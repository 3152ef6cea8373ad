"""Checkpoints hold tensors and plain values only: a crafted checkpoint cannot run code when a
command resumes, anything else is refused with one error naming the file, and resume still works."""

import os
import pickle
import warnings

import numpy as np
import pytest
import torch

from backend.core.errors import IGSError
from backend.train.baseline import BaselineConfig, train_3dgs
from backend.train.loop import TrainConfig, load_checkpoint
from tests.support.train_scene import make_workspace


class _RunsCode:
    """Unpickling this calls ``os.system``: what a crafted checkpoint.pt would do."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture(scope="module")
def box_ws(tmp_path_factory):
    return make_workspace(tmp_path_factory.mktemp("box"), n_views=6, width=24, height=18)


def _config(iterations):
    train = TrainConfig(iterations=iterations, checkpoint_every=4, seed=1)
    train.scale_schedule = False
    return BaselineConfig(train=train, sh_degree=1, device="cpu")


def test_a_crafted_checkpoint_runs_nothing_and_is_refused(box_ws, tmp_path):
    ckpt_dir = box_ws.checkpoints / "train_3dgs"
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    marker = tmp_path / "pwned"
    torch.save({"version": 1, "payload": _RunsCode(marker)}, ckpt_dir / "checkpoint.pt")
    with pytest.raises(IGSError, match="checkpoint.pt.*could run code.*--restart"):
        load_checkpoint(ckpt_dir)
    with pytest.raises(IGSError, match="checkpoint.pt"):
        train_3dgs(box_ws.root, _config(8), resume=True)
    assert not marker.exists()
    # a raw pickle (not a torch zip) is refused too, and runs nothing
    (ckpt_dir / "checkpoint.pt").write_bytes(pickle.dumps(_RunsCode(marker)))
    with warnings.catch_warnings(record=True) as caught, pytest.raises(IGSError, match="checkpoint.pt"):
        warnings.simplefilter("always")
        load_checkpoint(ckpt_dir)
    assert not marker.exists()
    assert [str(w.message) for w in caught] == []  # the one error only, not torch's protocol warning too


def test_other_contents_are_refused_with_the_file_named(box_ws):
    ckpt_dir = box_ws.checkpoints / "train_3dgs"
    ckpt_dir.mkdir(parents=True, exist_ok=True)
    path = ckpt_dir / "checkpoint.pt"
    for content in ([1, 2], {"version": 1}, {"rng": np.zeros(3)}):
        torch.save(content, path)
        with pytest.raises(IGSError, match=f"{path}"):
            load_checkpoint(ckpt_dir)
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(IGSError, match="unreadable checkpoint"):
        load_checkpoint(ckpt_dir)


def test_written_checkpoints_load_with_weights_only_and_resume(box_ws):
    train_3dgs(box_ws.root, _config(8), resume=False, stop_after=4)
    path = box_ws.checkpoints / "train_3dgs" / "checkpoint.pt"
    state = torch.load(path, map_location="cpu", weights_only=True)  # raises on anything but plain data
    assert state["step"] == 4
    entry = train_3dgs(box_ws.root, _config(8), resume=True)
    assert entry["resumed_from"] == 4
    assert load_checkpoint(path.parent)["step"] == 8
