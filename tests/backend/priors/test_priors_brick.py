import numpy as np
import pytest

from backend.core.errors import IGSError
from backend.priors.brick import BrickConfig, brick_schedule

LENGTHS = [1, 2, 8, 9, 56, 57, 58, 64, 65, 89, 90, 96, 97, 100, 128, 200, 300, 1000]


def test_paper_layout_57_frame_windows_advancing_32_frames_in_64_frame_chunks():
    c = BrickConfig()
    assert (c.window_frames, c.advance_frames, c.chunk_frames) == (57, 32, 64)
    s = brick_schedule(300)
    for w in s.windows:
        assert w.start == 32 * w.index
        assert len(w.source_frames) == 57
        assert len(w.groups) == 7  # one start latent + 7 regular latents = 8 latents per step
        assert w.groups == tuple(range(4 * w.index, 4 * w.index + 7))  # advance = 4 latents
        # Each regular latent decodes to 8 frames on the global grid: group g = frames 1+8g .. 8+8g.
        assert w.start + 1 == 1 + 8 * w.groups[0]


@pytest.mark.parametrize("n", LENGTHS)
def test_every_frame_is_kept_exactly_once_from_a_window_that_contains_it(n):
    s = brick_schedule(n)
    assert s.assignment.shape == (n, 2)
    for f, (k, p) in enumerate(s.assignment):
        w = s.windows[k]
        assert 0 <= p < 57
        assert w.frame_at(p) == f
        assert w.source_frames[p] == f  # a kept frame is never padding
    # Kept positions per window, concatenated in window order, are the video in order.
    order = [s.windows[k].frame_at(p) for k in range(len(s.windows)) for p in s.kept_positions(k)]
    assert order == list(range(n))


@pytest.mark.parametrize("n", LENGTHS)
def test_windows_cover_the_video_and_overlap_for_continuity(n):
    s = brick_schedule(n)
    covered = set()
    for w in s.windows:
        covered.update(f for f in range(w.start, w.start + 57) if f < n)
    assert covered == set(range(n))
    for a, b in zip(s.windows, s.windows[1:]):
        overlap = a.start + 57 - b.start
        assert overlap == 25  # 3 regular latents + the next window's start frame
        # The seam of one window (its last frame) lies strictly inside the next one, and vice versa.
        assert b.start < a.start + 56 < b.start + 56
    # Only as many windows as needed: the last one is needed for some kept frame.
    assert s.kept_positions(len(s.windows) - 1)


@pytest.mark.parametrize("n", LENGTHS)
def test_steps_alternate_between_two_walls_of_disjoint_bricks(n):
    s = brick_schedule(n)
    seen = set()
    for step in range(4):
        wall = s.windows_for_step(step)
        spans = sorted((w.start, w.start + 57) for w in wall)
        assert all(e0 <= s1 for (_, e0), (s1, _) in zip(spans, spans[1:]))  # no overlap within a step
        seen.update(w.index for w in wall)
        if len(s.windows) > 1:
            other = {w.index for w in s.windows_for_step(step + 1)}
            assert other.isdisjoint(w.index for w in wall)  # the next step uses the shifted tiling
    assert seen == set(range(len(s.windows)))
    # A latent left idle by one wall is denoised by the other: none is idle in two consecutive steps.
    assert not set(s.idle_groups(0)) & set(s.idle_groups(1))
    if n >= 300:
        assert len(s.idle_groups(0)) >= 4  # one regular latent per 64-frame chunk


def test_kept_frames_are_whole_latents_away_from_seams():
    s = brick_schedule(300)
    for k in range(1, len(s.windows) - 1):
        kept = s.kept_positions(k)
        # Middle windows keep their middle 4 regular latents = 32 frames, never a seam frame.
        assert kept == list(range(17, 49))
    assert s.kept_positions(0)[0] == 0  # frame 0 from the first start latent


def test_short_videos_are_padded_by_repeating_the_last_frame():
    s = brick_schedule(10)
    assert len(s.windows) == 1
    src = s.windows[0].source_frames
    assert src[:10] == tuple(range(10)) and set(src[10:]) == {9}
    s1 = brick_schedule(1)
    assert s1.assignment.tolist() == [[0, 0]]
    assert set(s1.windows[0].source_frames) == {0}


def test_length_not_multiple_of_32_pads_the_last_window_only():
    s = brick_schedule(100)
    last = s.windows[-1]
    assert last.start == 64 and last.source_frames[35] == 99 and last.source_frames[36:] == (99,) * 21
    assert all(max(w.source_frames) < 100 for w in s.windows)
    assert np.all(s.assignment[:, 0] < len(s.windows))


def test_invalid_lengths_and_layouts_are_errors():
    with pytest.raises(IGSError):
        brick_schedule(0)
    with pytest.raises(IGSError):
        brick_schedule(10, BrickConfig(latents=8, advance_latents=8))
