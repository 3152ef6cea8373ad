"""Preferences operators: create the backend environment, check an interpreter."""

from __future__ import annotations

from pathlib import Path

import bpy

from ..igs_blender import compat, preferences
from ..igs_blender.addon_id import ADDON_ID
from ..igs_blender.env import backend_env
from ..igs_blender.jobs.client import BackendJob
from .job import BackendOperator


class IGS_OT_create_backend_env(BackendOperator, bpy.types.Operator):
    """Create a Python environment with the backend's pinned requirements for the chosen Device and use it (downloads about 0.5 GB for CPU; 3.1 GB for NVIDIA CUDA, which then builds gsplat's kernels with NVIDIA's compiler from PyPI: no CUDA toolkit needed)"""

    bl_idname = "igs.create_backend_env"
    bl_label = "Create Backend Environment"
    writes_workspace = False

    def make_job(self, context) -> BackendJob:
        prefs = preferences.get(context)
        env_dir = Path(bpy.path.abspath(prefs.env_dir)) if prefs.env_dir else \
            backend_env.default_env_dir(compat.extension_user_dir(ADDON_ID, ""))
        base = bpy.path.abspath(prefs.base_python) if prefs.base_python else ""
        self._env_dir = env_dir
        return backend_env.setup_job(base, env_dir, include_bpy=prefs.include_bpy, root=prefs.backend_root,
                                     device=prefs.device, torch_index=prefs.torch_index,
                                     cuda_archs=prefs.cuda_archs)

    def finish(self, context, job: BackendJob) -> str:
        prefs = preferences.get(context)
        python = next((p for k, p in job.state.outputs if k == "interpreter"),
                      str(backend_env.venv_python(self._env_dir)))
        prefs.backend_python = python
        prefs.check_report, prefs.check_ok = "", False  # the last check was of another environment
        return f"Backend environment ready: {python} (run 'Check Backend' to list its commands)"


class IGS_OT_check_backend(BackendOperator, bpy.types.Operator):
    """Check that the backend interpreter has every pinned package for its Python and the Device, which torch build it has, whether CUDA works, and list the backend's commands"""

    bl_idname = "igs.check_backend"
    writes_workspace = False
    bl_label = "Check Backend"

    def make_job(self, context) -> BackendJob:
        prefs = preferences.get(context)
        return backend_env.check_job(preferences.interpreter(context), prefs.backend_root, prefs.include_bpy,
                                     device=prefs.device)

    def finish(self, context, job: BackendJob) -> str:
        prefs = preferences.get(context)
        ok, lines = backend_env.env_report_lines(job)
        prefs.check_ok = ok
        prefs.check_report = "\n".join(lines)
        self.finish_level = "INFO" if ok else "WARNING"
        return lines[0]  # what is wrong and how to fix it; the details are in the preferences


CLASSES = (IGS_OT_create_backend_env, IGS_OT_check_backend)
