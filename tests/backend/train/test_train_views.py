"""load_views: the views come back in the frames' order, decoded on several threads, and a bad image
is one error naming the first bad view in that order."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from backend.capture.load import load_capture
from backend.core.errors import IGSError
from backend.core.imageio import read_image
from backend.train.views import load_views
from tests.support.train_scene import make_workspace


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("views") / "box"
    make_workspace(root, n_views=12, width=32, height=24)
    return load_capture(root)


def test_views_keep_the_frames_order(capture):
    frames = capture.frames
    indices = list(range(100, 100 + len(frames)))
    views = load_views(frames, indices)
    assert [v.index for v in views] == indices
    for view, frame in zip(views, frames):
        assert view.camera.name == frame.name
        np.testing.assert_array_equal(view.image.numpy(), read_image(frame.image))


def test_the_first_bad_view_in_order_is_the_error(capture, tmp_path):
    frames = capture.frames
    saved = {i: frames[i].image.read_bytes() for i in (3, 7)}
    try:
        for i in saved:
            frames[i].image.write_bytes(b"not a png")
        with pytest.raises(IGSError, match=frames[3].image.name):
            load_views(frames, range(len(frames)))
    finally:
        for i, data in saved.items():
            frames[i].image.write_bytes(data)


def test_loading_shows_progress_as_events(capture, capsys):
    from backend.core import events

    events.enable_json(True)
    try:
        load_views(capture.frames, range(len(capture.frames)))
    finally:
        events.enable_json(False)
    lines = [json.loads(ln) for ln in capsys.readouterr().out.splitlines() if ln.startswith("{")]
    stages = [e for e in lines if e["event"] == "stage"]
    assert stages == [{"event": "stage", "stage": "load views", "total": 12, "unit": "view"}]
    last = [e for e in lines if e["event"] == "progress"][-1]
    assert (last["stage"], last["step"], last["total"]) == ("load views", 12, 12)


def test_a_cancel_stops_loading(capture, monkeypatch):
    """The bar raises Cancelled at the first view; the views not yet started are dropped, not decoded.
    (One loading thread, and every view after the first takes 50 ms, so that the cancel comes while
    the second decodes.)"""
    from backend.core import events
    from backend.core.errors import Cancelled
    from backend.train import views as views_module

    decoded = []
    real = views_module.read_image_codes

    def slow(path):
        if decoded:
            time.sleep(0.05)
        decoded.append(path)
        return real(path)

    monkeypatch.setattr(views_module, "read_image_codes", slow)
    monkeypatch.setattr(views_module, "get_threads", lambda: 1)
    events.request_cancel()
    try:
        with pytest.raises(Cancelled):
            load_views(capture.frames, range(len(capture.frames)))
    finally:
        events._cancel.clear()
    assert len(decoded) <= 3 < len(capture.frames)
