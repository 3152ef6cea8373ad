"""Build gsplat's CUDA kernels into a backend environment with NVIDIA's compiler wheels (no CUDA toolkit).

Run by the add-on's set-up (setup_env.py loads this file for the NVIDIA CUDA device), or on its own
for an environment that already has torch's CUDA build::

    python cuda_build.py --python ENV/bin/python [--cuda-archs "8.0;8.6;8.9;9.0+PTX"] [--pip-arg ARG ...]
        [--events]
    python cuda_build.py --python ENV/bin/python --print-requirements     (what it installs, one a line)

Standard library only. In the environment of ``--python``:

1. NVIDIA's compiler and headers from PyPI: ``cuda-toolkit[nvcc,cccl]`` at the version torch's own
   metadata pins (torch 2.13.0: cuda-toolkit 13.0.3, i.e. nvidia-cuda-nvcc and -crt 13.0.88,
   nvidia-nvvm 13.0.88, nvidia-cuda-cccl 13.0.85, nvidia-cuda-runtime 13.0.96), else the release of
   ``torch.version.cuda`` (13.0.*); and ninja. They install under site-packages/nvidia/cu13 (bin/nvcc,
   nvvm/, include/), a CUDA_HOME of its own.
2. gsplat's sdist is built into a wheel (``pip wheel --no-binary gsplat --no-build-isolation``: its
   setup.py compiles the ``gsplat.csrc`` extension against the installed torch), with CUDA_HOME,
   TORCH_CUDA_ARCH_LIST, MAX_JOBS, PATH and LIBRARY_PATH set for that subprocess only: a system
   toolkit is neither used nor changed, and nothing is written outside the environment except pip's
   temporary build folder. Ninja's ``[k/n]`` lines become progress.
3. The wheel replaces the installed gsplat; the module is loaded by its path, its architectures are
   read back from it (check_env.py's reader), and then it is imported the way gsplat's rasterizer
   imports it at run time (``gsplat.cuda._backend._C``, no environment variables).

An installed build that loads and already holds the architectures is kept (no download, no build).

Architectures: those of the GPUs torch sees, else ``--cuda-archs`` (default DEFAULT_ARCHS). A host
C++ compiler (g++) and Python's headers are needed, as for any C++ extension. Speaks the backend's
JSON-lines events with ``--events``; otherwise prints progress lines and keeps pip's output in
ENV/igs-gsplat-build.log. Exit codes: 0 ok, 2 failed, 130 cancelled.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

STAGE = "gsplat kernels"
COMPILER_EXTRAS = "cccl,nvcc"  # cuda-toolkit's extras: nvcc brings crt, nvvm and the runtime's headers
NINJA = "ninja==1.13.2"  # torch's extension builder runs the compiles in parallel with it
UNDECLARED = ("packaging",)
"""What gsplat 1.5.3 imports at run time without declaring it (gsplat/cuda/_backend.py: packaging)."""
DEFAULT_ARCHS = "8.0;8.6;8.9;9.0+PTX"
"""When no GPU is visible: A100, RTX 30xx, RTX 40xx/L4/L40, H100/H200 machine code; compute_90 PTX
that the driver compiles for newer GPUs (RTX 50xx, B200) on first use."""
SUPPORTED_ARCHS = ("7.5", "8.0", "8.6", "8.7", "8.9", "9.0", "10.0", "10.3", "11.0", "12.0", "12.1")
"""What CUDA 13's nvcc and torch's TORCH_CUDA_ARCH_LIST both accept (CUDA 13 dropped everything before Turing)."""
LOG_NAME = "igs-gsplat-build.log"


def load_check_env():
    """check_env.py from this script's folder (it is run by path; this folder is not on sys.path)."""
    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "check_env.py")
    spec = importlib.util.spec_from_file_location("igs_check_env", path)
    if spec is None or spec.loader is None:
        raise RuntimeError(f"{path}: missing; reinstall the extension")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


try:
    from . import check_env  # the add-on's package (backend_env validates the preference with this file)
except ImportError:  # run by path, or loaded by setup_env.py
    check_env = load_check_env()
GSPLAT = next(r for r in check_env.DEVICE_EXTRAS["cuda"] if r.startswith("gsplat"))


# -- architectures ---------------------------------------------------------------------------------


def _key(arch: str) -> tuple[int, int]:
    major, minor = arch.split("+")[0].split(".")
    return int(major), int(minor)


