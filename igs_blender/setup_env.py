"""Create the backend's Python environment: a venv with the project's pinned requirements.

Run by the add-on with a base Python 3.11 (Blender's own by default), never imported by Blender::

    python setup_env.py --venv DIR --requirements-json '["numpy==1.26.4", "torch==2.13.0", ...]'

Standard library only (the environment does not exist yet). Speaks the backend's JSON-lines event
protocol on stdout (stage, progress, log, done, error, cancelled) so the add-on shows it like any
backend job. torch is installed first and on its own, as ``dev.sh`` does, so that its pin picks
the platform's default build. Exit codes: 0 ok, 2 failed, 130 cancelled.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import venv


def emit(event: str, **fields) -> None:
    sys.stdout.write(json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


def venv_python(env_dir: str) -> str:
    if sys.platform == "win32":
        return os.path.join(env_dir, "Scripts", "python.exe")
    return os.path.join(env_dir, "bin", "python")


def run_pip(python: str, args: list[str], stage: str, step: int, total: int) -> None:
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
        emit("log", message=line)
    rc = proc.wait()
    if rc != 0:
        raise RuntimeError(f"pip {' '.join(args[:2])} failed (exit {rc})" + (f": {last_error}" if last_error else ""))
    emit("progress", stage=stage, step=step, total=total, eta_s=None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--venv", required=True, help="folder of the environment to create or update")
    parser.add_argument("--requirements-json", required=True, help="JSON list of pinned requirements")
    parser.add_argument("--pip-arg", action="append", default=[], help="extra argument for every pip install")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    emit("start", command="setup-env", argv=argv or sys.argv[1:])
    try:
        reqs = json.loads(args.requirements_json)
        if not isinstance(reqs, list) or not all(isinstance(r, str) for r in reqs):
            raise ValueError("expected a JSON list of strings")
    except ValueError as e:
        emit("error", message=f"--requirements-json: {e}")
        return 2
    torch = [r for r in reqs if r.split("=")[0].split("[")[0].strip().lower() == "torch"]
    rest = [r for r in reqs if r not in torch]
    groups = [g for g in (torch, rest) if g]
    total = 1 + len(groups)
    stage = "backend environment"
    emit("stage", stage=stage, total=total)
    try:
        python = venv_python(args.venv)
        if not os.path.exists(python):
            emit("log", message=f"creating {args.venv} with {sys.executable} (Python {sys.version.split()[0]})")
            venv.EnvBuilder(with_pip=True, clear=False, upgrade_deps=False).create(args.venv)
        else:
            emit("log", message=f"updating the existing environment {args.venv}")
        if not os.path.exists(python):
            raise RuntimeError(f"the new environment has no interpreter at {python}")
        emit("progress", stage=stage, step=1, total=total, eta_s=None)
        for i, group in enumerate(groups, start=2):
            run_pip(python, ["install", "--disable-pip-version-check", *args.pip_arg, *group], stage, i, total)
        emit("output", kind="interpreter", path=python)
    except KeyboardInterrupt:
        emit("cancelled", message="environment setup cancelled; run it again to finish")
        return 130
    except (RuntimeError, OSError, subprocess.SubprocessError) as e:
        emit("error", message=str(e))
        return 2
    emit("done", command="setup-env", seconds=time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
