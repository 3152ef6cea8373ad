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
whether CUDA works with the GPU's compute capability; for the cuda device also the compiler the
set-up installed and gsplat's built kernels with the architectures read from the module itself;
whether ``backend`` imports and which commands it offers), then ``done``. The add-on turns that
into the report shown in the preferences.
"""

from __future__ import annotations

import argparse
import importlib.metadata as md
import json
import re
import struct
import sys
import time

# What the "NVIDIA CUDA" device adds to the pinned set: gsplat's CUDA rasteriser. Its PyPI wheel is
# pure Python and would compile the kernels at first use with a CUDA toolkit; the set-up instead
# builds them from its sdist with NVIDIA's compiler wheels (cuda_build.py).
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


# -- gsplat's built kernels (the .nv_fatbin section of its extension module) ---------------------

_FATBIN_MAGIC = 0xBA55ED50
_FATBIN_PTX, _FATBIN_CUBIN = 1, 2


def elf_section(path: str, name: str) -> bytes | None:
    """The bytes of section ``name`` of a 64-bit little-endian ELF file (None when it has none).
    Raises ValueError for a file that is no such ELF."""
    with open(path, "rb") as f:
        head = f.read(64)
        if len(head) < 64 or head[:4] != b"\x7fELF" or head[4] != 2 or head[5] != 1:
            raise ValueError(f"{path}: not a 64-bit little-endian ELF file")
        (shoff,) = struct.unpack_from("<Q", head, 0x28)
        shentsize, shnum, shstrndx = struct.unpack_from("<HHH", head, 0x3A)
        f.seek(shoff)
        table = f.read(shentsize * shnum)
        if len(table) < shentsize * shnum or shstrndx >= shnum or shentsize < 40:
            raise ValueError(f"{path}: truncated ELF section table")

        def header(i: int) -> tuple[int, int, int]:  # (name offset, file offset, size)
            fields = struct.unpack_from("<IIQQQQ", table, i * shentsize)
            return fields[0], fields[4], fields[5]

        _, str_off, str_size = header(shstrndx)
        f.seek(str_off)
        names = f.read(str_size)
        for i in range(shnum):
            name_off, off, size = header(i)
            end = names.find(b"\0", name_off)
            if names[name_off:end if end >= 0 else None] == name.encode():
                f.seek(off)
                return f.read(size)
    return None


def fatbin_archs(data: bytes) -> tuple[list[int], list[int]]:
    """(SM versions with machine code, SM versions with PTX) of the CUDA fat binaries in ``data`` (an
    ELF ``.nv_fatbin`` section: one fat binary per compiled file, each a 16-byte header, then entries
    whose own header holds the kind at byte 0, its size at 4, the payload's size at 8 and the SM
    version at 28): ([80, 89, 90], [90]) for sm_80, sm_89 and sm_90 plus compute_90 PTX."""
    cubins, ptx = set(), set()
    off = 0
    while off + 16 <= len(data):
        magic, _, head_size, fat_size = struct.unpack_from("<IHHQ", data, off)
        if magic != _FATBIN_MAGIC:
            off += 8  # fat binaries are 8-byte aligned; padding between them is zeros
            continue
        entry, end = off + head_size, min(off + head_size + fat_size, len(data))
        while entry + 32 <= end:
            kind, _, entry_head, payload = struct.unpack_from("<HHIQ", data, entry)
            (sm,) = struct.unpack_from("<I", data, entry + 28)
            if entry_head == 0:
                break
            (cubins if kind == _FATBIN_CUBIN else ptx if kind == _FATBIN_PTX else set()).add(sm)
            entry += entry_head + payload
        off = max(end, off + 8)
    return sorted(cubins), sorted(ptx)


def arch_text(sm: list[int], ptx: list[int]) -> str:
    """"sm_80, sm_89, sm_90 (+PTX compute_90)"."""
    text = ", ".join(f"sm_{v}" for v in sm) or "no machine code"
    return text + (f" (+PTX {', '.join(f'compute_{v}' for v in ptx)})" if ptx else "")


def runs_on(capability: int, sm: list[int], ptx: list[int]) -> bool:
    """Whether kernels with machine code for ``sm`` and PTX for ``ptx`` run on a GPU of compute
    capability ``capability`` (89 for 8.9): machine code runs on the same major version at the same
    or a later minor one; PTX is compiled by the driver for any later GPU."""
    return (any(v // 10 == capability // 10 and v <= capability for v in sm)
            or any(v <= capability for v in ptx))


def gsplat_kernels(load: bool) -> dict | None:
    """gsplat's compiled extension (``gsplat.csrc``) in this environment, None when gsplat is not
    installed: ``module`` (its path, '' when the installed gsplat has none: the PyPI wheel), ``sm``
    and ``ptx`` (the architectures it was built for), ``error`` (why it cannot be read or loaded).
    ``load`` also loads it (torch must be imported first: it links against torch's libraries)."""
    try:
        dist = md.distribution("gsplat")
    except md.PackageNotFoundError:
        return None
    info = {"version": dist.version, "module": "", "sm": [], "ptx": [], "error": ""}
    found = [f for f in dist.files or [] if re.fullmatch(r"gsplat/csrc(\.[^/]*)?\.(so|pyd)", str(f).replace("\\", "/"))]
    if not found:
        return info
    path = str(dist.locate_file(found[0]))
    info["module"] = path
    try:
        section = elf_section(path, ".nv_fatbin")
        info["sm"], info["ptx"] = fatbin_archs(section or b"")
        if load:
            import importlib.util  # noqa: PLC0415

            spec = importlib.util.spec_from_file_location("gsplat.csrc", path)
            if spec is None or spec.loader is None:
                raise ImportError(f"{path}: not an extension module")
            spec.loader.exec_module(importlib.util.module_from_spec(spec))
    except Exception as e:  # a broken build is what the user needs to see
        info["error"] = (f"{type(e).__name__}: {e}".splitlines() or ["?"])[0]
    return info


def cuda_compiler() -> str:
    """The nvcc the set-up installed in this environment (NVIDIA's nvidia-cuda-nvcc wheel), '' if none."""
    try:
        dist = md.distribution("nvidia-cuda-nvcc")
    except md.PackageNotFoundError:
        return ""
    for f in dist.files or []:
        if str(f).replace("\\", "/").endswith(("/bin/nvcc", "/bin/nvcc.exe")):
            return str(dist.locate_file(f))
    return ""


def torch_info() -> dict | None:
    """The installed torch build and whether CUDA works with it (None when torch is not installed)."""
    try:
        version = md.version("torch")
    except md.PackageNotFoundError:
        return None
    info = {"version": version, "cuda": None, "cuda_available": False, "cuda_device": "", "cuda_capability": 0,
            "cuda_error": "", "error": ""}
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
            major, minor = torch.cuda.get_device_capability(0)
            info["cuda_capability"] = 10 * major + minor
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
    cuda = args.device == "cuda"
    kernels = gsplat_kernels(load=bool(torch and not torch["error"])) if cuda else None
    ok_backend, commands, err = backend_commands()
    emit("env", executable=sys.executable, python=sys.version.split()[0], python_ok=not problem,
         requires_python=requires_python, python_supported=supported_pythons(requires_python) if requires_python else [],
         device=args.device, packages=packages, not_applicable=skipped, torch=torch,
         nvcc=cuda_compiler() if cuda else "", gsplat_kernels=kernels, backend=ok_backend, backend_error=err,
         commands=commands)
    emit("done", command="check-env", seconds=time.perf_counter() - t0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
