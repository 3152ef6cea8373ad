"""A stand-in Blender binary that runs the synthetic capture's worker in this Python, for the tests of the Blender-binary path."""

from __future__ import annotations

import sys
from pathlib import Path


def fake_blender(folder: Path, prelude: str = "") -> Path:
    path = folder / "blender"
    path.write_text(FAKE_BLENDER.format(python=sys.executable, prelude=prelude))
    path.chmod(0o755)
    return path


# Blender's command line: blender --background --factory-startup --python-exit-code 1 --python FILE -- ARGS.
# Blender runs FILE with sys.argv = [blender, all its arguments, "--", ARGS]; so does this stand-in.
# PRELUDE (Python source) runs first, inside the stand-in, to simulate failures.
FAKE_BLENDER = '''#!{python}
import os, runpy, sys
args = sys.argv[1:]
assert args[:4] == ["--background", "--factory-startup", "--python-exit-code", "1"], args
assert args[4] == "--python" and args[6] == "--", args
sys.argv = [sys.argv[0], *args]
print("fake blender: starting", os.getpid(), flush=True)
{prelude}
try:
    runpy.run_path(args[5], run_name="__main__")
except BaseException:
    import traceback
    traceback.print_exc()
    sys.exit(1)
'''
