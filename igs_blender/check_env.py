"""Report what a backend interpreter lacks; run BY that interpreter, never imported by Blender::

    python check_env.py --requirements-json '["numpy==1.26.4", ...]' [--python-version 3.11]

Standard library only. Prints one ``{"event": "env", ...}`` JSON line (python version, each pinned
package with the installed version, whether ``backend`` imports and which commands it offers),
then ``done``. The add-on turns that into the report shown in the preferences.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import json
import re
import sys
import time


def emit(event: str, **fields) -> None:
    sys.stdout.write(json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


def _normal(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def check_packages(reqs: list[str]) -> list[dict]:
    out = []
    for req in reqs:
        m = re.match(r"^\s*([A-Za-z0-9_.\-]+)(?:\[.*\])?\s*(==|>=|~=)?\s*([^;\s]*)", req)
        if not m:
            continue
        name, op, want = m.group(1), m.group(2) or "", m.group(3) or ""
        try:
            have = md.version(name)
        except md.PackageNotFoundError:
            have = None
        ok = have is not None and (op != "==" or _base(have) == want)
        out.append({"name": _normal(name), "want": f"{op}{want}", "have": have, "ok": ok})
    return out


def _base(version: str) -> str:
    return version.split("+")[0]  # torch reports local versions such as 2.13.0+cpu


def backend_commands() -> tuple[bool, list[str], str]:
    """(importable, command names, error) of the backend on this interpreter's path."""
    try:
        from backend import cli  # noqa: PLC0415 (only in the backend interpreter)

        parser = cli.build_parser()
    except Exception as e:  # any import problem is what the user needs to see
        return False, [], f"{type(e).__name__}: {e}"
    names: list[str] = []
    for action in parser._actions:  # argparse has no public accessor for subcommands
        choices = getattr(action, "choices", None)
        if isinstance(choices, dict):
            names.extend(choices)
    return True, sorted(names), ""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requirements-json", required=True)
    parser.add_argument("--python-version", default="3.11", help="required major.minor")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    emit("start", command="check-env", argv=argv or sys.argv[1:])
    packages = check_packages(json.loads(args.requirements_json))
    ok_backend, commands, err = backend_commands()
    have_py = f"{sys.version_info.major}.{sys.version_info.minor}"
    emit("env", executable=sys.executable, python=sys.version.split()[0], python_ok=have_py == args.python_version,
         python_wanted=args.python_version, packages=packages, backend=ok_backend, backend_error=err,
         commands=commands)
    emit("done", command="check-env", seconds=time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
