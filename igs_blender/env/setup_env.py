"""Create the backend's Python environment: a venv with the project's pinned requirements.

Run by the add-on with the base Python (Blender's own by default), never imported by Blender::

    python setup_env.py --venv DIR --requirements-json '["numpy==1.26.4; python_version < \\'3.12\\'", ...]' \\
        [--requires-python '>=3.11,<3.15'] [--device cpu|cuda] [--cuda-archs "8.0;8.6;8.9;9.0+PTX"] \\
        [--torch-index URL] [--pip-arg ARG ...]
    python setup_env.py --venv DIR --pyproject pyproject.toml --device cuda     (the command-line equivalent)

Standard library only (the environment does not exist yet). The requirements carry PEP 508
markers: the set for the environment's Python is chosen with check_env.py's evaluator (the file
beside this one), plus the device's extras (gsplat for cuda). torch is installed first and on its
own, from ``--torch-index`` when given (PyTorch's CPU index: the small CPU-only build; empty: PyPI,
whose Linux wheels are the CUDA builds); the rest from PyPI. A torch of the other build is
uninstalled first, since pip would keep it (``torch==2.13.0`` matches ``2.13.0+cpu`` too). For
cuda, cuda_build.py (beside this file) then installs NVIDIA's compiler wheels and builds gsplat's
kernels in the environment, for the GPU present or ``--cuda-archs``; its C++ compiler and Python
headers are checked before anything is downloaded.
Speaks the backend's JSON-lines event protocol on stdout (stage, progress, log, output, done,
error, cancelled) so the add-on shows it like any backend job; on a terminal it prints progress
lines instead and keeps pip's output in DIR/igs-setup.log. Exit codes: 0 ok, 2 failed,
130 cancelled.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import sysconfig
import time
import venv

_human = None  # on a terminal: cuda_build.Reporter's lines instead of events (main sets it)


def emit(event: str, **fields) -> None:
    if _human is not None:
        _human(event, **fields)
        return
    sys.stdout.write(json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


def load_script(name: str = "check_env"):
    """``name``.py from this script's folder (run with runpy, this folder is not on sys.path)."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), f"{name}.py")
    spec = importlib.util.spec_from_file_location(f"igs_{name}", path)
    if spec is None or spec.loader is None:
        raise RuntimeError(f"{path}: missing; reinstall the extension")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def venv_python(env_dir: str) -> str:
    if sys.platform == "win32":
        return os.path.join(env_dir, "Scripts", "python.exe")
    return os.path.join(env_dir, "bin", "python")


def venv_version(env_dir: str) -> str:
    """The Python version an existing venv was made with (its pyvenv.cfg), '' when it is no venv."""
    try:
        with open(os.path.join(env_dir, "pyvenv.cfg"), encoding="utf-8") as f:
            cfg = dict(line.split("=", 1) for line in f if "=" in line)
    except OSError:
        return ""
    cfg = {k.strip().lower(): v.strip() for k, v in cfg.items()}
    return cfg.get("version_info") or cfg.get("version") or "?"


def prepare_venv(env_dir: str, python_full: str) -> None:
    """Create ``env_dir``, or reuse it when it is a venv of this Python's minor version."""
    have = venv_version(env_dir)
    python = venv_python(env_dir)
    if not have:
        if os.path.isdir(env_dir) and os.listdir(env_dir):
            raise RuntimeError(f"{env_dir} exists and is not a Python environment (no pyvenv.cfg): "
                               "choose a new or empty Environment Folder")
        emit("log", message=f"creating {env_dir} with {sys.executable} (Python {python_full})")
        try:
            venv.EnvBuilder(with_pip=True).create(env_dir)
        except subprocess.CalledProcessError as e:  # ensurepip failed: Debian/Ubuntu split it out
            raise RuntimeError(f"{sys.executable} cannot create a virtual environment with pip (ensurepip "
                               f"failed); on Debian/Ubuntu install python{python_full.rsplit('.', 1)[0]}-venv, "
                               "or choose another Base Python") from e
    elif have.split(".")[:2] != python_full.split(".")[:2]:
        raise RuntimeError(f"{env_dir} is a Python {'.'.join(have.split('.')[:2])} environment but the Base "
                           f"Python is {'.'.join(python_full.split('.')[:2])}: delete that folder or choose "
                           "another Environment Folder")
    elif not os.path.exists(python):
        # Its base Python moved (an upgraded Blender of the same Python): point it at this one.
        emit("log", message=f"repairing {env_dir}: its interpreter is gone, using {sys.executable}")
        venv.EnvBuilder(with_pip=True, upgrade=True).create(env_dir)
    else:
        emit("log", message=f"updating the existing environment {env_dir} (Python {have})")
    if not os.path.exists(python):
        raise RuntimeError(f"the new environment has no interpreter at {python}")


