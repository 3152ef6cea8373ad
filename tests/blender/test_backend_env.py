"""The backend environment: one pinned set per Python, the CPU/CUDA choice, creating and checking it.

The marker evaluator and requires-python handling are tested on their own and on the real
pyproject.toml; check_env.py runs in real interpreters (the project's venv, a bare venv);
setup_env.py runs the real venv + pip path offline, with tiny stand-in wheels named like the real
pins (so pip would fail if the wrong set were asked for). The preferences' side is
``test_backend_env_prefs.py``.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import stat
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parents[2]

from intrinsic_splats.igs_blender.env import backend_env, check_env, cuda_build  # noqa: E402
from intrinsic_splats.igs_blender.errors import UserError  # noqa: E402
from intrinsic_splats.igs_blender.jobs.client import BackendJob, parse_event  # noqa: E402

from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)
from tests.support.env_pins import FIX, PINS, wanted_reqs  # noqa: E402

PYTHON = sys.executable
REQUIRES = backend_env.read_pyproject(ROOT)[0]


def names(reqs: list[str]) -> dict[str, str]:
    return dict(r.split("==", 1) for r in reqs)


# -- markers and requires-python ---------------------------------------------------------------------


@pytest.mark.parametrize("python, numpy, bpy", [("3.11", "1.26.4", "5.0.1"), ("3.11.7", "1.26.4", "5.0.1"),
                                                ("3.13", "2.4.6", "5.3.0"), ("3.13.0", "2.4.6", "5.3.0"),
                                                ("3.14.10", "2.4.6", None)])
def test_the_real_pins_give_one_set_per_python(python, numpy, bpy):
    applies, skipped = check_env.requirements_for(PINS, python)
    pins = names(applies)
    assert pins["numpy"] == numpy and pins.get("bpy") == bpy
    assert pins["torch"] == "2.13.0" and pins["av"] == "18.1.0"
    assert len(applies) == len(pins), "one pin per package"
    assert all(";" not in r for r in applies) and all(";" in r for r in skipped)
    assert len(applies) + len(skipped) == len(PINS)
    cuda = names(check_env.requirements_for(PINS, python, "cuda")[0])
    assert cuda == {**pins, "gsplat": "1.5.3"}


def test_marker_evaluator_compares_versions_not_strings():
    ev = check_env.evaluate_marker
    assert ev("python_version < '3.12'", "3.11.9") and not ev("python_version < '3.12'", "3.13.0")
    assert ev("python_version >= '3.12'", "3.14") and not ev("python_version >= '3.12'", "3.11")
    assert not ev("python_version < '3.9'", "3.14")  # "3.14" < "3.9" as strings
    assert ev('python_version == "3.13"', "3.13.5") and ev("python_version != '3.13'", "3.14")
    assert ev("python_version >= '3.12' and python_version < '3.14'", "3.13")
    assert not ev("python_version >= '3.12' and python_version < '3.14'", "3.14")
    assert ev("python_version < '3.12' or python_version >= '3.14'", "3.14")
    assert ev("python_full_version >= '3.11.4'", "3.11.7") and not ev("python_full_version >= '3.11.8'", "3.11.7")
    assert ev("python_version ~= '3.11'", "3.14") and not ev("python_version ~= '3.13.0'", "3.14")


@pytest.mark.parametrize("marker", ["sys_platform == 'linux'", "platform_machine == 'x86_64'",
                                    "(python_version < '3.12')", "'3.12' > python_version",
                                    "python_version < 3.12", "extra == 'cuda'"])
def test_other_markers_are_refused_by_name(marker):
    with pytest.raises(ValueError, match="unsupported marker.*only python_version"):
        check_env.evaluate_marker(marker, "3.11")


def test_a_pyproject_with_a_marker_the_scripts_cannot_read_is_one_user_error(tmp_path):
    (tmp_path / "pyproject.toml").write_text('[project]\nrequires-python = ">=3.11"\n'
                                             "dependencies = [\"torch==2.13.0; sys_platform == 'linux'\"]\n")
    with pytest.raises(UserError, match="pyproject.toml: cannot read.*sys_platform"):
        backend_env.pinned_requirements(tmp_path)


def test_supported_pythons_come_from_requires_python():
    assert REQUIRES == ">=3.11,<3.15"  # what the add-on and dev.sh read, never a hard-coded 3.11
    assert check_env.supported_pythons(REQUIRES) == ["3.11", "3.12", "3.13", "3.14"]
    assert check_env.supported_pythons(">=3.11,<3.15,!=3.12.*") == ["3.11", "3.13", "3.14"]
    assert check_env.choices_text(["3.11", "3.13", "3.14"]) == "a Python 3.11, 3.13 or 3.14"
    assert check_env.choices_text(check_env.supported_pythons(">=3.12")) == "a Python 3.12 or later"
    assert check_env.python_problem("3.14.10", REQUIRES) == ""
    assert check_env.python_problem("3.15.0", REQUIRES) == "Python 3.15 is not supported (requires-python >=3.11,<3.15)"
    assert check_env.python_problem("3.10.4", REQUIRES).startswith("Python 3.10 is not supported")
    with pytest.raises(ValueError, match="unsupported version specifier"):
        check_env.version_matches("3.11", ">=3.11 ; <3.15")


# -- check_env.py in real interpreters ------------------------------------------------------------


def run_check(python: str | Path, *args: str, root: Path = ROOT) -> BackendJob:
    argv = backend_env.script_argv(str(python), "check_env.py", list(args))
    _, env = backend_env.backend_command(str(python), [], root)
    job = BackendJob(argv, "Check backend", env=env, cwd=str(Path.home())).start()
    assert job.wait(timeout=180) == 0, job.report()
    return job


def env_event(job: BackendJob) -> dict:
    return next(e for e in job.state.other if e.get("event") == "env")


def test_project_venv_is_ready_with_its_python_set_and_torch_build():
    job = backend_env.check_job(PYTHON, str(ROOT)).start()
    assert job.wait(timeout=180) == 0, job.report()
    ok, lines = backend_env.env_report_lines(job)
    env = env_event(job)
    assert ok, lines
    minor = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert lines[0].startswith(f"Python {minor}") and "backend ready" in lines[0]
    torch = env["torch"]
    assert lines[0].endswith(f"torch {torch['version']} " + (f"CUDA on {torch['cuda_device']}"
                                                              if torch["cuda_available"] else "on the CPU"))
    build = "CPU-only build" if torch["cuda"] is None else f"CUDA {torch['cuda']} build, " + (
        f"CUDA usable on {torch['cuda_device']}" if torch["cuda_available"]
        else f"CUDA not usable: {torch['cuda_error'] or 'no GPU'}")  # PyPI's Linux torch is a CUDA build
    assert f"torch {torch['version']}: {build}" in lines
    assert env["python_ok"] and env["requires_python"] == REQUIRES and env["device"] == "cpu"
    wanted = names(wanted_reqs(minor))
    assert {p["name"]: p["want"] for p in env["packages"]} == {n: "==" + v for n, v in wanted.items()}
    skipped = [r for r in PINS if ";" in r and r.split(";")[0] not in wanted_reqs(minor)]
    assert env["not_applicable"] == skipped and skipped
    assert f"Not for Python {minor}: " + ", ".join(skipped) in lines


def test_check_env_reads_the_real_pyproject_itself():
    res = subprocess.run([PYTHON, str(ROOT / "igs_blender" / "env" / "check_env.py"), "--pyproject", str(ROOT / "pyproject.toml")],
                         capture_output=True, text=True, timeout=180, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    env = next(json.loads(ln) for ln in res.stdout.splitlines() if '"event": "env"' in ln)
    assert env["python_ok"] and env["requires_python"] == REQUIRES
    assert all(p["ok"] for p in env["packages"]), [p for p in env["packages"] if not p["ok"]]
    listed = subprocess.run([PYTHON, str(ROOT / "igs_blender" / "env" / "check_env.py"), "--pyproject",
                             str(ROOT / "pyproject.toml"), "--list"], capture_output=True, text=True, timeout=60)
    minor = f"{sys.version_info.major}.{sys.version_info.minor}"
    assert listed.stdout.split() == check_env.requirements_for(PINS, minor)[0]


BARE_MINOR = "3.11" if shutil.which("python3.11") else f"{sys.version_info.major}.{sys.version_info.minor}"


def test_bare_venv_names_the_missing_packages_and_the_fix(bare_venv):
    job = backend_env.check_job(str(bare_venv), str(ROOT)).start()
    assert job.wait(timeout=120) == 0, job.report()
    ok, lines = backend_env.env_report_lines(job)
    assert not ok
    # Every pin for its Python is missing: the first two named, the count of the rest, then the fix.
    first_two = "numpy, bpy" if BARE_MINOR in ("3.11", "3.13") else "numpy, torch"  # no bpy pin for 3.14
    assert lines[0] == f"{first_two} and {len(wanted_reqs(BARE_MINOR)) - 2} more missing: {FIX}"
    missing = next(line for line in lines if line.startswith("Missing: "))
    for req in wanted_reqs(BARE_MINOR):
        assert req in missing
    assert any(line.startswith("Backend does not import: ") for line in lines)


def test_bare_venv_with_a_wrong_version_and_an_unsupported_python(bare_venv, tmp_path):
    site = next(Path(bare_venv).parent.parent.glob("lib/python3*/site-packages"))
    dist = site / "numpy-2.4.6.dist-info"
    dist.mkdir()
    try:
        (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: numpy\nVersion: 2.4.6\n")
        job = run_check(bare_venv, "--requirements-json", json.dumps(["numpy==1.26.4", "torch==2.13.0"]))
        ok, lines = backend_env.env_report_lines(job)
        assert not ok and lines[0] == f"torch missing and numpy 2.4.6 where 1.26.4 is wanted: {FIX}"
        assert "Other versions: numpy 2.4.6 (wants ==1.26.4)" in lines
    finally:
        shutil.rmtree(dist)
    requires = ">=3.12,<3.15" if BARE_MINOR == "3.11" else f">=3.11,<3.15,!={BARE_MINOR}.*"
    others = [v for v in ("3.11", "3.12", "3.13", "3.14") if v != BARE_MINOR]
    job = run_check(bare_venv, "--requirements-json", json.dumps(PINS), "--requires-python", requires)
    ok, lines = backend_env.env_report_lines(job)
    assert not ok
    assert lines[0] == (f"Python {BARE_MINOR} is not supported: choose a Python {', '.join(others[:-1])} or "
                        f"{others[-1]} as Base Python and {FIX}")


def report_for(env: dict) -> tuple[bool, list[str]]:
    """env_report_lines on a check event as check_env.py writes it (for what no machine here has)."""
    base = {"executable": "/env/bin/python", "python": "3.14.10", "python_ok": True, "requires_python": REQUIRES,
            "python_supported": ["3.11", "3.12", "3.13", "3.14"], "device": "cpu", "packages": [],
            "not_applicable": [], "torch": None, "nvcc": "", "gsplat_kernels": None, "backend": True, "backend_error": "", "commands": ["info"]}
    job = SimpleNamespace(state=SimpleNamespace(other=[{"event": "env", **base, **env}]), report=lambda: "")
    return backend_env.env_report_lines(job)


CUDA_TORCH = {"version": "2.13.0", "cuda": "13.0", "cuda_available": True, "cuda_device": "NVIDIA H100",
              "cuda_error": "", "error": ""}


KERNELS = {"version": "1.5.3", "module": "/env/site/gsplat/csrc.so", "sm": [80, 89, 90], "ptx": [90], "error": ""}


def test_the_first_line_names_the_cuda_problem_and_its_fix():
    nvcc = "/env/site/nvidia/cu13/bin/nvcc"
    ready = {"device": "cuda", "torch": {**CUDA_TORCH, "cuda_capability": 90}, "nvcc": nvcc, "gsplat_kernels": KERNELS}
    ok, lines = report_for(ready)
    assert ok and lines[0] == "Python 3.14.10: backend ready, torch 2.13.0 CUDA on NVIDIA H100"
    assert "torch 2.13.0: CUDA 13.0 build, CUDA usable on NVIDIA H100" in lines
    assert f"CUDA compiler: {nvcc}" in lines and "gsplat built for sm_80, sm_89, sm_90 (+PTX compute_90)" in lines
    ok, lines = report_for({**ready, "torch": {**CUDA_TORCH, "cuda_capability": 120}})
    assert ok, "compute_90 PTX runs on a newer GPU"
    ok, lines = report_for({**ready, "torch": {**CUDA_TORCH, "cuda_capability": 75}})
    assert not ok and lines[0] == ("gsplat is built for sm_80, sm_89, sm_90 (+PTX compute_90), not for this GPU "
                                   f"(sm_75): {FIX}")
    ok, lines = report_for({**ready, "nvcc": "", "gsplat_kernels": {**KERNELS, "module": "", "sm": [], "ptx": []}})
    assert not ok and lines[0] == f"gsplat's CUDA kernels are not built: {FIX}"
    assert "gsplat 1.5.3: its CUDA kernels are not built" in lines
    assert "CUDA compiler: none in the environment (Create Backend Environment installs NVIDIA's from PyPI)" in lines
    broken = {**KERNELS, "error": "ImportError: undefined symbol: _ZN3c10"}
    ok, lines = report_for({**ready, "gsplat_kernels": broken})
    assert not ok and lines[0] == f"gsplat's kernels do not load (ImportError: undefined symbol: _ZN3c10): {FIX}"
    no_driver = {**CUDA_TORCH, "cuda_available": False, "cuda_error": "Found no NVIDIA driver on your system."}
    ok, lines = report_for({**ready, "torch": no_driver})
    assert not ok and lines[0] == ("CUDA is not usable (Found no NVIDIA driver on your system.): install the NVIDIA "
                                   f"driver, or choose CPU as Device and {FIX}")
    ok, lines = report_for({"device": "cpu", "torch": no_driver})  # a CUDA build is fine on the CPU
    assert ok and lines[0].endswith("torch 2.13.0 on the CPU")
    cpu = {**CUDA_TORCH, "version": "2.13.0+cpu", "cuda": None, "cuda_available": False, "cuda_device": ""}
    ok, lines = report_for({"device": "cuda", "torch": cpu, "gsplat_kernels": None,
                            "packages": [{"name": "numpy", "want": "==2.4.6", "have": "1.26.4", "ok": False}]})
    assert not ok and lines[0] == ("numpy 1.26.4 where 2.4.6 is wanted and torch 2.13.0+cpu is a CPU-only build "
                                   f"where the Device is NVIDIA CUDA: {FIX}")
    ok, lines = report_for({"torch": cpu, "backend": False, "backend_error": "ImportError: no module named cv2"})
    assert not ok and lines[0] == "backend does not import: ImportError: no module named cv2"


# -- setup_env.py: the real venv + pip path, offline -------------------------------------------------


def make_wheel(folder: Path, name: str, version: str, module: str = "", requires: tuple[str, ...] = (),
               files: dict[str, str] | None = None, extras: tuple[str, ...] = ()) -> Path:
    """A pure-Python wheel ``name version`` holding ``module`` as its package's __init__ (or ``files``,
    those under a bin/ folder executable), offering ``extras``."""
    folder.mkdir(parents=True, exist_ok=True)
    dist = f"{name.replace('-', '_')}-{version}"
    pkg = name.replace("-", "_")
    meta = (f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n" + "".join(f"Provides-Extra: {e}\n"
                                                                                    for e in extras)
            + "".join(f"Requires-Dist: {r}\n" for r in requires))
    files = {**(files if files is not None else {f"{pkg}/__init__.py": module}),
             f"{dist}.dist-info/METADATA": meta,
             f"{dist}.dist-info/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"}
    record = "".join(f"{n},,\n" for n in files) + f"{dist}.dist-info/RECORD,,\n"
    whl = folder / f"{dist}-py3-none-any.whl"
    with zipfile.ZipFile(whl, "w") as z:
        for n, text in files.items():
            info = zipfile.ZipInfo(n)
            info.external_attr = (stat.S_IFREG | (0o755 if "/bin/" in n else 0o644)) << 16
            z.writestr(info, text)
        z.writestr(f"{dist}.dist-info/RECORD", record)
    return whl


TORCH_CPU = "__version__ = '2.13.0+cpu'\nclass version:\n    cuda = None\n"
TORCH_CUDA = ("__version__ = '2.13.0'\nclass version:\n    cuda = '13.0'\nclass cuda:\n    @staticmethod\n"
              "    def init():\n        raise RuntimeError('Found no NVIDIA driver on your system. Please check.')\n"
              "    @staticmethod\n    def is_available():\n        return False\n")


def simple_index(wheels: Path) -> str:
    """A PEP 503 index (file:// URL) serving the wheels of one folder, as pip reads PyTorch's."""
    root = wheels.parent / f"{wheels.name}-simple"
    for whl in wheels.glob("*.whl"):
        project = root / check_env.normal_name(whl.name.split("-")[0])
        project.mkdir(parents=True, exist_ok=True)
        with open(project / "index.html", "a") as f:
            f.write(f'<a href="{whl.as_uri()}">{whl.name}</a>\n')
    return root.as_uri()


# gsplat's sdist as cuda_build.py builds it, minus nvcc: a build backend that reports what its
# environment holds, prints ninja's "[k/n]" lines, and compiles a real extension module gsplat.csrc
# whose .nv_fatbin section lists TORCH_CUDA_ARCH_LIST's architectures the way nvcc's fat binaries do.
STANDIN_GSPLAT_BACKEND = r'''
import json, os, shutil, struct, subprocess, sysconfig, zipfile

META = "Metadata-Version: 2.1\nName: gsplat\nVersion: 1.5.3\n"
C = """#include <Python.h>
__attribute__((used, section(".nv_fatbin"), aligned(8))) static const unsigned char fatbin[] = {%s};
static struct PyModuleDef def = {PyModuleDef_HEAD_INIT, "csrc", NULL, -1, NULL};
PyMODINIT_FUNC PyInit_csrc(void) { return PyModule_Create(&def); }
"""


def get_requires_for_build_wheel(config_settings=None):
    return []


def fatbin(archs):
    body = b""
    for arch in archs.split(";"):
        sm = int(arch.split("+")[0].replace(".", ""))
        for kind in ((2, 1) if arch.endswith("+PTX") else (2,)):
            head = bytearray(64)
            struct.pack_into("<HHIQ", head, 0, kind, 0x101, 64, 8)
            struct.pack_into("<I", head, 28, sm)
            body += bytes(head) + bytes(8)
    return struct.pack("<IHHQ", 0xBA55ED50, 1, 16, len(body)) + body


def build_wheel(wheel_directory, config_settings=None, metadata_directory=None):
    links = [d for d in os.environ.get("LIBRARY_PATH", "").split(os.pathsep) if d]
    seen = {k: os.environ.get(k) for k in ("CUDA_HOME", "TORCH_CUDA_ARCH_LIST", "MAX_JOBS", "CUDA_PATH")}
    seen["nvcc"], seen["links"] = shutil.which("nvcc"), links
    seen["cudart"] = [os.path.realpath(os.path.join(d, "libcudart.so")) for d in links
                      if os.path.exists(os.path.join(d, "libcudart.so"))]
    print("IGS-STANDIN-BUILD " + json.dumps(seen), flush=True)
    print("[1/2] " + subprocess.run([seen["nvcc"]], capture_output=True, text=True).stdout.strip(), flush=True)
    with open("csrc.c", "w") as f:
        f.write(C % ",".join(str(b) for b in fatbin(seen["TORCH_CUDA_ARCH_LIST"])))
    subprocess.run(["cc", "-shared", "-fPIC", "-I", sysconfig.get_paths()["include"], "csrc.c", "-o", "csrc.so"],
                   check=True)
    print("[2/2] c++ -shared -o csrc.so", flush=True)
    with open("csrc.so", "rb") as f:
        files = {"gsplat/__init__.py": b"", "gsplat/cuda/__init__.py": b"",
                 "gsplat/cuda/_backend.py": b"from gsplat import csrc as _C\n", "gsplat/csrc.so": f.read(),
                 "gsplat-1.5.3.dist-info/METADATA": META.encode(),
                 "gsplat-1.5.3.dist-info/WHEEL": b"Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: false\n"
                                                 b"Tag: py3-none-any\n"}
    name = "gsplat-1.5.3-py3-none-any.whl"
    with zipfile.ZipFile(os.path.join(wheel_directory, name), "w") as z:
        for n, data in files.items():
            z.writestr(n, data)
        z.writestr("gsplat-1.5.3.dist-info/RECORD", "".join(n + ",,\n" for n in files)
                   + "gsplat-1.5.3.dist-info/RECORD,,\n")
    return name
'''


def make_sdist(folder: Path, name: str, version: str, backend: str) -> Path:
    """A source distribution ``name version`` built by the in-tree PEP 517 ``backend``."""
    top = f"{name}-{version}"
    members = {f"{top}/pyproject.toml": '[build-system]\nrequires = []\nbuild-backend = "standin_backend"\n'
                                        'backend-path = ["."]\n',
               f"{top}/PKG-INFO": f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n",
               f"{top}/standin_backend.py": backend}
    path = folder / f"{top}.tar.gz"
    with tarfile.open(path, "w:gz") as tar:
        for member, text in members.items():
            data = text.encode()
            info = tarfile.TarInfo(member)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return path


@pytest.fixture(scope="module")
def wheelhouses(tmp_path_factory) -> dict[str, Path]:
    """Stand-ins for the real pins of this Python only (asking for another Python's pin is a pip
    error), in three folders: the rest, the CPU torch, a CUDA torch (it requires an nvidia-* package,
    as PyPI's does) with gsplat."""
    folders = {k: tmp_path_factory.mktemp(k) for k in ("rest", "cpu_torch", "cuda")}
    for name, version in names(wanted_reqs(f"{sys.version_info.major}.{sys.version_info.minor}")).items():
        if name != "torch":
            make_wheel(folders["rest"], name, version)
    make_wheel(folders["cpu_torch"], "torch", "2.13.0+cpu", TORCH_CPU)
    make_wheel(folders["cuda"], "torch", "2.13.0", TORCH_CUDA, ("nvidia-cuda-runtime==13.0.96", "cuda-toolkit==13.0.3"))
    make_wheel(folders["cuda"], "nvidia-cuda-runtime", "13.0.96")
    make_wheel(folders["cuda"], "gsplat", "1.5.3")  # PyPI's wheel: pure Python, no kernels
    # NVIDIA's compiler as cuda_build.py asks for it: cuda-toolkit[cccl,nvcc]==13.0.3 and ninja.
    make_wheel(folders["cuda"], "cuda-toolkit", "13.0.3", extras=("cccl", "nvcc"),
               requires=("nvidia-cuda-nvcc==13.0.88; extra == 'nvcc'", "nvidia-cuda-cccl==13.0.85; extra == 'cccl'"))
    make_wheel(folders["cuda"], "nvidia-cuda-nvcc", "13.0.88",
               files={"nvidia/cu13/bin/nvcc": "#!/bin/sh\necho stand-in nvcc\n", "nvidia/cu13/lib/libcudart.so.13": ""})
    make_wheel(folders["cuda"], "nvidia-cuda-cccl", "13.0.85", files={"nvidia/cu13/include/cccl/cub.h": ""})
    make_wheel(folders["cuda"], "ninja", cuda_build.NINJA.split("==")[1])
    make_wheel(folders["cuda"], "packaging", "26.4")  # gsplat imports it without declaring it
    make_sdist(folders["cuda"], "gsplat", "1.5.3", STANDIN_GSPLAT_BACKEND)
    return folders


def local_pip(job: BackendJob, *pip_args: str) -> BackendJob:
    """Make every pip run of ``job`` see only ``pip_args`` (no pip config, no PIP_* variables)."""
    job.argv += [f"--pip-arg={a}" for a in pip_args]
    job.env = {k: v for k, v in (job.env or os.environ).items() if not k.startswith("PIP_")}
    job.env["PIP_CONFIG_FILE"] = os.devnull
    return job


def logs(job: BackendJob) -> str:
    """Every log event of a finished job, from its full log file (the job state keeps the last 50)."""
    events = (parse_event(line) for line in job.log_path.read_text(encoding="utf-8").splitlines())
    return "\n".join(e["message"] for e in events if e and e["event"] == "log")


def pip_commands(job: BackendJob) -> list[str]:
    return [line for line in logs(job).splitlines() if line.startswith("$ ")]


@pytest.mark.skipif(not (shutil.which("cc") and shutil.which("g++")), reason="the stand-in gsplat build needs a C compiler")
def test_setup_env_installs_its_pythons_set_torch_first_and_switches_the_build(wheelhouses, tmp_path):
    env_dir = tmp_path / "venv"
    # torch from its own index (the only one that has it), the rest from another index.
    torch_index, rest_index = simple_index(wheelhouses["cpu_torch"]), simple_index(wheelhouses["rest"])
    job = backend_env.setup_job(PYTHON, env_dir, root=str(ROOT), device="cpu", torch_index=torch_index)
    local_pip(job, f"--index-url={rest_index}").start()
    assert job.wait(timeout=300) == 0, job.report() + logs(job)[-3000:]
    python = backend_env.venv_python(env_dir)
    assert job.state.outputs == [("interpreter", str(python))]
    installs = [c for c in pip_commands(job) if " install " in c]
    wanted = wanted_reqs(f"{sys.version_info.major}.{sys.version_info.minor}")
    assert len(installs) == 2 and installs[0].endswith(f" --index-url {torch_index} torch==2.13.0")
    assert installs[1].split()[-len(wanted) + 1:] == [r for r in wanted if not r.startswith("torch")]
    assert torch_index not in installs[1]
    assert f"not for Python {sys.version.split()[0]}: " in logs(job) and "torch 2.13.0+cpu: CPU build" in logs(job)

    check = backend_env.check_job(str(python), str(ROOT), device="cpu").start()
    assert check.wait(timeout=120) == 0, check.report()
    ok, lines = backend_env.env_report_lines(check)
    assert f"All {len(wanted)} pinned packages present" in lines and "torch 2.13.0+cpu: CPU-only build" in lines
    assert not ok and lines[0].startswith("backend does not import: ")  # the stand-ins are empty modules
    check = backend_env.check_job(str(python), str(ROOT), device="cuda").start()
    assert check.wait(timeout=120) == 0, check.report()
    ok, lines = backend_env.env_report_lines(check)
    assert lines[0] == f"gsplat missing and torch 2.13.0+cpu is a CPU-only build where the Device is NVIDIA CUDA: {FIX}"

    # NVIDIA CUDA on the same environment: pip alone would keep 2.13.0+cpu (it matches ==2.13.0). Then
    # cuda_build.py: the compiler's stand-ins, gsplat's stand-in sdist built, a system nvcc on PATH unused.
    system_bin = tmp_path / "usr-local-cuda" / "bin"
    system_bin.mkdir(parents=True)
    (system_bin / "nvcc").write_text("#!/bin/sh\necho system nvcc\n")
    (system_bin / "nvcc").chmod(0o755)
    job = backend_env.setup_job(PYTHON, env_dir, root=str(ROOT), device="cuda", torch_index=torch_index,
                                cuda_archs="8.0;8.9;9.0+PTX")
    local_pip(job, "--no-index", f"--find-links={wheelhouses['cuda']}", f"--find-links={wheelhouses['rest']}")
    job.env["PATH"] = os.pathsep.join([str(system_bin), job.env.get("PATH", "")])
    job.env.pop("MAX_JOBS", None)
    job.start()
    assert job.wait(timeout=300) == 0, job.report() + logs(job)[-3000:]
    assert "torch 2.13.0+cpu is a CPU-only build, not the one for device 'cuda': replacing it" in logs(job)
    commands = pip_commands(job)
    assert " uninstall --yes torch" in commands[0] and commands[1].endswith(" torch==2.13.0")
    assert torch_index not in commands[1], "the CPU index is for the CPU build only"
    assert commands[2].endswith(" gsplat==1.5.3") and "torch 2.13.0: CUDA build" in logs(job)
    assert commands[3].endswith(" cuda-toolkit[cccl,nvcc]==13.0.3 " + cuda_build.NINJA)
    assert " wheel -v " in commands[4] and "--no-binary gsplat" in commands[4] and "--no-build-isolation" in commands[4]
    assert "--force-reinstall" in commands[5] and commands[5].endswith("gsplat-1.5.3-py3-none-any.whl")
    assert "no GPU visible: building for sm_80, sm_89, sm_90 (+PTX compute_90) (CUDA Architectures)" in logs(job)
    seen = json.loads(next(line for line in logs(job).splitlines() if line.strip().startswith("IGS-STANDIN-BUILD "))
                      .strip().split(" ", 1)[1])  # pip -v indents the build's output
    site = Path(subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    home = site / "nvidia" / "cu13"
    assert seen["CUDA_HOME"] == str(home) and seen["nvcc"] == str(home / "bin" / "nvcc") and seen["CUDA_PATH"] is None
    assert seen["TORCH_CUDA_ARCH_LIST"] == "8.0;8.9;9.0+PTX" and int(seen["MAX_JOBS"]) >= 1
    assert seen["cudart"] == [str(home / "lib" / "libcudart.so.13")]
    assert "[1/2] stand-in nvcc" in logs(job)
    kernels = job.state.stages[cuda_build.STAGE]
    assert (kernels.step, kernels.total, kernels.state) == (2, 2, "done")
    assert any(line.startswith("gsplat built for sm_80, sm_89, sm_90 (+PTX compute_90) in ") for line in logs(job).splitlines())
    assert not os.path.exists(seen["links"][0]), "the build's libcudart.so link was temporary"
    assert (site / "gsplat" / "csrc.so").is_file()

    check = backend_env.check_job(str(python), str(ROOT), device="cuda").start()
    assert check.wait(timeout=120) == 0, check.report()
    ok, lines = backend_env.env_report_lines(check)
    assert not ok and lines[0].startswith("CUDA is not usable (Found no NVIDIA driver on your system): install")
    assert "torch 2.13.0: CUDA 13.0 build, CUDA not usable: Found no NVIDIA driver on your system" in lines
    assert "gsplat built for sm_80, sm_89, sm_90 (+PTX compute_90)" in lines  # read from the module, which loads
    assert f"CUDA compiler: {home / 'bin' / 'nvcc'}" in lines

    # Again with the same architectures: the build that loads is kept, nothing is compiled.
    again = backend_env.setup_job(PYTHON, env_dir, root=str(ROOT), device="cuda", cuda_archs="8.0;8.9;9.0+PTX")
    local_pip(again, "--no-index", f"--find-links={wheelhouses['cuda']}", f"--find-links={wheelhouses['rest']}").start()
    assert again.wait(timeout=300) == 0, again.report() + logs(again)[-3000:]
    assert "gsplat's kernels are already built for sm_80, sm_89, sm_90 (+PTX compute_90) and load: kept" in logs(again)
    assert not any(" wheel " in c or "cuda-toolkit" in c for c in pip_commands(again))


def run_setup(*args: str) -> BackendJob:
    job = BackendJob(backend_env.script_argv(PYTHON, "setup_env.py", list(args)), "Create backend environment").start()
    job.wait(timeout=120)
    return job


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="the messages below are written for Python 3.11")
def test_setup_env_refuses_an_unsupported_python_and_folders_it_must_not_touch(tmp_path):
    pins = json.dumps(PINS)
    job = run_setup("--venv", str(tmp_path / "a"), "--requirements-json", pins, "--requires-python", ">=3.12")
    assert job.returncode == 2 and not (tmp_path / "a").exists()
    assert job.state.error == ("Python 3.11 is not supported (requires-python >=3.12): choose a Python 3.12 or later "
                               "as Base Python")
    home = tmp_path / "home"
    (home / "notes.txt").parent.mkdir()
    (home / "notes.txt").write_text("mine")
    job = run_setup("--venv", str(home), "--requirements-json", pins, "--requires-python", REQUIRES)
    assert job.returncode == 2 and "is not a Python environment (no pyvenv.cfg)" in job.state.error
    assert sorted(p.name for p in home.iterdir()) == ["notes.txt"]
    other = tmp_path / "venv313"
    other.mkdir()
    (other / "pyvenv.cfg").write_text("home = /usr/bin\nversion = 3.13.1\n")
    job = run_setup("--venv", str(other), "--requirements-json", pins, "--requires-python", REQUIRES)
    assert job.returncode == 2 and job.state.error == (f"{other} is a Python 3.13 environment but the Base Python is "
                                                       "3.11: delete that folder or choose another Environment Folder")


def test_setup_job_argv_carries_the_device_index_and_requires_python(tmp_path):
    def args(job: BackendJob) -> list[str]:
        return job.argv[job.argv.index(str(backend_env.SCRIPTS / "setup_env.py")) + 1:]

    url = backend_env.CPU_TORCH_INDEX
    cpu = args(backend_env.setup_job(PYTHON, tmp_path, root=str(ROOT), device="CPU", torch_index=url))
    assert cpu[cpu.index("--device") + 1] == "cpu" and cpu[cpu.index("--torch-index") + 1] == url
    assert cpu[cpu.index("--requires-python") + 1] == REQUIRES
    assert json.loads(cpu[cpu.index("--requirements-json") + 1]) == PINS
    cuda = args(backend_env.setup_job(PYTHON, tmp_path, root=str(ROOT), device="CUDA", torch_index=url))
    assert cuda[cuda.index("--device") + 1] == "cuda" and "--torch-index" not in cuda
    assert "--torch-index" not in args(backend_env.setup_job(PYTHON, tmp_path, root=str(ROOT), torch_index=" "))
    no_bpy = args(backend_env.setup_job(PYTHON, tmp_path, include_bpy=False, root=str(ROOT)))
    assert not any(r.startswith("bpy") for r in json.loads(no_bpy[no_bpy.index("--requirements-json") + 1]))
    with pytest.raises(UserError, match="Base Python .*nope.*not found"):
        backend_env.setup_job(str(tmp_path / "nope"), tmp_path, root=str(ROOT))
    with pytest.raises(UserError, match="unknown device 'tpu'"):
        backend_env.setup_job(PYTHON, tmp_path, root=str(ROOT), device="TPU")
