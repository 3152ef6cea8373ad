"""The pieces of the NVIDIA CUDA set-up's kernel build (igs_blender/env/cuda_build.py), and check_env.py's
reader of the architectures a built module holds.

Fast and offline: the compiler's pins are chosen from the real torch's metadata where this
environment has it (PyPI's torch 2.13.0 pins cuda-toolkit 13.0.3) and from made-up ones; the
architecture lists go through the parser; the fat-binary reader reads ELF files written here byte
by byte, laid out as nvcc lays out its ``.nv_fatbin`` section. The set-up itself, with stand-in
wheels and a stand-in gsplat sdist, is in test_backend_env.py; the real build (NVIDIA's compiler,
gsplat's sdist, minutes) is ``./dev.sh gsplat-build``.
"""

from __future__ import annotations

import importlib.metadata as md
import os
import struct
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

from intrinsic_splats.igs_blender.env import backend_env, check_env, cuda_build  # noqa: E402
from intrinsic_splats.igs_blender.errors import UserError  # noqa: E402

from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)

# -- the compiler's pins from torch's CUDA release ----------------------------------------------------

TORCH_213_REQUIRES = [  # PyPI's torch 2.13.0 for Linux, as its metadata lists them
    "filelock", "setuptools>=77.0.3",
    'cuda-toolkit[cublas,cudart,cufft,cufile,cupti,curand,cusolver,cusparse,nvjitlink,nvrtc,nvtx]==13.0.3; '
    'platform_system == "Linux"',
    'nvidia-cudnn-cu13==9.20.0.48; platform_system == "Linux"', 'triton==3.7.1; platform_system == "Linux"']


def test_the_compiler_comes_from_the_cuda_toolkit_release_torch_pins():
    assert cuda_build.compiler_requirements("2.13.0", "13.0", TORCH_213_REQUIRES) == [
        "cuda-toolkit[cccl,nvcc]==13.0.3", cuda_build.NINJA]
    # Without a cuda-toolkit pin: the release of torch.version.cuda.
    assert cuda_build.compiler_requirements("2.13.1", "13.2", ["nvidia-cuda-runtime==13.2.51"])[0] == \
        "cuda-toolkit[cccl,nvcc]==13.2.*"
    with pytest.raises(ValueError, match=r"torch 2.13.0\+cpu is a CPU-only build"):
        cuda_build.compiler_requirements("2.13.0+cpu", None, [])
    with pytest.raises(ValueError, match="built with CUDA 12.8; the compiler set-up is for torch's CUDA 13"):
        cuda_build.compiler_requirements("2.9.0", "12.8", ["nvidia-cuda-runtime-cu12==12.8.90"])
    assert cuda_build.cuda_home("/env/site", "13.0") == os.path.join("/env/site", "nvidia", "cu13")


def _installed(name: str) -> md.Distribution | None:
    try:
        return md.distribution(name)
    except md.PackageNotFoundError:
        return None


@pytest.mark.skipif(_installed("cuda-toolkit") is None, reason="this environment's torch is not PyPI's CUDA build")
def test_with_this_environments_torch_the_compiler_matches_its_cuda_libraries():
    torch = md.distribution("torch")
    import torch as torch_module

    reqs = cuda_build.compiler_requirements(torch.version, torch_module.version.cuda, list(torch.requires or []))
    toolkit = md.distribution("cuda-toolkit")
    assert reqs[0].startswith("cuda-toolkit[cccl,nvcc]==")
    assert check_env.version_matches(toolkit.version, reqs[0].split("]", 1)[1])  # the release torch was installed with
    # The metapackage's nvcc extra pins nvcc at the release of the CUDA runtime torch runs on.
    nvcc_extra = [r for r in toolkit.requires or [] if "extra == 'nvcc'" in r or 'extra == "nvcc"' in r]
    pinned = dict(r.split(";")[0].strip().split("==") for r in nvcc_extra)
    assert {"nvidia-cuda-nvcc", "nvidia-cuda-crt", "nvidia-nvvm", "nvidia-cuda-runtime"} <= set(pinned)
    runtime = md.version("nvidia-cuda-runtime")
    assert runtime.startswith(pinned["nvidia-cuda-runtime"].rstrip(".*"))
    assert pinned["nvidia-cuda-nvcc"].split(".")[:2] == torch_module.version.cuda.split(".")[:2]


# -- architectures -------------------------------------------------------------------------------------


