"""Report what a backend interpreter lacks; run BY that interpreter (the add-on imports only its helpers)::

    python check_env.py --requirements-json '["numpy==1.26.4; python_version < \\'3.12\\'", ...]' \\
        [--requires-python '>=3.11,<3.15'] [--device cpu|cuda]
    python check_env.py --pyproject pyproject.toml [--device cpu|cuda]      (the same, read from the file)
    python check_env.py --pyproject pyproject.toml --python-only            (exit 2 + one line if unsupported)
    python check_env.py --pyproject pyproject.toml --list                   (the pins that apply here)

Standard library only, and it must run on any Python 3 far enough to say "this Python is not
supported". The requirements carry PEP 508 markers; this interpreter keeps only those whose
``python_version`` markers hold for itself (the small evaluator below understands exactly
``python_version``/``python_full_version`` comparisons joined by ``and``/``or`` and refuses any
other marker). Prints one ``{"event": "env", ...}`` JSON line (python version and whether
``requires-python`` allows it, each applicable pin with the installed version, the torch build and
whether CUDA works, whether ``backend`` imports and which commands it offers), then ``done``. The
add-on turns that into the report shown in the preferences.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import json
import os
import re
import shutil
import sys
import time

# What the "NVIDIA CUDA" device adds to the pinned set: gsplat's CUDA rasteriser (a pure-Python
# wheel that compiles its kernels with the CUDA toolkit's nvcc on first use).
DEVICE_EXTRAS = {"cpu": [], "cuda": ["gsplat==1.5.3"]}
DEVICES = tuple(DEVICE_EXTRAS)


def emit(event: str, **fields) -> None:
    sys.stdout.write(json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


# -- versions, specifiers and markers (the PEP 440 / 508 subset pyproject.toml uses) -----------------

_SPEC = re.compile(r"^(~=|==|!=|<=|>=|<|>)\s*([0-9]+(?:\.[0-9]+)*)(\.\*)?$")
_MARKER = re.compile(r"""^(python_version|python_full_version)\s*(~=|==|!=|<=|>=|<|>)\s*(['"])([^'"]*)\3$""")


def _release(text: str) -> tuple[int, ...]:
    return tuple(int(p) for p in text.split("."))


def _cmp(a: tuple[int, ...], b: tuple[int, ...]) -> int:
    n = max(len(a), len(b))  # PEP 440 pads the shorter release with zeros
    a, b = a + (0,) * (n - len(a)), b + (0,) * (n - len(b))
    return (a > b) - (a < b)


def version_matches(version: str, specifiers: str) -> bool:
    """Whether the release ``version`` ("3.14.10", "3.11") satisfies ``specifiers`` (">=3.11,<3.15",
    "!=3.12.*", "~=3.11"). Raises ValueError for anything else."""
    have = _release(version)
    for spec in filter(None, (s.strip() for s in specifiers.split(","))):
        m = _SPEC.match(spec)
        if not m:
            raise ValueError(f"unsupported version specifier {spec!r}")
        op, want_text, wildcard = m.groups()
        want = _release(want_text)
        if wildcard:
            if op not in ("==", "!="):
                raise ValueError(f"unsupported version specifier {spec!r}")
            prefix = (have + (0,) * len(want))[:len(want)] == want
            ok = prefix if op == "==" else not prefix
        elif op == "~=":
            if len(want) < 2:
                raise ValueError(f"unsupported version specifier {spec!r} (~= needs two parts)")
            ok = _cmp(have, want) >= 0 and have[:len(want) - 1] == want[:-1]
        else:
            c = _cmp(have, want)
            ok = {"==": c == 0, "!=": c != 0, "<": c < 0, "<=": c <= 0, ">": c > 0, ">=": c >= 0}[op]
        if not ok:
            return False
    return True


def evaluate_marker(marker: str, python_full: str) -> bool:
    """A PEP 508 marker made of ``python_version``/``python_full_version`` comparisons joined by
    ``and``/``or`` (``and`` binds tighter), for the Python ``python_full`` ("3.14.10" or "3.14").
    Any other variable, parentheses or a version on the left are refused with a ValueError."""
    python_version = ".".join(python_full.split(".")[:2])
    results = []
    for alternative in re.split(r"\s+or\s+", marker.strip()):
        terms = []
        for term in re.split(r"\s+and\s+", alternative.strip()):
            m = _MARKER.match(term.strip())
            if not m:
                raise ValueError(f"unsupported marker {term.strip()!r} in {marker!r}: only python_version "
                                 "comparisons such as python_version < '3.12' are understood")
            var, op, _, value = m.groups()
            terms.append(version_matches(python_version if var == "python_version" else python_full, op + value))
        results.append(all(terms))
    return any(results)


_REQ = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(\[[^\]]*\])?\s*([^;]*?)\s*(?:;\s*(.*?))?\s*$")


