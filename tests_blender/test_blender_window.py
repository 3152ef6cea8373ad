"""The add-on in a real Blender window: Debian's Blender 5.2 LTS under Xvfb, driven like a user.

``./dev.sh test-blender`` runs this file. It builds (once, cached outside the repository) a Debian
sid root holding Blender 5.2 and Xvfb (``scripts/blender_root.sh``), builds the extension zip with
that Blender's own ``extension build``, and starts one GUI session with ``driver.py``. The driver
installs the zip through the Extensions API and walks the whole flow: the backend environment
created by the add-on from Blender's own Python (cached in the root between runs), a synthetic
capture, a tiny decomposition, the layers, a plane fitted on a real Ctrl+B rectangle, a colour
bake and a turntable. Each test below checks one step's outcome; screenshots of every panel state
land in ``artifacts/blender-window/``.

Needs root (debootstrap and chroot); without it every test skips with one line saying why.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from blender_session import DISPLAY, REPO, ROOT_SCRIPT, Mounts, copy_driver, copy_sources, in_root, why_not

ARTIFACTS = REPO / "artifacts" / "blender-window"
RUN = "/root/igs-run"  # inside the root; wiped at every session
ENV_DIR = "/opt/igs-backend-venv"  # inside the root; kept between sessions (the CUDA torch is ~3 GB)
SESSION_TIMEOUT_S = int(os.environ.get("IGS_GUI_TIMEOUT", "3000"))

STEPS = ["splash", "install", "preferences", "create_backend_env", "check_backend", "close_preferences",
         "capture_model_priors", "capture_procedural_scene", "import_synthetic", "decompose", "load_layers", "splat_view", "splat_agreement",
         "look_through", "ctrl_b_rectangle", "fit_plane", "edit_preview", "colour_and_bake", "render_turntable", "lights_render_view",
         "lights_live_view"]


@pytest.fixture(scope="module")
def root() -> Path:
    why = why_not()
    if why:
        pytest.skip(why)
    res = subprocess.run([str(ROOT_SCRIPT)], capture_output=True, text=True, timeout=1800)
    assert res.returncode == 0, f"building the Blender root failed:\n{res.stderr[-3000:]}"
    return Path(res.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def session(root: Path) -> dict:
    """One GUI session through the whole flow; returns the driver's results and Blender's console log."""
    run = root / RUN.lstrip("/")
    shutil.rmtree(run, ignore_errors=True)
    (run / "out").mkdir(parents=True)
    (run / "dist").mkdir()
    copy_sources(run / "src")
    copy_driver("driver.py", run)
    with Mounts(root):
        build = in_root(root, f"cd {RUN}/src && blender --command extension validate . && "
                              f"blender --command extension build --source-dir . --output-dir {RUN}/dist", 600)
        assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
        zips = sorted((run / "dist").glob("*.zip"))
        assert len(zips) == 1, zips
        config = {
            "out": f"{RUN}/out", "zip": f"{RUN}/dist/{zips[0].name}", "env_dir": ENV_DIR,
            "workspace": f"{RUN}/ws", "iterations": 100, "bake_iterations": 100, "edit": "wall_decal",
            "turntable_frames": 8, "env_timeout_s": 2400, "step_timeout_s": 900,
            # Continue on the first-run splash, in a 1600x1000 screen
            "splash_continue": [798, 706],
            # CPU device, torch from PyPI: this machine reaches no other package index
            "prefs": json.loads(os.environ.get("IGS_GUI_PREFS", "{\"torch_index\": \"\"}")),
        }
        (run / "config.json").write_text(json.dumps(config, indent=1))
        script = (f"Xvfb {DISPLAY} -screen 0 1600x1000x24 -nolisten tcp >{RUN}/xvfb.log 2>&1 & XP=$!; "
                  f"for i in $(seq 50); do [ -e /tmp/.X11-unix/X{DISPLAY[1:]} ] && break; sleep 0.2; done; "
                  f"DISPLAY={DISPLAY} timeout {SESSION_TIMEOUT_S} blender --python {RUN}/driver.py "
                  f">{RUN}/blender.log 2>&1; rc=$?; kill $XP; exit $rc")
        env = {"IGS_DRIVER_CONFIG": f"{RUN}/config.json", "BLENDER_USER_RESOURCES": f"{RUN}/user",
               "TMPDIR": f"{RUN}/tmp"}
        (run / "tmp").mkdir()
        res = in_root(root, script, SESSION_TIMEOUT_S + 120, env)
    shutil.rmtree(ARTIFACTS, ignore_errors=True)
    ARTIFACTS.mkdir(parents=True)
    for f in (run / "out").iterdir():
        shutil.copy2(f, ARTIFACTS / f.name)
    log = (run / "blender.log").read_text(errors="replace") if (run / "blender.log").exists() else ""
    (ARTIFACTS / "blender.log").write_text(log)
    for f in (run / "tmp" / "intrinsic_splats_logs").glob("*.log"):
        shutil.copy2(f, ARTIFACTS / f"backend-{f.name}")
    results_path = run / "out" / "results.json"
    results = json.loads(results_path.read_text()) if results_path.exists() else {"steps": []}
    return {"rc": res.returncode, "results": results, "log": log,
            "steps": {s["name"]: s for s in results.get("steps", [])}}


@pytest.mark.parametrize("name", STEPS)
def test_step(session, name):
    step = session["steps"].get(name)
    if step is None:
        pytest.fail(f"step '{name}' never ran; session exit {session['rc']}; "
                    f"fatal: {session['results'].get('fatal', '')[-1500:]}; log tail:\n{session['log'][-1500:]}")
    assert step["ok"], f"{name} failed: {step.get('error', '')}\nreport: {step.get('report', '')}"


def test_session_ran_to_the_end_on_blender_5_2_or_later(session):
    res = session["results"]
    assert res.get("done"), res.get("fatal", "")
    # Debian sid's Blender: 5.2.2 LTS when this was written; a root rebuilt later may hold a newer one.
    major, minor = (int(x) for x in res["blender"].split()[0].split(".")[:2])
    assert (major, minor) >= (5, 2), res["blender"]
    assert session["rc"] == 0, session["log"][-2000:]


def test_no_python_error_in_blenders_console(session):
    lines = session["log"].splitlines()
    bad = [i for i, ln in enumerate(lines) if ln.startswith("Traceback") or "Error:" in ln and "Python" in ln]
    assert not bad, "\n".join("\n".join(lines[i:i + 12]) for i in bad[:3])


def test_backend_created_from_blenders_own_python(session):
    step = session["steps"]["create_backend_env"]
    assert step["backend_python"].startswith(ENV_DIR), step["backend_python"]
    check = session["steps"]["check_backend"]
    assert check["check_ok"], check["check_report"]
    assert session["results"]["python"] in check["check_report"], check["check_report"]


def test_edit_rectangle_and_results(session):
    s = session["steps"]
    rect = s["ctrl_b_rectangle"]
    assert rect["border"][0], "no border drawn"
    assert not s["fit_plane"]["border_after"], "the render border stays on after the fit"
    assert s["colour_and_bake"]["baked"]
    assert any(m.endswith(".mp4") for m in s["render_turntable"]["mp4s"])


def test_viewport_splats_agree_with_the_backend_render(session):
    """The engine's picture of a capture camera, read back, against `igs render` of the same camera."""
    step = session["steps"]["splat_agreement"]
    assert set(step["psnr"]) == {"A", "S", "R", "full"}, step
    assert min(step["psnr"].values()) >= 30.0, step["psnr"]


def test_edit_preview_shows_the_proxy_before_the_bake(session):
    step = session["steps"]["edit_preview"]
    assert step["proxy"].startswith("IGS proxy"), step
    assert step["proxy_pixels"] > 100, step


def test_screenshots_show_the_window(session):
    """Every screenshot is a real frame: full-size and not blank (Blender's own screenshot is black here)."""
    import cv2

    shots = sorted(ARTIFACTS.glob("*.png"))
    assert len(shots) >= 10, [p.name for p in shots]
    for p in shots:
        img = cv2.imread(str(p))
        assert img is not None and img.shape[:2] == (1000, 1600), p.name
        assert float(img.std()) > 10.0 and float(np.mean(img)) > 15.0, f"{p.name} looks blank"