def test_architecture_lists_parse_normalise_and_name_a_bad_entry():
    assert cuda_build.parse_archs("8.0;8.9;9.0") == ["8.0", "8.9", "9.0"]
    assert cuda_build.parse_archs(" 9.0, sm_80 86  8.9+ptx 120 8.0+PTX") == ["8.0+PTX", "8.6", "8.9+PTX", "9.0",
                                                                            "12.0"]
    assert cuda_build.parse_archs(cuda_build.DEFAULT_ARCHS) == ["8.0", "8.6", "8.9", "9.0+PTX"]
    assert cuda_build.sm_numbers(["8.0", "8.9", "9.0+PTX"]) == ([80, 89, 90], [90])
    for bad, message in (("8.5", "'8.5' is not an architecture CUDA 13's compiler builds for"),
                         ("7.0", "'7.0' is not an architecture"), ("sm80a", "'sm80a' is not a CUDA architecture"),
                         ("8.0;ampere", "'ampere' is not a CUDA architecture"), (" ; ", "no CUDA architecture given")):
        with pytest.raises(ValueError, match=message):
            cuda_build.parse_archs(bad)


def test_the_gpus_present_choose_the_architectures_else_the_list():
    fallback = cuda_build.parse_archs(cuda_build.DEFAULT_ARCHS)
    assert cuda_build.archs_for_gpus([], fallback) == fallback
    assert cuda_build.archs_for_gpus(["8.9"], fallback) == ["8.9"]
    assert cuda_build.archs_for_gpus(["9.0", "8.6", "9.0"], fallback) == ["8.6", "9.0"]
    assert cuda_build.archs_for_gpus(["12.2"], fallback) == ["12.1"]  # same major: its machine code runs
    assert cuda_build.archs_for_gpus(["13.0"], fallback) == ["12.1+PTX"]  # newer: the driver compiles PTX
    with pytest.raises(ValueError, match=r"compute capability 7.0\) is older than CUDA 13 supports"):
        cuda_build.archs_for_gpus(["7.0"], fallback)


def test_the_preference_is_checked_before_the_setup_runs(tmp_path):
    job = backend_env.setup_job(sys.executable, tmp_path, root=str(ROOT), device="CUDA", cuda_archs="sm_86, 9.0")
    args = job.argv[job.argv.index(str(backend_env.SCRIPTS / "setup_env.py")) + 1:]
    assert args[args.index("--cuda-archs") + 1] == "8.6;9.0" and job.state.expected_stages == 2
    cpu = backend_env.setup_job(sys.executable, tmp_path, root=str(ROOT), device="CPU", cuda_archs="nonsense")
    assert "--cuda-archs" not in cpu.argv
    with pytest.raises(UserError, match="CUDA Architectures: '8.5' is not an architecture"):
        backend_env.setup_job(sys.executable, tmp_path, root=str(ROOT), device="CUDA", cuda_archs="8.0;8.5")


# -- the build's environment ----------------------------------------------------------------------------


def test_the_build_sees_the_wheels_compiler_and_no_other_toolkit(tmp_path):
    system = tmp_path / "cuda-13.0" / "bin"
    system.mkdir(parents=True)
    (system / "nvcc").write_text("#!/bin/sh\n")
    tools = tmp_path / "tools"
    tools.mkdir()
    base = {"PATH": os.pathsep.join([str(system), str(tools), "/usr/bin"]), "CUDA_PATH": "/usr/local/cuda",
            "CUDA_INC_PATH": "/usr/local/cuda/include", "TORCH_CUDA_ARCH_LIST": "7.5", "HOME": "/home/a",
            "LIBRARY_PATH": "/opt/lib"}
    env = cuda_build.build_environ(base, "/env/site/nvidia/cu13", "/env/bin", ["8.0", "9.0+PTX"], 3, "/tmp/links")
    assert env["PATH"].split(os.pathsep) == ["/env/bin", "/env/site/nvidia/cu13/bin", str(tools), "/usr/bin"]
    assert env["CUDA_HOME"] == "/env/site/nvidia/cu13" and env["TORCH_CUDA_ARCH_LIST"] == "8.0;9.0+PTX"
    assert env["MAX_JOBS"] == "3" and env["LIBRARY_PATH"] == os.pathsep.join(["/tmp/links", "/opt/lib"])
    assert "CUDA_PATH" not in env and "CUDA_INC_PATH" not in env and env["HOME"] == "/home/a"
    assert base["PATH"].startswith(str(system)), "the caller's environment is left as it was"


