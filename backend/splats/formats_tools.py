"""The PlayCanvas ``splat-transform`` command line (npm), when it is installed, run as a subprocess.

It is looked up as ``$IGS_SPLAT_TRANSFORM``, then ``<venv>/npm-tools/node_modules/.bin/splat-transform``
(where ``./dev.sh test`` installs the pinned version when npm exists), then on ``PATH``. The backend
uses it only to read ``.sog`` files when gsply's own SOG reader lacks imagecodecs; the interop tests
use it to check that our exports load in it.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from backend.core.errors import IGSError

SPLAT_TRANSFORM_VERSION = "3.7.0"
"""The version ``./dev.sh test`` installs (pinned; the tests record the version they ran)."""
NPM_TOOLS = "npm-tools"
"""Folder inside the venv where ``./dev.sh test`` installs npm tools."""


@dataclass(frozen=True)
class SplatTransform:
    """A runnable ``splat-transform``."""

    command: tuple[str, ...]

    def run(self, args: list[str], what: str, timeout_s: float = 600) -> str:
        """Run it with ``args`` (overwriting outputs); its stdout. A failure is one IGSError naming ``what``."""
        try:
            done = subprocess.run([*self.command, "-w", *args], capture_output=True, text=True, timeout=timeout_s)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise IGSError(f"{what}: splat-transform did not run ({e})") from None
        if done.returncode != 0:
            tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no message"]
            raise IGSError(f"{what}: splat-transform failed (exit {done.returncode}: {tail[0]})")
        return done.stdout

    def version(self) -> str:
        out = subprocess.run([*self.command, "--version"], capture_output=True, text=True, timeout=60)
        words = (out.stdout or out.stderr).split() if out.returncode == 0 else []
        return next((w.lstrip("v") for w in words if w[:1] == "v" and w[1:2].isdigit()), "?")


def splat_transform() -> SplatTransform | None:
    """The installed ``splat-transform``, or None."""
    env = os.environ.get("IGS_SPLAT_TRANSFORM")
    candidates = [env] if env else []
    candidates.append(str(Path(sys.prefix) / NPM_TOOLS / "node_modules" / ".bin" / "splat-transform"))
    found = shutil.which("splat-transform")
    if found:
        candidates.append(found)
    for c in candidates:
        if c and Path(c).is_file() and os.access(c, os.X_OK):
            return SplatTransform((c,))
    return None