def parse_archs(text: str) -> list[str]:
    """"8.0; 8.9,sm_90 120+PTX" -> ["8.0", "8.9", "9.0", "12.0+PTX"] (sorted, one entry per
    architecture, +PTX kept). Raises ValueError naming an entry CUDA 13 cannot build for."""
    out: dict[str, bool] = {}
    for token in filter(None, re.split(r"[;,\s]+", text.strip())):
        m = re.fullmatch(r"(?:sm_?)?(\d+)(?:\.(\d+))?(\+ptx)?", token, re.I)
        if not m:
            raise ValueError(f"'{token}' is not a CUDA architecture (write them as 8.6, 86 or sm_86, "
                             "separated by ';')")
        digits, minor, ptx = m.groups()
        arch = f"{int(digits)}.{int(minor)}" if minor is not None else f"{int(digits[:-1] or 0)}.{digits[-1]}"
        if arch not in SUPPORTED_ARCHS:
            raise ValueError(f"'{token}' is not an architecture CUDA 13's compiler builds for "
                             f"(one of {', '.join(SUPPORTED_ARCHS)})")
        out[arch] = out.get(arch, False) or bool(ptx)
    if not out:
        raise ValueError("no CUDA architecture given (for example 8.6, or 8.0;8.9;9.0)")
    return [a + ("+PTX" if ptx else "") for a, ptx in sorted(out.items(), key=lambda kv: _key(kv[0]))]


def archs_for_gpus(capabilities: list[str], fallback: list[str]) -> list[str]:
    """The architectures to build: one per visible GPU ("8.9"), else ``fallback``. A GPU newer than
    the compiler knows gets the newest machine code of its major version, or the newest PTX."""
    if not capabilities:
        return fallback
    out = []
    for cap in capabilities:
        same_major = [a for a in SUPPORTED_ARCHS if _key(a)[0] == _key(cap)[0] and _key(a) <= _key(cap)]
        if same_major:
            arch = same_major[-1]
        elif _key(cap) > _key(SUPPORTED_ARCHS[-1]):
            arch = SUPPORTED_ARCHS[-1] + "+PTX"
        else:
            raise ValueError(f"this GPU (compute capability {cap}) is older than CUDA 13 supports "
                             f"({SUPPORTED_ARCHS[0]} and newer): choose CPU as Device")
        if arch not in out:
            out.append(arch)
    return parse_archs(";".join(out))


def sm_numbers(archs: list[str]) -> tuple[list[int], list[int]]:
    """(["8.0", "9.0+PTX"]) -> ([80, 90], [90]): the machine code and PTX the build must contain."""
    sm = [10 * _key(a)[0] + _key(a)[1] for a in archs]
    return sm, [s for s, a in zip(sm, archs) if a.endswith("+PTX")]


# -- the compiler's pins ---------------------------------------------------------------------------


def compiler_requirements(torch_version: str, torch_cuda: str | None, torch_requires: list[str]) -> list[str]:
    """The pip requirements of NVIDIA's compiler and headers matching a torch build: the cuda-toolkit
    version torch's metadata pins (its CUDA libraries come from the same release), else the release of
    ``torch.version.cuda``. Raises ValueError for a CPU build or a CUDA release before 13."""
    if not torch_cuda:
        raise ValueError(f"torch {torch_version} is a CPU-only build: the NVIDIA CUDA device needs torch's "
                         "CUDA build (PyPI's Linux wheel)")
    major = int(torch_cuda.split(".")[0])
    if major < 13:
        raise ValueError(f"torch {torch_version} is built with CUDA {torch_cuda}; the compiler set-up is for "
                         "torch's CUDA 13 builds (the pinned torch from PyPI)")
    for req in torch_requires:
        name, spec, _ = check_env.split_requirement(req)
        if check_env.normal_name(name) == "cuda-toolkit" and re.fullmatch(r"==\s*[0-9.]+", spec):
            return [f"cuda-toolkit[{COMPILER_EXTRAS}]=={spec[2:].strip()}", NINJA]
    release = ".".join(torch_cuda.split(".")[:2])
    return [f"cuda-toolkit[{COMPILER_EXTRAS}]=={release}.*", NINJA]


def cuda_home(purelib: str, torch_cuda: str) -> str:
    """Where NVIDIA's CUDA 13 wheels put bin/, include/, lib/ and nvvm/: a complete CUDA_HOME."""
    return os.path.join(purelib, "nvidia", f"cu{torch_cuda.split('.')[0]}")