def test_ninja_lines_are_the_progress_and_jobs_follow_cpus_and_memory(monkeypatch):
    assert cuda_build.ninja_step("[3/29] /env/nvidia/cu13/bin/nvcc -c a.cu") == (3, 29)
    assert cuda_build.ninja_step("  [29/29] c++ -shared -o csrc.so") == (29, 29)
    assert cuda_build.ninja_step("Building wheel for gsplat (pyproject.toml): started") is None
    monkeypatch.delenv("MAX_JOBS", raising=False)
    assert cuda_build.build_jobs(16, 128.0) == 16 and cuda_build.build_jobs(16, 9.5) == 4
    assert cuda_build.build_jobs(2, 1.0) == 1
    monkeypatch.setenv("MAX_JOBS", "5")
    assert cuda_build.build_jobs(16, 128.0) == 5


def test_a_missing_compiler_or_python_headers_is_one_line_with_the_fix(tmp_path):
    assert cuda_build.host_compiler_problem(path=str(tmp_path)).startswith(
        "gsplat's kernels need a C++ compiler (g++) for their host code and none is on PATH: install it")
    assert cuda_build.python_headers_problem("/usr/include/python3.11", True) == ""
    assert "Python's headers are missing (/usr/include/python3.11/Python.h)" in \
        cuda_build.python_headers_problem("/usr/include/python3.11", False)


# -- reading the architectures back from a built module ------------------------------------------------


def fatbin(entries: list[tuple[int, int]]) -> bytes:
    """One fat binary as nvcc writes it: (kind 1 = PTX / 2 = machine code, SM version) per entry, each
    a 64-byte header and an 8-byte payload."""
    body = b""
    for kind, sm in entries:
        head = bytearray(64)
        struct.pack_into("<HHIQ", head, 0, kind, 0x101, 64, 8)
        struct.pack_into("<I", head, 28, sm)
        body += bytes(head) + b"\xab" * 8
    return struct.pack("<IHHQ", 0xBA55ED50, 1, 16, len(body)) + body


def elf(sections: dict[str, bytes]) -> bytes:
    """A 64-bit little-endian ELF file with these sections (and the section-name table)."""
    names = b"\0" + b"".join(n.encode() + b"\0" for n in [*sections, ".shstrtab"])
    data, offsets = b"", []
    for blob in [*sections.values(), names]:
        offsets.append(64 + len(data))
        data += blob + b"\0" * (-len(blob) % 8)
    shoff, count = 64 + len(data), len(sections) + 2
    head = bytearray(64)
    head[:6] = b"\x7fELF\x02\x01"
    struct.pack_into("<Q", head, 0x28, shoff)
    struct.pack_into("<HHH", head, 0x3A, 64, count, count - 1)
    table = bytes(64)  # the null section
    for i, (name, blob) in enumerate([*sections.items(), (".shstrtab", names)]):
        table += struct.pack("<IIQQQQ", names.index(name.encode() + b"\0"), 1, 0, 0, offsets[i], len(blob)) + bytes(24)
    return bytes(head) + data + table


def test_the_architectures_are_read_from_the_modules_fat_binaries(tmp_path):
    one = fatbin([(2, 80), (2, 89), (2, 90), (1, 90)])
    two = fatbin([(2, 80), (2, 89), (2, 90), (1, 90)])
    module = tmp_path / "csrc.so"
    module.write_bytes(elf({".text": b"\x90" * 40, ".nv_fatbin": one + b"\0" * 8 + two}))
    section = check_env.elf_section(str(module), ".nv_fatbin")
    assert check_env.fatbin_archs(section) == ([80, 89, 90], [90])
    assert check_env.arch_text([80, 89, 90], [90]) == "sm_80, sm_89, sm_90 (+PTX compute_90)"
    assert check_env.elf_section(str(module), ".nv_relfatbin") is None
    plain = tmp_path / "plain.so"
    plain.write_bytes(elf({".text": b"\x90"}))
    assert check_env.elf_section(str(plain), ".nv_fatbin") is None and check_env.fatbin_archs(b"") == ([], [])
    (tmp_path / "text.so").write_text("not an ELF")
    with pytest.raises(ValueError, match="not a 64-bit little-endian ELF"):
        check_env.elf_section(str(tmp_path / "text.so"), ".nv_fatbin")


def test_machine_code_runs_on_its_major_version_and_ptx_on_anything_newer():
    sm, ptx = [80, 89, 90], [90]
    assert check_env.runs_on(86, sm, ptx) and check_env.runs_on(89, sm, ptx) and check_env.runs_on(90, sm, ptx)
    assert check_env.runs_on(120, sm, ptx)  # through the PTX
    assert not check_env.runs_on(75, sm, ptx) and not check_env.runs_on(120, sm, [])
    assert not check_env.runs_on(86, [89], []) and check_env.runs_on(89, [86], [])
