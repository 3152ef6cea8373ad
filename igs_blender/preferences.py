"""Add-on preferences: the backend interpreter, creating its environment (CPU or CUDA), checking it."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, StringProperty

from .addon_id import ADDON_ID
from .env import backend_env
from .env.backend_env import CPU_TORCH_INDEX
from .env.cuda_build import DEFAULT_ARCHS
from .errors import UserError
from .jobs.client import BackendJob

# Download sizes measured with pip (wheels, Linux x86-64): torch 2.13.0+cpu (cp311) 192 MB and the
# CPU set for Python 3.11 458 MB in all; the CUDA set for Python 3.14 2.96 GB (torch 527 MB, the
# nvidia-*/triton CUDA 13 libraries 2.2 GB, the rest 229 MB); bpy 5.0.1 374 MB (+9 MB of its deps).
# The CUDA device's compiler (cuda_build.py): nvidia-nvvm 61.6 MB, nvidia-cuda-nvcc 37.4 MB,
# nvidia-cuda-cccl 3.1 MB, nvidia-cuda-crt 0.1 MB and ninja 0.2 MB, 102 MB; gsplat's sdist 4.7 MB.
DEVICE_ITEMS = (
    ("CPU", "CPU",
     "CPU-only torch (2.13.0+cpu, 192 MB) from the Torch Package Index; about 0.46 GB of downloads in all "
     "for Python 3.11, plus 0.38 GB for bpy. Training runs on the CPU"),
    ("CUDA", "NVIDIA CUDA",
     "torch from PyPI, whose Linux wheels are the CUDA 13 builds, plus gsplat 1.5.3: about 3 GB of downloads "
     "for Python 3.14 (torch 527 MB, NVIDIA CUDA libraries 2.2 GB). No CUDA toolkit needed: NVIDIA's compiler "
     "comes from PyPI (about 100 MB more) and builds gsplat's kernels during the set-up, for the GPU present "
     "(three architectures took 19 min on 2 CPU cores). Needs an NVIDIA GPU and driver, and a C++ compiler (g++). Linux only"),
)


class IGS_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    backend_python: StringProperty(
        name="Backend Python",
        description="Python interpreter with the backend's dependencies (torch, pycolmap, ...); "
                    "'Create Backend Environment' fills this in",
        subtype="FILE_PATH",
    )
    backend_root: StringProperty(
        name="Backend Sources",
        description="Folder that holds backend/ and igs_contract/ (empty: the copy shipped inside this extension)",
        subtype="DIR_PATH",
    )
    base_python: StringProperty(
        name="Base Python",
        description="Python that creates the environment (empty: Blender's own Python). One that the shipped "
                    "pyproject.toml's requires-python allows; its version picks the pinned set "
                    "(only Python 3.11 has the bpy module)",
        subtype="FILE_PATH",
    )
    env_dir: StringProperty(
        name="Environment Folder",
        description="Where 'Create Backend Environment' puts the virtual environment "
                    "(empty: this extension's user folder)",
        subtype="DIR_PATH",
    )
    device: EnumProperty(
        name="Device",
        description="Which torch build 'Create Backend Environment' installs, and what 'Check Backend' expects",
        items=DEVICE_ITEMS,
        default="CPU",
    )
    cuda_archs: StringProperty(
        name="CUDA Architectures",
        description="NVIDIA CUDA: the GPU architectures 'Create Backend Environment' builds gsplat's kernels for "
                    "when it sees no GPU (with a GPU, its own). Compute capabilities separated by ';' "
                    "(8.6 = RTX 30xx, 8.9 = RTX 40xx, 9.0 = H100; +PTX adds code newer GPUs compile on first use). "
                    "Each one adds minutes to the build",
        default=DEFAULT_ARCHS,
    )
    torch_index: StringProperty(
        name="Torch Package Index",
        description="Package index torch alone comes from when the Device is CPU (PyTorch's CPU-only wheels "
                    "and their dependencies); empty: PyPI, whose Linux torch is the CUDA build (~2.7 GB)",
        default=CPU_TORCH_INDEX,
    )
    include_bpy: BoolProperty(
        name="Include bpy (Python 3.11 and 3.13)",
        description="Also install the bpy module in the backend environment, to render synthetic demo "
                    "captures: Blender 5.3.0 on Python 3.13 (408 MB), 5.0.1 on Python 3.11 (383 MB); none "
                    "exists for other Pythons",
        default=True,
    )
    native_splats: BoolProperty(
        name="Native Splats (Blender 5.3+)",
        description="Load layers as Blender's own Gaussian splats, which EEVEE and Cycles render (F12 renders "
                    "A x S + R through a compositor group). Off: point clouds drawn by the add-on's viewport "
                    "splats, rendered by the backend, as on Blender 4.2-5.2",
        default=True,
    )
    check_report: StringProperty(name="Check Report", default="")
    check_ok: BoolProperty(default=False)

    def draw(self, context):
        layout = self.layout
        col = layout.column()
        col.prop(self, "backend_python")
        col.row().prop(self, "device", expand=True)
        row = col.row(align=True)
        row.operator("igs.create_backend_env", icon="CONSOLE")
        row.operator("igs.check_backend", icon="CHECKMARK")
        box = layout.box()
        if self.check_report:
            for i, line in enumerate(self.check_report.splitlines()):
                icon = ("CHECKMARK" if self.check_ok else "ERROR") if i == 0 else "BLANK1"
                box.label(text=line, icon=icon)
        else:
            box.label(text="Not checked yet", icon="QUESTION")
        from . import jobs

        job = jobs.current()
        if job is not None and job.running:
            box.progress(factor=job.state.fraction, text=job.state.status_text())
            box.operator("igs.cancel_job", icon="CANCEL")
        adv = layout.column(heading="Advanced")
        from . import compat

        if compat.native_splats():  # Blender 5.3+: the choice between native splats and the add-on's own
            adv.prop(self, "native_splats")
        adv.prop(self, "base_python")
        adv.prop(self, "env_dir")
        sub = adv.row()
        sub.active = self.device == "CPU"  # the index is used for the CPU build only
        sub.prop(self, "torch_index")
        sub = adv.row()
        sub.active = self.device == "CUDA"  # the architectures are for the CUDA build only
        sub.prop(self, "cuda_archs")
        adv.prop(self, "backend_root")
        adv.prop(self, "include_bpy")


def get(context: bpy.types.Context | None = None) -> IGS_AddonPreferences:
    ctx = context or bpy.context
    addon = ctx.preferences.addons.get(ADDON_ID)
    if addon is None:
        raise UserError(f"the add-on '{ADDON_ID}' is not enabled")
    return addon.preferences


def interpreter(context: bpy.types.Context | None = None) -> str:
    """The configured backend interpreter (absolute), or a UserError saying how to set one."""
    path = get(context).backend_python
    if not path:
        raise UserError("No backend interpreter is set: open Preferences > Add-ons > Intrinsic Splats and "
                        "click 'Create Backend Environment' (or choose a Python with the backend's packages)")
    return bpy.path.abspath(path)


CLASSES = (IGS_AddonPreferences,)


def backend_job(context: bpy.types.Context | None, args: list, label: str, expected_stages: int = 0) -> BackendJob:
    """A (not yet started) backend job ``args`` run by the preferences' interpreter and backend sources."""
    return backend_env.backend_job(interpreter(context), args, label, root=get(context).backend_root,
                                   expected_stages=expected_stages)
