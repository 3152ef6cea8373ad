"""Where the backend is and how to run it: interpreter, shipped sources, pinned requirements (no bpy).

The extension ships the backend sources (``backend/`` and the ``igs_contract/`` it shares with the
add-on) and ``pyproject.toml`` beside the add-on; jobs run the configured interpreter with that
folder first on PYTHONPATH, so Blender never imports the backend. The
pins carry PEP 508 ``python_version`` markers (one set per Python); the scripts that create and
check an environment run in its interpreter and pick the set for it (check_env.py's evaluator).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

from ...igs_contract import events
from ..errors import UserError
from ..jobs.client import BackendJob, backend_command
from . import check_env, cuda_build

ADDON_ROOT = Path(__file__).resolve().parents[2]  # igs_blender/env/ -> the extension folder
SCRIPTS = Path(__file__).resolve().parent

# PyTorch's own index of CPU-only wheels (torch 2.13.0+cpu for cp311 is 192 MB where PyPI's Linux
# wheel is the CUDA build with 2.2 GB of NVIDIA libraries); its mirror of torch's deps comes with it.
CPU_TORCH_INDEX = "https://download.pytorch.org/whl/cpu"
DEVICES = check_env.DEVICES
FIX_ENV = "click Create Backend Environment"


def read_pyproject(root: Path = ADDON_ROOT) -> tuple[str, list[str]]:
    """(requires-python, ``[project] dependencies``) of the shipped pyproject.toml."""
    import tomllib

    path = root / "pyproject.toml"
    if not path.is_file():
        raise UserError(f"{path}: missing; this copy of the extension does not ship the backend's requirements")
    try:
        project = tomllib.loads(path.read_text(encoding="utf-8"))["project"]
        deps, requires = list(project["dependencies"]), str(project.get("requires-python", ""))
        for dep in deps:
            _, _, marker = check_env.split_requirement(dep)
            if marker:
                check_env.evaluate_marker(marker, "3.11")  # refuse markers the scripts cannot evaluate now
        check_env.version_matches("3.11", requires)
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as e:
        raise UserError(f"{path}: cannot read [project] dependencies and requires-python ({e})") from e
    return requires, deps


def pinned_requirements(root: Path = ADDON_ROOT, include_bpy: bool = True) -> list[str]:
    """The ``[project] dependencies`` of the shipped pyproject.toml (exact pins, markers kept)."""
    deps = read_pyproject(root)[1]
    if not include_bpy:
        deps = [d for d in deps if check_env.normal_name(check_env.split_requirement(d)[0]) != "bpy"]
    return deps


def backend_root(configured: str = "") -> Path:
    """The folder holding ``backend/`` and ``igs_contract/`` (the configured one, else the extension's own)."""
    root = Path(configured).expanduser() if configured else ADDON_ROOT
    for needed in ("backend/__main__.py", "igs_contract/__init__.py"):
        if not (root / needed).is_file():
            raise UserError(f"{root}: no backend sources here ({needed} is missing); "
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


def check_job(interpreter: str, root: str = "", include_bpy: bool = True, device: str = "cpu") -> BackendJob:
    """A job that reports what ``interpreter`` lacks for ``device`` (see check_env.py)."""
    requires, _ = read_pyproject(backend_root(root))
    reqs = pinned_requirements(backend_root(root), include_bpy)
    _, env = backend_command(interpreter, [], backend_root(root))
    argv = script_argv(interpreter, "check_env.py", ["--requirements-json", json.dumps(reqs),
                                                     "--requires-python", requires, "--device", _device(device)])
    return BackendJob(argv, "Check backend", env=env, cwd=str(Path.home()))


def setup_job(base_python: str, env_dir: Path, include_bpy: bool = True, root: str = "", device: str = "cpu",
              torch_index: str = CPU_TORCH_INDEX, cuda_archs: str = cuda_build.DEFAULT_ARCHS) -> BackendJob:
    """A job that creates/updates the backend venv from the pinned requirements (see setup_env.py).

    ``base_python`` ('' = the running Python, Blender's own) makes the venv; its version picks the
    pins. ``torch_index`` (CPU only; '' = PyPI) is where the CPU build of torch comes from.
    ``cuda_archs`` (CUDA only) are the GPU architectures gsplat's kernels are built for when the
    set-up sees no GPU.
    """
    device = _device(device)
    try:
        archs = cuda_build.parse_archs(cuda_archs) if device == "cuda" else []
    except ValueError as e:
        raise UserError(f"CUDA Architectures: {e}") from e
    if base_python and not (os.path.isfile(base_python) and os.access(base_python, os.X_OK)):
        raise UserError(f"Base Python {base_python}: not found or not executable; fix 'Base Python' under "
                        "Advanced in the preferences (empty: Blender's own Python)")
    requires, _ = read_pyproject(backend_root(root))
    reqs = pinned_requirements(backend_root(root), include_bpy)
    args = ["--venv", str(env_dir), "--requirements-json", json.dumps(reqs), "--requires-python", requires,
            "--device", device]
    if device == "cpu" and torch_index.strip():
        args += ["--torch-index", torch_index.strip()]
    if archs:
        args += ["--cuda-archs", ";".join(archs)]
    argv = script_argv(base_python or sys.executable, "setup_env.py", args)
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("PYTHONPATH", None)
    return BackendJob(argv, "Create backend environment", env=env, cwd=str(Path.home()),
                      expected_stages=2 if archs else 1, grace_s=10.0, log_path=log_path("setup-env"))


def _device(device: str) -> str:
    device = device.lower()
    if device not in DEVICES:
        raise UserError(f"unknown device '{device}' (expected one of {', '.join(DEVICES)})")
    return device


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _package_problem(missing: list[dict], wrong: list[dict]) -> str:
    """"torch missing and numpy 1.26.4 where 2.4.6 is wanted" ('' when nothing is)."""
    parts = []
    if missing:
        names = [p["name"] for p in missing]
        parts.append(_and(names if len(names) <= 3 else [*names[:2], f"{len(names) - 2} more"]) + " missing")
    parts += [f"{p['name']} {p['have']} where {p['want'].removeprefix('==')} is wanted" for p in wrong[:2]]
    if len(wrong) > 2:
        parts.append(f"{len(wrong) - 2} more at other versions")
    return " and ".join(parts)


def _kernels_report(env: dict, info: dict) -> tuple[str, list[str]]:
    """(what is wrong with gsplat's built kernels, which Create Backend Environment fixes; detail lines)."""
    lines = [f"CUDA compiler: {env['nvcc']}" if env.get("nvcc") else
             "CUDA compiler: none in the environment (Create Backend Environment installs NVIDIA's from PyPI)"]
    kernels = env.get("gsplat_kernels")
    if kernels is None:  # gsplat is not installed: the package list says so
        return "", lines
    if not kernels["module"]:
        lines.append(f"gsplat {kernels['version']}: its CUDA kernels are not built")
        return "gsplat's CUDA kernels are not built", lines
    built = check_env.arch_text(kernels["sm"], kernels["ptx"])
    if kernels["error"]:
        lines.append(f"gsplat built for {built}, but it does not load: {kernels['error']}")
        return f"gsplat's kernels do not load ({kernels['error']})", lines
    lines.append(f"gsplat built for {built}")
    capability = (info.get("cuda_capability") or 0) if info.get("cuda_available") else 0
    if capability and not check_env.runs_on(capability, kernels["sm"], kernels["ptx"]):
        return f"gsplat is built for {built}, not for this GPU (sm_{capability})", lines
    return "", lines


def _torch_report(env: dict) -> tuple[str, str, list[str]]:
    """(what is wrong with torch or gsplat's kernels for the device and needs Create Backend Environment,
    what else is wrong with a fix of its own, detail lines)."""
    info, device = env.get("torch"), env.get("device", "cpu")
    if not info:
        return "", "", []  # missing: the package list says so
    version = info["version"]
    if info.get("error"):
        return f"torch {version} does not import ({info['error']})", "", [f"torch {version} does not import: {info['error']}"]
    if info.get("cuda"):
        usable = (f"CUDA usable on {info['cuda_device']}" if info.get("cuda_available")
                  else f"CUDA not usable: {info.get('cuda_error') or 'no GPU'}")
        lines = [f"torch {version}: CUDA {info['cuda']} build, {usable}"]
    else:
        lines = [f"torch {version}: CPU-only build"]
    if device != "cuda":
        return "", "", lines
    if not info.get("cuda"):
        return f"torch {version} is a CPU-only build where the Device is NVIDIA CUDA", "", lines
    kernels_problem, kernel_lines = _kernels_report(env, info)
    lines += kernel_lines
    if kernels_problem:
        return kernels_problem, "", lines
    if not info.get("cuda_available"):
        return "", (f"CUDA is not usable ({info.get('cuda_error') or 'no GPU'}): install the NVIDIA driver, "
                    f"or choose CPU as Device and {FIX_ENV}"), lines
    return "", "", lines


def env_report_lines(job: BackendJob) -> tuple[bool, list[str]]:
    """(everything present, lines for the user) from a finished check job: the first line says what is
    wrong and how to fix it (or that the backend is ready), the others are the details."""
    env = next((e for e in job.state.other if e.get(events.EVENT) == events.ENV), None)
    if env is None:
        return False, [job.report()]
    minor = ".".join(env["python"].split(".")[:2])
    details = [f"Python {env['python']} at {env['executable']}"
               + (f" (requires-python {env['requires_python']})" if env.get("requires_python") else "")]
    missing = [p for p in env["packages"] if p["have"] is None]
    wrong = [p for p in env["packages"] if p["have"] is not None and not p["ok"]]
    if missing:
        details.append("Missing: " + ", ".join(f"{p['name']}{p['want']}" for p in missing))
    if wrong:
        details.append("Other versions: " + ", ".join(f"{p['name']} {p['have']} (wants {p['want']})" for p in wrong))
    if not missing and not wrong:
        details.append(f"All {len(env['packages'])} pinned packages present")
    if env.get("not_applicable"):
        details.append(f"Not for Python {minor}: " + ", ".join(env["not_applicable"]))
    torch_problem, cuda_problem, torch_lines = _torch_report(env)
    details += torch_lines
    if env.get("backend"):
        details.append("Backend commands: " + (", ".join(env["commands"]) or "none yet"))
    else:
        details.append(f"Backend does not import: {env.get('backend_error')}")

    if not env.get("python_ok", True):
        choices = check_env.choices_text(env.get("python_supported") or [])
        problem = f"Python {minor} is not supported: choose {choices} as Base Python and {FIX_ENV}"
    elif missing or wrong or torch_problem:
        problem = " and ".join(filter(None, (_package_problem(missing, wrong), torch_problem))) + f": {FIX_ENV}"
    elif cuda_problem:
        problem = cuda_problem
    elif not env.get("backend"):
        problem = f"backend does not import: {env.get('backend_error')}"
    else:
        info = env.get("torch") or {}
        where = f"CUDA on {info['cuda_device']}" if info.get("cuda_available") else "on the CPU"
        summary = f"Python {env['python']}: backend ready" + (f", torch {info['version']} {where}" if info else "")
        return True, [summary, *details]
    return False, [problem, *details]
