"""What the drivers that run inside a real Blender window share (``driver.py``, ``viewport_bench_driver.py``).

Each is started as ``blender --python driver.py`` with this module copied beside it
(:func:`blender_session.copy_driver`). A driver is a flow: a generator that yields the seconds to
wait before its next part; a part that waits for something waits for a condition (:func:`wait_until`,
:func:`drawn`), never for a fixed time, so a busy machine only makes the run slower. :meth:`Session.run` steps it from a ``bpy.app.timers`` callback, so
Blender's event loop, its modal operators and their timers run between the parts as they do for a
user; when the flow ends or raises (the traceback goes to the results as ``fatal``), Blender quits.
The results are a JSON file in the output folder, rewritten whole after each change, so a crash
still leaves what happened before it. Screenshots are of the whole X screen, with ImageMagick's
``import -window root`` (Blender's own screenshot operator gives a black image under Xvfb).
Standard library and bpy only (this is Blender's Python).
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import time
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path

import bpy


class Session:
    """The configuration (the JSON file ``$<config_env>`` names), the output folder and the results."""

    def __init__(self, config_env: str, results_name: str, results: dict):
        self.config: dict = json.loads(Path(os.environ[config_env]).read_text())
        self.out = Path(self.config["out"])
        self.out.mkdir(parents=True, exist_ok=True)
        self.results_path = self.out / results_name
        self.results = results

    def save(self) -> None:
        """Write the results (a temporary file renamed over the last one)."""
        tmp = self.results_path.with_name(self.results_path.name + ".tmp")
        tmp.write_text(json.dumps(self.results, indent=1, default=str))
        tmp.replace(self.results_path)

    def shot(self, name: str) -> str:
        """Screenshot of the whole X screen (every Blender window) as OUT/NAME.png; returns the file name."""
        path = self.out / f"{name}.png"
        subprocess.run(["import", "-window", "root", str(path)], check=False, timeout=60,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        return path.name

    def run(self, flow: Callable[[], Iterator[float]], first_interval: float,
            last: Callable[[], object] | None = None) -> None:
        """Step ``flow`` from a timer, ``first_interval`` seconds from now; when it is over, call ``last``
        (a final screenshot, say) and quit Blender."""
        steps: list[Iterator[float]] = []

        def tick() -> float | None:
            try:
                if not steps:
                    steps.append(flow())
                return next(steps[0])
            except StopIteration:
                pass
            except Exception:
                self.results["fatal"] = traceback.format_exc()[-4000:]
                self.save()
            try:
                if last is not None:
                    last()
            finally:
                bpy.ops.wm.quit_blender()
            return None

        bpy.app.timers.register(tick, first_interval=first_interval)


def main_window():
    """The main window: preferences and render windows have temporary screens, it does not."""
    return next(w for w in bpy.context.window_manager.windows if not w.screen.is_temporary)


def view3d(area_type: str = "VIEW_3D"):
    """(window, area, its main region) of the main window's first area of ``area_type``."""
    win = main_window()
    area = next(a for a in win.screen.areas if a.type == area_type)
    region = next(r for r in area.regions if r.type == "WINDOW")
    return win, area, region


POLL_S = 0.1
"""How often a condition is checked: each check runs in its own turn of Blender's event loop."""


def wait_until(condition: Callable[[], object], timeout_s: float, what: str) -> Iterator[float]:
    """Yield until ``condition()`` is true; TimeoutError naming ``what`` after ``timeout_s``. Returns
    the condition's value."""
    t0 = time.monotonic()
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"{what}: not after {timeout_s:.0f} s")
        yield POLL_S


class _Draws:
    """Counts the draws of the main window's editors (a POST_PIXEL handler on each kind of space)."""

    SPACES = ("SpaceView3D", "SpacePreferences", "SpaceImageEditor")

    def __init__(self):
        self.count = 0
        self.handles: list = []

    def install(self) -> None:
        if self.handles:
            return
        for name in self.SPACES:
            space = getattr(bpy.types, name)
            self.handles.append((space, space.draw_handler_add(self._tick, (), "WINDOW", "POST_PIXEL")))

    def _tick(self) -> None:
        self.count += 1


DRAWS = _Draws()


def tag_redraw() -> None:
    for win in bpy.context.window_manager.windows:
        for area in win.screen.areas:
            area.tag_redraw()


def drawn(times: int = 2, timeout_s: float = 120.0) -> Iterator[float]:
    """Yield until the windows have drawn ``times`` more times. Blender reads input at the start of an
    event-loop turn and draws at its end, so after two draws every X event sent before the call (a
    click, a key) has been handled, and whatever it changed is on the screen."""
    DRAWS.install()
    for _ in range(times):
        start = DRAWS.count
        tag_redraw()
        yield from wait_until(lambda start=start: DRAWS.count > start, timeout_s, "the window to draw")


def _screen_pixels():
    """The whole X screen as an (H, W, 3) uint8 array (ImageMagick's ``import``), or None."""
    import numpy as np

    win = main_window()
    raw = subprocess.run(["import", "-window", "root", "-depth", "8", "rgb:-"], check=False, timeout=60,
                         capture_output=True).stdout
    screen = bpy.context.window_manager.windows[0]
    for w, h in ((win.width, win.height), (screen.width, screen.height), (1600, 1000)):
        if w * h * 3 == len(raw):
            return np.frombuffer(raw, dtype=np.uint8).reshape(h, w, 3)
    return None


def compiling_text_shown(pixels) -> bool:
    """The 3D view's info text has a third line under the view's name and the collection: EEVEE's
    "Compiling shaders" (it runs in no job that ``bpy.app.is_job_running`` sees). Lines of text are runs
    of rows with bright pixels in the view's top-left corner; three at the info text's pitch (about 19 px
    at scale 1; the headers above are further apart) mean the third line is there."""
    if pixels is None:
        return False
    win, _, region = view3d()
    x0 = region.x + 10
    counts = (pixels[:, x0:x0 + 300].mean(axis=2) > 190).sum(axis=1)
    top = max(0, win.height - (region.y + region.height))
    runs: list[list[int]] = []  # [first row, last row, most bright pixels in a row]
    for row in range(top, min(top + 220, len(counts))):
        if counts[row] <= 5:
            continue
        if runs and row - runs[-1][1] <= 3:
            runs[-1][1], runs[-1][2] = row, max(runs[-1][2], int(counts[row]))
        else:
            runs.append([row, row, int(counts[row])])
    lines = [r[0] for r in runs if r[1] - r[0] >= 4 and r[2] >= 25]
    return any(15 <= b - a <= 23 and 15 <= c - b <= 23 for a, b, c in zip(lines, lines[1:], lines[2:]))


def screen_at_rest(timeout_s: float = 600.0) -> Iterator[float]:
    """Yield until the screen is the same after a draw as before it, and EEVEE shows no "Compiling
    shaders" line: it has compiled its shaders and finished its viewport samples. Only for a screen
    without a running job (a progress bar keeps moving)."""
    t0 = time.monotonic()
    last = None
    while True:
        yield from drawn(1, timeout_s)
        pixels = _screen_pixels()
        now = None if pixels is None else hashlib.sha1(pixels.tobytes()).digest()
        if now is not None and now == last and not compiling_text_shown(pixels):
            return
        last = now
        if time.monotonic() - t0 > timeout_s:
            raise TimeoutError(f"the screen still changes after {timeout_s:.0f} s (EEVEE compiling shaders?)")