# -- the environment ------------------------------------------------------------------------------

_PROBE = r"""
import importlib.metadata as md, json, os, sysconfig
out = {"purelib": sysconfig.get_paths()["purelib"], "bin": sysconfig.get_paths()["scripts"],
       "python_h": os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h")),
       "include": sysconfig.get_paths()["include"],
       "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1,
       "memory_gib": os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
       if hasattr(os, "sysconf") else 0, "torch": None, "cuda": None, "requires": [], "gpus": []}
try:
    dist = md.distribution("torch")
    out["torch"], out["requires"] = dist.version, list(dist.requires or [])
except md.PackageNotFoundError:
    pass
if out["torch"]:
    import torch
    out["torch"], out["cuda"] = str(torch.__version__), torch.version.cuda
    if torch.version.cuda and torch.cuda.is_available():
        for i in range(torch.cuda.device_count()):
            major, minor = torch.cuda.get_device_capability(i)
            out["gpus"].append({"name": torch.cuda.get_device_name(i), "arch": f"{major}.{minor}"})
print("IGS-PROBE " + json.dumps(out))
"""

_KERNELS = r"""
import json, sys
sys.path.insert(0, sys.argv[1])  # check_env.py's folder
import torch  # gsplat.csrc links against torch's libraries
import check_env
print("IGS-KERNELS " + json.dumps(check_env.gsplat_kernels(load=True)))
"""

_VERIFY = r"""
import json, torch
from gsplat.cuda import _backend  # what gsplat's rasterizer imports: the built module, else a JIT build
c = _backend._C
print("IGS-VERIFY " + json.dumps({"name": getattr(c, "__name__", None), "file": getattr(c, "__file__", None)}))
"""


def _run_json(python: str, code: str, tag: str, args: tuple[str, ...] = (), timeout: float = 600):
    """Run ``code`` in ``python``; its line starting with ``tag`` as JSON (RuntimeError with its last line)."""
    res = subprocess.run([python, "-c", code, *args], capture_output=True, text=True, timeout=timeout)
    for line in res.stdout.splitlines():
        if line.startswith(tag + " "):
            return json.loads(line[len(tag) + 1:])
    last = (res.stderr.strip().splitlines() or res.stdout.strip().splitlines() or [f"exit {res.returncode}"])[-1]
    raise RuntimeError(last)


def probe(python: str) -> dict:
    """What the environment of ``python`` has: torch's version, CUDA release and pins, the GPUs'
    compute capabilities, its site-packages, Python headers, CPUs and memory."""
    try:
        return _run_json(python, _PROBE, "IGS-PROBE")
    except (OSError, subprocess.SubprocessError, RuntimeError, ValueError) as e:
        raise RuntimeError(f"{python}: cannot inspect the environment ({e})") from e


def built_kernels(python: str) -> dict | None:
    """check_env.gsplat_kernels(load=True) in the environment of ``python``: the installed gsplat's
    module, its architectures and whether it loads (None: no gsplat). Loads the module by its path,
    never through gsplat's own import, which would start a compile where a module is missing."""
    here = os.path.dirname(os.path.abspath(check_env.__file__))
    try:
        return _run_json(python, _KERNELS, "IGS-KERNELS", (here,))
    except (OSError, subprocess.SubprocessError, RuntimeError, ValueError) as e:
        raise RuntimeError(f"{python}: cannot inspect gsplat's kernels ({e})") from e


def covers(kernels: dict | None, archs: list[str]) -> bool:
    """Whether a loadable build of the pinned gsplat holds every architecture of ``archs``."""
    if not kernels or not kernels["module"] or kernels["error"] or kernels["version"] != GSPLAT.split("==")[-1]:
        return False
    want_sm, want_ptx = sm_numbers(archs)
    return set(want_sm) <= set(kernels["sm"]) and set(want_ptx) <= set(kernels["ptx"])


def host_compiler_problem(path: str | None = None) -> str:
    """'' when a C++ compiler for the kernels' host code is on PATH, else the one-line fix."""
    if shutil.which("g++", path=path) and shutil.which(os.environ.get("CXX") or "c++", path=path):
        return ""
    return ("gsplat's kernels need a C++ compiler (g++) for their host code and none is on PATH: install "
            "it (Debian/Ubuntu: sudo apt install g++; Fedora: sudo dnf install gcc-c++) and run the set-up again")


