"""What the drivers that run inside a real Blender window share (``driver.py``, ``viewport_bench_driver.py``).

Each is started as ``blender --python driver.py`` with this module copied beside it
(:func:`blender_session.copy_driver`). A driver is a flow: a generator that yields the seconds to
wait before its next part. :meth:`Session.run` steps it from a ``bpy.app.timers`` callback, so
Blender's event loop, its modal operators and their timers run between the parts as they do for a
user; when the flow ends or raises (the traceback goes to the results as ``fatal``), Blender quits.
The results are a JSON file in the output folder, rewritten whole after each change, so a crash
still leaves what happened before it. Screenshots are of the whole X screen, with ImageMagick's
``import -window root`` (Blender's own screenshot operator gives a black image under Xvfb).
Standard library and bpy only (this is Blender's Python).
"""

from __future__ import annotations

import json
import os
import subprocess
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
