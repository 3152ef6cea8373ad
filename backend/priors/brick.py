"""The brick-window schedule for running a video albedo model over a long video (paper 3.2.1).

DiffusionRenderer works on 8 latents of the Cosmos video tokenizer: the first ("start") latent
decodes to 1 frame, each following ("regular") latent to 8 frames, 1 + 7 * 8 = 57 frames. For Brick
Diffusion the window must move by a whole number of latents *and* of frames at once, so frames are
grouped on one global grid: frame 0 alone, then groups of 8 (group g = frames 1 + 8g .. 8 + 8g).
A window starts on a frame s that is a multiple of 32 and holds a start latent for frame s plus the
7 regular latents of the groups that follow (frames s .. s + 56). Consecutive windows are 4 latents
= 32 frames apart: the video is tiled in 64-frame chunks (one start latent + 8 regular latents) and
each denoising step works on 57 of the 64 frames of every chunk; the next step works on the tiling
shifted by 32 frames (windows alternate between the two "walls" of bricks), so every boundary of one
step lies inside a window of the next and no seam survives. In each step one regular latent per chunk
lies outside that step's windows (:meth:`BrickSchedule.idle_groups`): it keeps its value for that
step and is denoised by the other wall's windows. After denoising, every start and
regular latent is decoded and each latent's frames are kept from exactly one window: the one in
which that latent lies farthest from a seam, i.e. an end of the window that is not an end of the
video (ties go to the earlier window); the other copies are redundant and discarded. Windows that run past the end of the video are padded by repeating the last frame.

This module is pure: it computes indices, it runs no model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.errors import IGSError


@dataclass(frozen=True)
class BrickConfig:
    """Latent layout of the video model and the window advance."""

    latents: int = 8
    """Latents per window: one start latent + (latents - 1) regular latents."""
    frames_per_latent: int = 8
    """Frames decoded from one regular latent (the start latent decodes to one frame)."""
    advance_latents: int = 4
    """Regular latents the window moves by between consecutive windows (4 -> 32 frames)."""

    @property
    def window_frames(self) -> int:
        """Frames in a window: 1 + (latents - 1) * frames_per_latent (57)."""
        return 1 + (self.latents - 1) * self.frames_per_latent

    @property
    def advance_frames(self) -> int:
        """Frames between the starts of consecutive windows (32)."""
        return self.advance_latents * self.frames_per_latent

    @property
    def chunk_frames(self) -> int:
        """Frames of a chunk, the period of one wall of bricks: 2 * advance (64)."""
        return 2 * self.advance_frames


@dataclass(frozen=True)
class BrickWindow:
    """One model call's worth of frames."""

    index: int
    start: int
    """First frame (decoded from the start latent); windows cover frames start .. start + window_frames - 1."""
    groups: tuple[int, ...]
    """Global indices of its regular latents (group g = frames 1 + 8g .. 8 + 8g)."""
    source_frames: tuple[int, ...]
    """The video frame to feed at each of the window's positions (the last frame repeats past the end)."""
    wall: int
    """0 or 1: the denoising steps of this parity process this window."""

    def frame_at(self, position: int) -> int:
        """Global frame index of a position in the window (may be >= the video length for padding)."""
        return self.start + position


@dataclass(frozen=True)
class BrickSchedule:
    """All windows, which of them each denoising step runs, and where each output frame comes from."""

    num_frames: int
    config: BrickConfig
    windows: tuple[BrickWindow, ...]
    assignment: np.ndarray
    """(num_frames, 2) int: for each frame, (window index, position in that window) to keep."""

    def windows_for_step(self, step: int) -> list[BrickWindow]:
        """Windows denoised at denoising step ``step``: one wall of non-overlapping bricks, alternating."""
        walls = {w.wall for w in self.windows}
        wall = step % 2 if len(walls) == 2 else next(iter(walls))
        return [w for w in self.windows if w.wall == wall]

    def idle_groups(self, step: int) -> list[int]:
        """Regular latents (global group indices) that no window of ``step`` covers."""
        n_groups = -(-(self.num_frames - 1) // self.config.frames_per_latent)
        covered = {g for w in self.windows_for_step(step) for g in w.groups}
        return [g for g in range(n_groups) if g not in covered]

    def kept_positions(self, window: int) -> list[int]:
        """Positions of a window whose decoded frames are kept (in order)."""
        return [int(p) for w, p in self.assignment if w == window]


def brick_schedule(num_frames: int, config: BrickConfig = BrickConfig()) -> BrickSchedule:
    """The windows and the frame assignment for a video of ``num_frames`` frames."""
    if num_frames < 1:
        raise IGSError(f"brick schedule: a video needs at least one frame (got {num_frames})")
    if config.latents < 2 or config.frames_per_latent < 1 or not 1 <= config.advance_latents < config.latents:
        raise IGSError(f"brick schedule: invalid layout {config}")
    n_reg = config.latents - 1
    fpl = config.frames_per_latent
    adv = config.advance_latents
    wf = config.window_frames

    # Groups needed to cover frames 1 .. num_frames - 1; window k covers groups adv*k .. adv*k + n_reg - 1.
    n_groups = -(-(num_frames - 1) // fpl)
    n_windows = 1 if n_groups <= n_reg else 1 + -(-(n_groups - n_reg) // adv)
    windows = []
    for k in range(n_windows):
        start = k * config.advance_frames
        src = tuple(min(start + p, num_frames - 1) for p in range(wf))
        windows.append(BrickWindow(k, start, tuple(range(adv * k, adv * k + n_reg)), src, k % 2))

    # Keep each regular latent's frames from the window where that latent sits farthest from a seam
    # (an end of the window that is not an end of the video); frame 0 comes from window 0's start latent.
    # The start frames of later windows are also the last frame of a group kept elsewhere: redundant.
    owner = np.zeros(n_groups, dtype=np.int64)
    for g in range(n_groups):
        best = None
        for w in windows:
            j = g - adv * w.index  # position among the window's regular latents
            if not 0 <= j < n_reg:
                continue
            margin = min(j + 1 if w.index > 0 else n_reg + 1, n_reg - j if w.index < n_windows - 1 else n_reg + 1)
            if best is None or margin > best[0]:
                best = (margin, w.index)
        owner[g] = best[1]
    assignment = np.zeros((num_frames, 2), dtype=np.int64)
    for f in range(1, num_frames):
        k = int(owner[(f - 1) // fpl])
        assignment[f] = k, f - windows[k].start
    return BrickSchedule(num_frames, config, tuple(windows), assignment)
