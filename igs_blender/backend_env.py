"""Where the backend is and how to run it: interpreter, shipped sources, pinned requirements (no bpy).

The extension ships the backend sources and ``pyproject.toml`` beside the add-on; jobs run the
configured interpreter with that folder first on PYTHONPATH, so Blender never imports them.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

from .client import BackendJob, backend_command
from .errors import UserError

ADDON_ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = Path(__file__).resolve().parent


def pinned_requirements(root: Path = ADDON_ROOT, include_bpy: bool = True) -> list[str]:
    """The ``[project] dependencies`` of the shipped pyproject.toml (exact pins)."""
    import tomllib

    path = root / "pyproject.toml"
    if not path.is_file():
        raise UserError(f"{path}: missing; this copy of the extension does not ship the backend's requirements")
    try:
        deps = tomllib.loads(path.read_text(encoding="utf-8"))["project"]["dependencies"]
    except (tomllib.TOMLDecodeError, KeyError) as e:
        raise UserError(f"{path}: cannot read [project] dependencies ({e})") from e
    if not include_bpy:
        deps = [d for d in deps if not d.lower().startswith("bpy")]
    return list(deps)


def backend_root(configured: str = "") -> Path:
    """The folder holding ``backend/`` (the configured one, else the extension's own)."""
    root = Path(configured).expanduser() if configured else ADDON_ROOT
    if not (root / "backend" / "__main__.py").is_file():
        raise UserError(f"{root}: no backend sources here (backend/__main__.py is missing); "
                        "reinstall the extension or fix 'Backend Sources' in the preferences")
    return root


def default_env_dir(user_dir: str) -> Path:
    return Path(user_dir) / "backend-venv"


def venv_python(env_dir: Path) -> Path:
    return env_dir / ("Scripts/python.exe" if sys.platform == "win32" else "bin/python")


def script_argv(python: str, script: str, args: list[str]) -> list[str]:
    """Run a stdlib-only helper script without putting its folder on sys.path (its module names
    such as ``client`` or ``errors`` must not shadow anything in the backend interpreter)."""
    code = "import runpy, sys; p = sys.argv[1]; sys.argv = sys.argv[1:]; runpy.run_path(p, run_name='__main__')"
    return [python, "-c", code, str(SCRIPTS / script), *args]


def log_path(command: str) -> Path:
    """Where a job's full output goes: a temp folder, never the workspace (commands own that)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    return Path(tempfile.gettempdir()) / "intrinsic_splats_logs" / f"{command}-{stamp}-{os.getpid()}.log"


def backend_job(interpreter: str, args: list, label: str, *, root: str = "", expected_stages: int = 0,
                ) -> BackendJob:
    """A (not yet started) ``python -m backend --events ARGS`` job."""
    argv, env = backend_command(interpreter, [str(a) for a in args], backend_root(root))
    name = "-".join(str(a) for a in args[:2]) if args[0] == "edit" else str(args[0])
    return BackendJob(argv, label, env=env, expected_stages=expected_stages, log_path=log_path(name))


def check_job(interpreter: str, root: str = "", include_bpy: bool = True) -> BackendJob:
    """A job that reports what ``interpreter`` lacks (see check_env.py)."""
    reqs = pinned_requirements(backend_root(root), include_bpy)
    _, env = backend_command(interpreter, [], backend_root(root))
    argv = script_argv(interpreter, "check_env.py", ["--requirements-json", json.dumps(reqs)])
    return BackendJob(argv, "Check backend", env=env, cwd=str(Path.home()))


def setup_job(base_python: str, env_dir: Path, include_bpy: bool = True, root: str = "") -> BackendJob:
    """A job that creates/updates the backend venv from the pinned requirements (see setup_env.py)."""
    reqs = pinned_requirements(backend_root(root), include_bpy)
    argv = script_argv(base_python or sys.executable, "setup_env.py",
                       ["--venv", str(env_dir), "--requirements-json", json.dumps(reqs)])
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("PYTHONPATH", None)
    return BackendJob(argv, "Create backend environment", env=env, cwd=str(Path.home()),
                      expected_stages=1, grace_s=10.0, log_path=log_path("setup-env"))


def env_report_lines(job: BackendJob) -> tuple[bool, list[str]]:
    """(everything present, lines for the user) from a finished check job."""
    env = next((e for e in job.state.other if e.get("event") == "env"), None)
    if env is None:
        return False, [job.report()]
    lines = [f"Python {env['python']} at {env['executable']}"]
    ok = bool(env.get("python_ok"))
    if not ok:
        lines.append(f"  needs Python {env.get('python_wanted')}.x (the pinned wheels, bpy 5.0.1 included, are built for it)")
    missing = [p for p in env["packages"] if p["have"] is None]
    wrong = [p for p in env["packages"] if p["have"] is not None and not p["ok"]]
    if missing:
        ok = False
        lines.append("Missing: " + ", ".join(f"{p['name']}{p['want']}" for p in missing))
    if wrong:
        ok = False
        lines.append("Other versions: " + ", ".join(f"{p['name']} {p['have']} (wants {p['want']})" for p in wrong))
    if not missing and not wrong:
        lines.append(f"All {len(env['packages'])} pinned packages present")
    if env.get("backend"):
        lines.append("Backend commands: " + (", ".join(env["commands"]) or "none yet"))
    else:
        ok = False
        lines.append(f"Backend does not import: {env.get('backend_error')}")
    return ok, lines
