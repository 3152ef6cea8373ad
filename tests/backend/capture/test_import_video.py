import json

import cv2
import numpy as np
import pytest

from backend.capture.importer import ImportConfig, detect_kind, import_capture
from backend.capture.video import FrameSelection, extract_frames, sharpness
from backend.core.errors import IGSError


def textured(seed: int, size=(96, 128)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = (rng.random((size[0] // 8, size[1] // 8, 3)) * 255).astype(np.uint8)
    return cv2.resize(small, (size[1], size[0]), interpolation=cv2.INTER_NEAREST)


def write_video(path, frames, fps=24):
    h, w = frames[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert vw.isOpened()
    for f in frames:
        vw.write(f)
    vw.release()


@pytest.fixture
def blurry_video(tmp_path):
    """12 frames; in each window of 3, only the middle frame is sharp."""
    frames = []
    for i in range(12):
        img = textured(i // 3)
        frames.append(img if i % 3 == 1 else cv2.GaussianBlur(img, (0, 0), 2.5))
    path = tmp_path / "clip.mp4"
    write_video(path, frames)
    return path


def test_sharpness_prefers_the_sharp_frame():
    img = textured(0)
    assert sharpness(img) > 3 * sharpness(cv2.GaussianBlur(img, (0, 0), 2.0))


def test_sharpest_frame_of_each_window_is_kept(tmp_path, blurry_video):
    out = extract_frames(blurry_video, tmp_path / "frames", FrameSelection(every=3))
    assert [f.video_index for f in out] == [1, 4, 7, 10]
    assert [f.path.name for f in out] == [f"frame_{i:04d}.png" for i in range(4)]
    first = extract_frames(blurry_video, tmp_path / "first", FrameSelection(every=3, sharpest=False))
    assert [f.video_index for f in first] == [0, 3, 6, 9]


def test_max_frames_and_max_side(tmp_path, blurry_video):
    out = extract_frames(blurry_video, tmp_path / "frames", FrameSelection(every=1, max_frames=5, max_side=64))
    assert len(out) == 5 and out[0].video_index == 0 and out[-1].video_index == 11
    img = cv2.imread(str(out[0].path))
    assert max(img.shape[:2]) == 64 and img.shape[:2] == (48, 64)


def test_extraction_is_reused_when_settings_match(tmp_path, blurry_video):
    sel = FrameSelection(every=3)
    a = extract_frames(blurry_video, tmp_path / "frames", sel)
    mtimes = [f.path.stat().st_mtime_ns for f in a]
    b = extract_frames(blurry_video, tmp_path / "frames", sel)
    assert [f.path.stat().st_mtime_ns for f in b] == mtimes
    c = extract_frames(blurry_video, tmp_path / "frames", FrameSelection(every=4))
    assert len(c) == 3 and not (tmp_path / "frames" / "frame_0003.png").exists()
    assert json.loads((tmp_path / "frames" / "frames.json").read_text())["stamp"]["selection"]["every"] == 4


def test_unreadable_video_is_one_clear_error(tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"this is not a video" * 100)
    with pytest.raises(IGSError, match="broken.mp4"):
        extract_frames(bad, tmp_path / "frames")
    with pytest.raises(IGSError, match="broken.mp4"):
        import_capture(bad, tmp_path / "ws")


def test_too_few_frames_is_one_clear_error(tmp_path):
    path = tmp_path / "short.mp4"
    write_video(path, [textured(i) for i in range(4)])
    with pytest.raises(IGSError, match="only 1 frame"):
        import_capture(path, tmp_path / "ws", ImportConfig(selection=FrameSelection(every=5)))


def test_source_kinds_are_detected(tmp_path, blurry_video):
    assert detect_kind(blurry_video) == "video"
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "a.jpg"), textured(0))
    assert detect_kind(photos) == "photos"
    (photos / "transforms.json").write_text("{}")
    assert detect_kind(photos) == "transforms"
    with pytest.raises(IGSError, match="not found"):
        detect_kind(tmp_path / "nothing")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(IGSError, match="no video, images"):
        detect_kind(empty)