def split_requirement(req: str) -> tuple[str, str, str]:
    """(name, version specifier, marker) of a PEP 508 requirement without a URL."""
    m = _REQ.match(req)
    if not m or "@" in req.split(";")[0]:
        raise ValueError(f"unsupported requirement {req!r}")
    return m.group(1), m.group(3), m.group(4) or ""


def normal_name(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def requirements_for(reqs: list[str], python_full: str, device: str = "cpu") -> tuple[list[str], list[str]]:
    """(the requirements that apply to Python ``python_full`` on ``device``, markers stripped; the
    ones whose markers exclude it, as written)."""
    if device not in DEVICE_EXTRAS:
        raise ValueError(f"unknown device {device!r} (expected one of {', '.join(DEVICES)})")
    applies, skipped = [], []
    for req in [*reqs, *DEVICE_EXTRAS[device]]:
        name, spec, marker = split_requirement(req)
        if marker and not evaluate_marker(marker, python_full):
            skipped.append(req)
        else:
            applies.append(f"{name}{spec}")
    return applies, skipped


_LAST_MINOR = 39  # enumerating 3.x up to here; a set reaching it has no upper bound


def supported_pythons(requires_python: str) -> list[str]:
    """The 3.x minor versions ``requires_python`` allows (any of their patch releases)."""
    return [f"3.{n}" for n in range(6, _LAST_MINOR + 1)
            if version_matches(f"3.{n}", requires_python) or version_matches(f"3.{n}.99", requires_python)]


def python_problem(python_full: str, requires_python: str) -> str:
    """'' when ``requires_python`` allows this Python, else "Python 3.10 is not supported" (plus which are)."""
    if not requires_python or version_matches(python_full, requires_python):
        return ""
    minor = ".".join(python_full.split(".")[:2])
    return f"Python {minor} is not supported (requires-python {requires_python})"


def choices_text(versions: list[str]) -> str:
    """["3.11", "3.13", "3.14"] -> "a Python 3.11, 3.13 or 3.14"; an open end -> "... 3.12 or later"."""
    if not versions:
        return "another Python"
    minors = [int(v.split(".")[1]) for v in versions]
    if minors[-1] == _LAST_MINOR:
        start = len(minors) - 1
        while start and minors[start - 1] == minors[start] - 1:
            start -= 1
        versions = [*versions[:start], f"{versions[start]} or later"]
    return "a Python " + (versions[0] if len(versions) == 1 else ", ".join(versions[:-1]) + " or " + versions[-1])


def read_pyproject(path: str) -> tuple[str, list[str]]:
    """(requires-python, [project] dependencies) of a pyproject.toml."""
    with open(path, encoding="utf-8") as f:
        text = f.read()
    try:
        import tomllib  # noqa: PLC0415 (3.11+; older Pythons only need requires-python to say no)
    except ImportError:
        m = re.search(r"""^requires-python\s*=\s*["']([^"']*)["']""", text, re.M)
        return (m.group(1) if m else ""), []
    project = tomllib.loads(text).get("project", {})
    return project.get("requires-python", ""), list(project.get("dependencies", []))


# -- what is installed ---------------------------------------------------------------------------


def _base(version: str) -> str:
    return version.split("+")[0]  # torch reports local versions such as 2.13.0+cpu


def check_packages(reqs: list[str]) -> list[dict]:
    """Each requirement (markers already applied) with the installed version and whether it fits."""
    out = []
    for req in reqs:
        name, spec, _ = split_requirement(req)
        try:
            have = md.version(name)
        except md.PackageNotFoundError:
            have = None
        ok = have is not None and _fits(_base(have), spec)
        out.append({"name": normal_name(name), "want": spec, "have": have, "ok": ok})
    return out


def _fits(have: str, spec: str) -> bool:
    try:
        return version_matches(have, spec)
    except ValueError:  # a pre-release or dev version the small evaluator does not order
        return have == spec[2:] if spec.startswith("==") else True


def cuda_toolkit() -> str:
    """The nvcc a JIT build (gsplat's kernels, through torch's cpp_extension) would use, '' if none."""
    for var in ("CUDA_HOME", "CUDA_PATH"):
        home = os.environ.get(var)
        if home and os.path.isfile(os.path.join(home, "bin", "nvcc")):
            return os.path.join(home, "bin", "nvcc")
    found = shutil.which("nvcc")
    if found:
        return found
    return "/usr/local/cuda/bin/nvcc" if os.path.isfile("/usr/local/cuda/bin/nvcc") else ""


def torch_info() -> dict | None:
    """The installed torch build and whether CUDA works with it (None when torch is not installed)."""
    try:
        version = md.version("torch")
    except md.PackageNotFoundError:
        return None
    info = {"version": version, "cuda": None, "cuda_available": False, "cuda_device": "", "cuda_error": "",
            "error": ""}
    try:
        import torch  # noqa: PLC0415 (only here: importing it takes seconds)
    except Exception as e:  # a broken install is what the user needs to see
        info["error"] = f"{type(e).__name__}: {e}".splitlines()[0]
        return info
    info["version"] = str(torch.__version__)
    info["cuda"] = torch.version.cuda
    if torch.version.cuda:
        try:
            torch.cuda.init()  # raises with the reason (no driver, no GPU) where is_available() says False
            info["cuda_available"] = True
            info["cuda_device"] = torch.cuda.get_device_name(0)
        except Exception as e:
            # First sentence only: torch's no-driver message goes on with a download URL.
            info["cuda_error"] = (str(e).splitlines() or [type(e).__name__])[0].split(". ")[0].rstrip(".")
    return info


def backend_commands() -> tuple[bool, list[str], str]:
    """(importable, command names, error) of the backend on this interpreter's path."""
    try:
        from backend.commands import cli  # noqa: PLC0415 (only in the backend interpreter)

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
    parser.add_argument("--requirements-json", help="JSON list of pinned requirements (PEP 508 markers allowed)")
    parser.add_argument("--requires-python", default="", help="specifiers this Python must satisfy")
    parser.add_argument("--pyproject", help="read requires-python and the dependencies from this pyproject.toml")
    parser.add_argument("--device", choices=DEVICES, default="cpu", help="the torch build and extras to expect")
    parser.add_argument("--python-only", action="store_true",
                        help="only check this Python against requires-python: exit 2 with one line if it is not allowed")
    parser.add_argument("--list", action="store_true", help="print the requirements that apply here, one a line")
    args = parser.parse_args(argv)
    python_full = ".".join(str(v) for v in sys.version_info[:3])
    try:
        requires_python, reqs = read_pyproject(args.pyproject) if args.pyproject else ("", [])
        if args.requirements_json is not None:
            reqs = json.loads(args.requirements_json)
            if not isinstance(reqs, list) or not all(isinstance(r, str) for r in reqs):
                raise ValueError("--requirements-json: expected a JSON list of strings")
        requires_python = args.requires_python or requires_python
        problem = python_problem(python_full, requires_python)
        if args.python_only:
            if problem:
                print(f"{problem}: use {choices_text(supported_pythons(requires_python))}", file=sys.stderr)
                return 2
            return 0
        applies, skipped = requirements_for(reqs, python_full, args.device)
    except (OSError, ValueError) as e:  # a malformed pin or pyproject: one line, no traceback
        print(f"check_env: {e}", file=sys.stderr)
        emit("error", message=str(e))
        return 2
    if args.list:
        print("\n".join(applies))
        return 0
    t0 = time.perf_counter()
    emit("start", command="check-env", argv=argv if argv is not None else sys.argv[1:])
    packages = check_packages(applies)
    torch = torch_info()
    ok_backend, commands, err = backend_commands()
    emit("env", executable=sys.executable, python=sys.version.split()[0], python_ok=not problem,
         requires_python=requires_python, python_supported=supported_pythons(requires_python) if requires_python else [],
         device=args.device, packages=packages, not_applicable=skipped, torch=torch,
         nvcc=cuda_toolkit() if args.device == "cuda" else "", backend=ok_backend, backend_error=err,
         commands=commands)
    emit("done", command="check-env", seconds=time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