_TORCH_QUERY = r"""
import importlib.metadata as md, json
try:
    d = md.distribution("torch")
    print(json.dumps([d.version, any(r.startswith("nvidia-") for r in d.requires or [])]))
except md.PackageNotFoundError:
    print("null")
"""


def installed_torch(python: str) -> tuple[str, bool] | None:
    """(version, CUDA build) of the torch installed in the environment, without importing it."""
    try:
        out = subprocess.run([python, "-c", _TORCH_QUERY], capture_output=True, text=True, timeout=120)
        found = json.loads(out.stdout.strip() or "null") if out.returncode == 0 else None
    except (OSError, subprocess.SubprocessError, ValueError):  # then pip decides alone
        return None
    return (found[0], bool(found[1])) if found else None


def torch_build_mismatch(torch: tuple[str, bool] | None, device: str, index: str) -> str:
    """Why the installed torch is the wrong build for ``device`` ('' when it fits or is absent)."""
    if torch is None:
        return ""
    version, cuda_build = torch
    cpu_build = version.endswith("+cpu")
    if device == "cuda" and (cpu_build or (sys.platform == "linux" and not cuda_build)):
        return f"torch {version} is a CPU-only build"
    if device == "cpu" and index and cuda_build:
        return f"torch {version} is a CUDA build"
    return ""