def python_headers_problem(include_dir: str, has_python_h: bool) -> str:
    if has_python_h:
        return ""
    minor = ".".join(str(v) for v in sys.version_info[:2])
    return (f"Python's headers are missing ({include_dir}/Python.h), and gsplat's kernels are a C++ extension: "
            f"install them (Debian/Ubuntu: sudo apt install python{minor}-dev) or choose another Base Python")


def build_jobs(cpus: int, memory_gib: float) -> int:
    """Parallel compiles: MAX_JOBS when set, else one per CPU and per 2 GiB of memory (a multi-
    architecture nvcc of gsplat's larger kernels takes over 1 GiB)."""
    if os.environ.get("MAX_JOBS", "").isdigit() and int(os.environ["MAX_JOBS"]) > 0:
        return int(os.environ["MAX_JOBS"])
    return max(1, min(cpus, int(memory_gib // 2) if memory_gib else cpus))


def _holds_a_compiler(folder: str) -> bool:
    return any(os.path.isfile(os.path.join(folder, tool)) for tool in ("nvcc", "ptxas", "cicc"))


def build_environ(base: dict[str, str], home: str, env_bin: str, archs: list[str], jobs: int,
                  link_dir: str) -> dict[str, str]:
    """The environment of the build subprocess: CUDA_HOME is the wheels' tree; PATH starts with the
    environment's scripts (ninja) and the wheels' nvcc and leaves out folders holding another nvcc,
    ptxas or cicc (nvcc finds its tools on PATH); LIBRARY_PATH has ``link_dir`` (libcudart.so, which the
    runtime wheel ships only as libcudart.so.13); variables that would add another toolkit's
    headers are dropped."""
    env = {k: v for k, v in base.items() if k not in ("CUDA_PATH", "CUDA_INC_PATH", "CUDNN_HOME", "CUDNN_PATH",
                                                      "BUILD_NO_CUDA", "NVCC_FLAGS", "TORCH_CUDA_ARCH_LIST")}
    kept = [p for p in base.get("PATH", "").split(os.pathsep) if p and not _holds_a_compiler(p)]
    env["PATH"] = os.pathsep.join([env_bin, os.path.join(home, "bin"), *kept])
    env["CUDA_HOME"] = home
    env["TORCH_CUDA_ARCH_LIST"] = ";".join(archs)
    env["MAX_JOBS"] = str(jobs)
    env["LIBRARY_PATH"] = os.pathsep.join(filter(None, [link_dir, base.get("LIBRARY_PATH", "")]))
    env["PYTHONUNBUFFERED"] = "1"
    return env


_NINJA_STEP = re.compile(r"^\s*\[(\d+)/(\d+)\]\s")


def ninja_step(line: str) -> tuple[int, int] | None:
    """(done, total) of a ninja status line "[3/22] nvcc ...", None for any other line."""
    m = _NINJA_STEP.match(line)
    return (int(m.group(1)), int(m.group(2))) if m else None


# -- running it ------------------------------------------------------------------------------------


class Reporter:
    """Events for the add-on (``emit`` given: setup_env's), or lines for a terminal: progress and
    messages on stdout, the tools' output in ``log_path`` only."""

    def __init__(self, emit=None, log_path: str = ""):
        self.emit, self.log_path, self._log = emit, log_path, None

    def __call__(self, event: str, **fields) -> None:
        if self.emit is not None:
            self.emit(event, **fields)
            return
        if event == "log" and fields.get("tool"):
            if self._log is None and self.log_path:
                self._log = open(self.log_path, "a", encoding="utf-8")  # noqa: SIM115 (closed in close())
            if self._log is not None:
                self._log.write(fields["message"] + "\n")
            return
        if event == "progress":
            eta = fields.get("eta_s")
            left = f", about {_duration(eta)} left" if eta is not None else ""
            done = "compiled" if fields["stage"] == STAGE else "done"
            print(f"  {fields['stage']}: {fields['step']}/{fields['total']} {done}{left}", flush=True)
        elif event in ("log", "error", "cancelled"):
            print(("error: " if event == "error" else "") + fields["message"], flush=True)
        elif event == "stage":
            print(f"== {fields['stage']}", flush=True)
        elif event == "output":
            print(f"{fields['kind']}: {fields['path']}", flush=True)
        elif event == "done":
            print(f"done in {_duration(fields['seconds'])}", flush=True)

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"


def run_tool(cmd: list[str], what: str, report: Reporter, env: dict[str, str] | None = None, on_line=None) -> None:
    """Run ``cmd``, its output as tool log lines (and to ``on_line``); RuntimeError naming ``what``
    with the last error line."""
    report("log", message="$ " + " ".join(cmd), tool=True)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1, env=env)
    last_error = ""
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            line = line.rstrip()
            if not line:
                continue
            if re.search(r"\berror\b", line, re.I):
                last_error = line.strip()
            report("log", message=line, tool=True)
            if on_line is not None:
                on_line(line)
        rc = proc.wait()
    finally:
        if proc.poll() is None:  # cancelled: the process group had the SIGINT too; do not leave it behind
            proc.kill()
            proc.wait()
    if rc != 0:
        raise RuntimeError(f"{what} failed (exit {rc})" + (f": {last_error}" if last_error else ""))


def setup_cuda(python: str, fallback_archs: list[str], pip_args: list[str], report: Reporter) -> dict:
    """Install the compiler wheels into the environment of ``python``, build gsplat's kernels there
    and check them; returns the summary (gsplat version, module, archs, seconds, jobs)."""
    t0 = time.perf_counter()
    info = probe(python)
    if not info["torch"]:
        raise RuntimeError(f"{python}: torch is not installed in this environment")
    problem = python_headers_problem(info["include"], info["python_h"]) or host_compiler_problem()
    if problem:
        raise RuntimeError(problem)
    compiler = compiler_requirements(info["torch"], info["cuda"], info["requires"])
    gpus = info["gpus"]
    archs = archs_for_gpus([g["arch"] for g in gpus], fallback_archs)
    target = check_env.arch_text(*sm_numbers(archs))
    if gpus:
        report("log", message=f"building for the GPU here: {', '.join(g['name'] + ' (' + g['arch'] + ')' for g in gpus)}"
                              f" -> {target}")
    else:
        report("log", message=f"no GPU visible: building for {target} (CUDA Architectures)")
    current = built_kernels(python)
    if covers(current, archs):
        assert current is not None
        report("log", message=f"gsplat's kernels are already built for {check_env.arch_text(current['sm'], current['ptx'])}"
                              f" and load: kept ({current['module']})")
        return {"gsplat": current["version"], "module": current["module"], "sm": current["sm"], "ptx": current["ptx"],
                "archs": ";".join(archs), "build_seconds": 0.0, "jobs": 0, "compiler": compiler, "kept": True,
                "seconds": round(time.perf_counter() - t0, 1)}
    pip = [python, "-m", "pip"]
    quiet = ["--disable-pip-version-check", "--progress-bar", "off"]
    report("log", message=f"installing NVIDIA's compiler: {', '.join(compiler)} (about 100 MB)")
    run_tool([*pip, "install", *quiet, *pip_args, *compiler], "installing the compiler", report)
    home = cuda_home(info["purelib"], info["cuda"])
    nvcc = os.path.join(home, "bin", "nvcc")
    cudart = sorted(f for f in os.listdir(os.path.join(home, "lib")) if f.startswith("libcudart.so.")) \
        if os.path.isdir(os.path.join(home, "lib")) else []
    if not os.path.isfile(nvcc) or not cudart:
        raise RuntimeError(f"the compiler wheels left no nvcc or libcudart in {home}")
    jobs = build_jobs(info["cpus"], info["memory_gib"])
    report("log", message=f"building gsplat's kernels from {GSPLAT}'s source with {jobs} parallel "
                          f"compile{'s' if jobs > 1 else ''} (nvcc {home}/bin/nvcc; minutes)")
    t_build = time.perf_counter()
    report("stage", stage=STAGE, total=0)
    with tempfile.TemporaryDirectory(prefix="igs-gsplat-") as tmp:
        link_dir, wheel_dir = os.path.join(tmp, "lib"), os.path.join(tmp, "wheel")
        os.makedirs(link_dir)
        os.symlink(os.path.join(home, "lib", cudart[0]), os.path.join(link_dir, "libcudart.so"))
        env = build_environ(dict(os.environ), home, info["bin"], archs, jobs, link_dir)

        def on_line(line: str) -> None:
            step = ninja_step(line)
            if step:
                done, total = step
                per = (time.perf_counter() - t_build) / done
                report("progress", stage=STAGE, step=done, total=total, eta_s=per * (total - done))

        run_tool([*pip, "wheel", "-v", *quiet, "--no-cache-dir", "--no-deps", "--no-build-isolation",
                  "--no-binary", "gsplat", "-w", wheel_dir, *pip_args, GSPLAT], f"building {GSPLAT}", report,
                 env=env, on_line=on_line)
        wheels = [os.path.join(wheel_dir, f) for f in os.listdir(wheel_dir) if f.startswith("gsplat-")]
        if not wheels:
            raise RuntimeError(f"building {GSPLAT} made no wheel")
        build_s = time.perf_counter() - t_build
        run_tool([*pip, "install", *quiet, "--no-deps", "--force-reinstall", *pip_args, wheels[0]],
                 "installing the built gsplat", report)
        run_tool([*pip, "install", *quiet, *pip_args, wheels[0], *UNDECLARED], "installing gsplat's dependencies",
                 report)
    kernels = built_kernels(python)
    if not kernels or not kernels["module"]:
        raise RuntimeError(f"the built {GSPLAT} has no kernels module (gsplat/csrc)")
    if kernels["error"]:
        raise RuntimeError(f"gsplat's built kernels do not load: {kernels['error']}")
    sm, ptx = kernels["sm"], kernels["ptx"]
    if not covers(kernels, archs):
        raise RuntimeError(f"{kernels['module']} holds {check_env.arch_text(sm, ptx)}, not {target}")
    # The way gsplat's rasterizer finds them at run time, with no variable set (safe now: it loads).
    loaded = _run_json(python, _VERIFY, "IGS-VERIFY")
    same = bool(loaded.get("file")) and os.path.realpath(loaded["file"]) == os.path.realpath(kernels["module"])
    if loaded.get("name") != "gsplat.csrc" or not same:
        raise RuntimeError(f"gsplat imports, but not its built kernels ({loaded})")
    summary = {"gsplat": kernels["version"], "module": loaded["file"], "sm": sm, "ptx": ptx,
               "archs": ";".join(archs), "build_seconds": round(build_s, 1), "jobs": jobs,
               "compiler": compiler, "kept": False, "seconds": round(time.perf_counter() - t0, 1)}
    report("log", message=f"gsplat built for {check_env.arch_text(sm, ptx)} in {_duration(build_s)}: {loaded['file']}")
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--python", required=True, help="the environment's interpreter (with torch's CUDA build)")
    parser.add_argument("--cuda-archs", default=DEFAULT_ARCHS,
                        help=f"architectures to build for when no GPU is visible (default {DEFAULT_ARCHS})")
    parser.add_argument("--pip-arg", action="append", default=[], help="extra argument for every pip run")
    parser.add_argument("--events", action="store_true", help="JSON-lines events on stdout (the add-on's protocol)")
    parser.add_argument("--print-requirements", action="store_true",
                        help="print what is installed besides gsplat (the compiler's pins for this environment's "
                             "torch, ninja, packaging) and exit")
    args = parser.parse_args(argv)
    emit = check_env.emit if args.events else None
    report = Reporter(emit, "" if args.events else os.path.join(os.path.dirname(os.path.dirname(args.python)),
                                                                  LOG_NAME))
    try:
        try:
            archs = parse_archs(args.cuda_archs)
        except ValueError as e:
            raise ValueError(f"--cuda-archs: {e}") from e
        if sys.platform != "linux":
            raise ValueError(f"building gsplat's kernels is set up for Linux only, not {sys.platform}")
        if args.print_requirements:
            info = probe(args.python)
            print("\n".join([*compiler_requirements(info["torch"] or "(none)", info["cuda"], info["requires"]),
                             *UNDECLARED]))
            return 0
        report("start", command="gsplat-build", argv=argv if argv is not None else sys.argv[1:])
        summary = setup_cuda(args.python, archs, args.pip_arg, report)
    except KeyboardInterrupt:
        report("cancelled", message="gsplat build cancelled; the environment keeps its previous gsplat")
        return 130
    except (RuntimeError, ValueError, OSError, subprocess.SubprocessError) as e:
        report("error", message=str(e))
        return 2
    finally:
        report.close()
    if args.events:
        report("result", command="gsplat-build", data=summary)
        report("done", command="gsplat-build", seconds=summary["seconds"])
    else:
        print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
