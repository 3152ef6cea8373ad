"""The preferences' Device and Check Backend, through the real operators in bpy: what reaches the setup
command and the one line the check reports.
"""

from __future__ import annotations

import json
import stat
import sys
from pathlib import Path

import pytest
from intrinsic_splats.igs_blender.env import backend_env

from tests.support.env_pins import FIX, wanted_reqs

ROOT = Path(__file__).resolve().parents[2]
PYTHON = sys.executable


# -- the preferences, through the real operators (bpy) ----------------------------------------------

RECORDER = r'''#!{python}
import json, os, sys
with open(os.environ["IGS_ARGV_FILE"], "a") as f:
    f.write(json.dumps(sys.argv[1:]) + "\n")
print(json.dumps({{"event": "output", "kind": "interpreter", "path": "/env/bin/python"}}), flush=True)
print(json.dumps({{"event": "done", "command": "setup-env", "seconds": 0.0}}), flush=True)
'''


@pytest.fixture(scope="module")
def prefs(tmp_path_factory):
    """The built extension installed and enabled in bpy (as tests/blender/test_blender_addon.py does)."""
    bpy = pytest.importorskip("bpy")
    import addon_utils

    from tests.support import blender as tba

    ext_zip = tba.build_zip(tmp_path_factory.mktemp("build"))
    bpy.ops.wm.read_homefile(use_empty=True)
    repo = bpy.context.preferences.extensions.repos.new(name="IGS Env Test", module=tba.REPO, source="USER",
                                                        custom_directory=str(tmp_path_factory.mktemp("repo")))
    bpy.ops.extensions.package_install_files(filepath=str(ext_zip), repo=tba.REPO, enable_on_install=True)
    yield bpy.context.preferences.addons[tba.MOD].preferences
    addon_utils.disable(tba.MOD, default_set=True)
    bpy.context.preferences.extensions.repos.remove(repo)
    bpy.ops.wm.read_homefile(use_empty=True)


def test_the_preferences_device_reaches_the_setup_command(prefs, tmp_path, monkeypatch):
    import bpy

    recorder = tmp_path / "python"
    recorder.write_text(RECORDER.format(python=PYTHON))
    recorder.chmod(recorder.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("IGS_ARGV_FILE", str(tmp_path / "argv.jsonl"))
    assert prefs.device == "CPU" and prefs.torch_index == backend_env.CPU_TORCH_INDEX
    prefs.base_python, prefs.env_dir = str(recorder), str(tmp_path / "env")
    prefs.check_report, prefs.check_ok = "stale", True
    for device, index in (("CPU", "https://example.org/cpu"), ("CUDA", "https://example.org/cpu"), ("CPU", "")):
        prefs.device, prefs.torch_index = device, index
        assert bpy.ops.igs.create_backend_env() == {"FINISHED"}
    assert prefs.backend_python == "/env/bin/python" and prefs.check_report == "" and not prefs.check_ok
    runs = [json.loads(line) for line in (tmp_path / "argv.jsonl").read_text().splitlines()]
    flags = [(a[a.index("--device") + 1], a[a.index("--torch-index") + 1] if "--torch-index" in a else None)
             for a in runs]
    assert flags == [("cpu", "https://example.org/cpu"), ("cuda", None), ("cpu", None)]
    assert all(a[a.index("--venv") + 1] == str(tmp_path / "env") for a in runs)

    prefs.base_python = str(tmp_path / "missing")
    with pytest.raises(RuntimeError, match="Base Python .*missing: not found"):
        bpy.ops.igs.create_backend_env()
    prefs.base_python = prefs.env_dir = ""


def test_check_backend_reports_the_one_line_and_keeps_the_details(prefs, tmp_path, bare_venv, capfd):
    import bpy

    prefs.device, prefs.backend_python = "CPU", str(bare_venv)
    capfd.readouterr()
    assert bpy.ops.igs.check_backend() == {"FINISHED"}  # the check ran; what it found is its report
    lines = prefs.check_report.splitlines()
    assert not prefs.check_ok and lines[0] == f"numpy, bpy and {len(wanted_reqs('3.11')) - 2} more missing: {FIX}"
    assert capfd.readouterr().out.splitlines() == [f"Warning: {lines[0]}"]  # a failed check warns; background Blender prints reports
    assert lines[1].startswith("Python 3.11") and any(line.startswith("Missing: ") for line in lines)
    prefs.backend_python = PYTHON
    assert bpy.ops.igs.check_backend() == {"FINISHED"}
    assert prefs.check_ok and prefs.check_report.splitlines()[0].startswith("Python {}.{}".format(*sys.version_info[:2]))