def run_pip(python: str, args: list[str], stage: str, step: int = 0, total: int = 0) -> None:
    """Run pip, forwarding its output as log events; raise RuntimeError with pip's last error line."""
    cmd = [python, "-m", "pip", *args]
    emit("log", message="$ " + " ".join(cmd))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    last_error = ""
    assert proc.stdout is not None
    for line in proc.stdout:
        line = line.rstrip()
        if not line:
            continue
        if "error" in line.lower():
            last_error = line
        emit("log", message=line, tool=True)
    rc = proc.wait()
    if rc != 0:
        raise RuntimeError(f"pip {' '.join(args[:2])} failed (exit {rc})" + (f": {last_error}" if last_error else ""))
    if step:
        emit("progress", stage=stage, step=step, total=total, eta_s=None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--venv", required=True, help="folder of the environment to create or update")
    parser.add_argument("--requirements-json",
                        help="JSON list of pinned requirements (PEP 508 python_version markers allowed)")
    parser.add_argument("--pyproject", help="read requires-python and the dependencies from this pyproject.toml")
    parser.add_argument("--requires-python", default="", help="specifiers the base Python must satisfy")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="cpu: any torch build (the CPU one from --torch-index); cuda: a CUDA torch and gsplat")
    parser.add_argument("--cuda-archs", default="",
                        help="cuda: the GPU architectures to build gsplat's kernels for when no GPU is visible "
                             "(default: cuda_build.py's)")
    parser.add_argument("--torch-index", default="", help="package index for the torch step only (empty: PyPI)")
    parser.add_argument("--pip-arg", action="append", default=[], help="extra argument for every pip install")
    args = parser.parse_args(argv)
    global _human
    if sys.stdout.isatty():  # run by hand: progress lines here, pip's output in the environment's log
        _human = load_script("cuda_build").Reporter(None, os.path.join(args.venv, "igs-setup.log"))
    t0 = time.perf_counter()
    emit("start", command="setup-env", argv=argv if argv is not None else sys.argv[1:])
    python_full = ".".join(str(v) for v in sys.version_info[:3])
    try:
        check = load_script()
        if args.requirements_json is not None:
            reqs = json.loads(args.requirements_json)
        elif args.pyproject:
            requires_python, reqs = check.read_pyproject(args.pyproject)
            args.requires_python = args.requires_python or requires_python
        else:
            raise ValueError("give the requirements: --requirements-json or --pyproject")
        problem = check.python_problem(python_full, args.requires_python)
        if problem:
            choices = check.choices_text(check.supported_pythons(args.requires_python))
            raise ValueError(f"{problem}: choose {choices} as Base Python")
        if args.device == "cuda" and not args.torch_index and sys.platform != "linux":
            raise ValueError(f"NVIDIA CUDA: PyPI has CUDA builds of torch only for Linux, not {sys.platform}; "
                             "choose CPU as Device")
        build = None
        if args.device == "cuda":  # what the kernels' build needs, before gigabytes are downloaded
            build = load_script("cuda_build")
            try:
                archs = build.parse_archs(args.cuda_archs or build.DEFAULT_ARCHS)
            except ValueError as e:
                raise ValueError(f"--cuda-archs: {e}") from e
            paths = sysconfig.get_paths()
            problem = build.python_headers_problem(paths["include"], os.path.isfile(
                os.path.join(paths["include"], "Python.h"))) or build.host_compiler_problem()
            if problem:
                raise ValueError(problem)
        if not isinstance(reqs, list) or not all(isinstance(r, str) for r in reqs):
            raise ValueError("--requirements-json: expected a JSON list of strings")
        applies, skipped = check.requirements_for(reqs, python_full, args.device)
    except (ValueError, RuntimeError, OSError) as e:
        emit("error", message=str(e))
        return 2
    torch = [r for r in applies if check.normal_name(check.split_requirement(r)[0]) == "torch"]
    rest = [r for r in applies if r not in torch]
    total = 1 + bool(torch) + bool(rest)
    stage = "backend environment"
    emit("stage", stage=stage, total=total)
    if skipped:
        emit("log", message=f"not for Python {python_full}: " + ", ".join(skipped))
    pip = ["install", "--disable-pip-version-check", "--progress-bar", "off"]
    try:
        prepare_venv(args.venv, python_full)
        python = venv_python(args.venv)
        emit("progress", stage=stage, step=1, total=total, eta_s=None)
        step = 1
        if torch:
            wrong = torch_build_mismatch(installed_torch(python), args.device, args.torch_index)
            if wrong:
                emit("log", message=f"{wrong}, not the one for device '{args.device}': replacing it")
                run_pip(python, ["uninstall", "--yes", "torch"], stage)
            # After the --pip-arg options, so that the torch index wins over an --index-url among them.
            index = ["--index-url", args.torch_index] if args.torch_index else []
            step += 1
            run_pip(python, [*pip, *args.pip_arg, *index, *torch], stage, step, total)
        if rest:
            step += 1
            run_pip(python, [*pip, *args.pip_arg, *rest], stage, step, total)
        found = installed_torch(python) if torch else None
        if found:
            emit("log", message=f"torch {found[0]}: " + ("CUDA build" if found[1] else "CPU build"))
        if build is not None:
            build.setup_cuda(python, archs, args.pip_arg, build.Reporter(emit))
        emit("output", kind="interpreter", path=python)
    except KeyboardInterrupt:
        emit("cancelled", message="environment setup cancelled; run it again to finish")
        return 130
    except (RuntimeError, OSError, subprocess.SubprocessError, ValueError) as e:
        emit("error", message=str(e))
        return 2
    emit("done", command="setup-env", seconds=time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
