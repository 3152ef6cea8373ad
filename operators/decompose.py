"""Decompose operators: the three-field decomposition and the vanilla 3DGS baseline."""

from __future__ import annotations

import bpy

from ..igs_blender import display
from ..igs_blender.errors import UserError
from ..igs_blender.jobs import commands
from ..igs_blender.jobs.client import BackendJob
from ..igs_blender.preferences import backend_job
from ..igs_blender.workspace_files import capture_summary, existing_workspace, metrics_summary
from ..igs_contract.memory_estimate import workspace_line
from .job import BackendOperator


def refuse_over_memory(ws, command: str) -> None:
    """The backend's own line, before the job starts, when ``command``'s estimated peak memory on the
    workspace is over what this machine has free (the backend would stop with it)."""
    if (line := workspace_line(ws, command)) is not None:
        raise UserError(line)


def decompose_args(props) -> tuple[list, int]:
    """Command line and number of stages for the Decompose panel's settings."""
    ws = existing_workspace(props.workspace)
    stage = None if props.decompose_stage == "ALL" else props.decompose_stage
    args = commands.decompose(ws, stage=stage, iterations=props.iterations, restart=props.restart)
    return args, 3 if stage is None else 1


def _load_results(context, kinds_wanted: tuple[str, ...], show: str | None = None) -> str:
    """Load the workspace's layers, show ``show`` (else the panel's choice); the point counts of ``kinds_wanted``."""
    props = context.scene.igs
    ws = existing_workspace(props.workspace)
    objs = display.load_workspace_layers(ws, max_points=props.max_points, radius_scale=props.radius_scale,
                                        composite=props.build_composite)
    props.metrics_info = metrics_summary(ws)
    props.capture_info = capture_summary(ws)
    if show is not None and show in objs:
        props.layer_display = show  # its update shows it
    display.apply_visibility()
    shown = [k for k in objs if k in kinds_wanted or k == "composite"]
    return ", ".join(f"{k} {len(objs[k].data.points)}" for k in shown)


class IGS_OT_decompose(BackendOperator, bpy.types.Operator):
    """Decompose the capture into albedo, shading and residual Gaussians (resumes from the last checkpoint), then load the layers"""

    bl_idname = "igs.decompose"
    bl_label = "Decompose"

    def make_job(self, context) -> BackendJob:
        args, stages = decompose_args(context.scene.igs)
        refuse_over_memory(args[1], "decompose")
        return backend_job(context, args, "Decompose", expected_stages=stages)

    def finish(self, context, job: BackendJob) -> str:
        return "Decomposed; layers: " + _load_results(context, ("albedo", "shading", "residual"))


class IGS_OT_train_3dgs(BackendOperator, bpy.types.Operator):
    """Train the vanilla 3DGS baseline (one radiance field) on the same capture, then load it"""

    bl_idname = "igs.train_3dgs"
    bl_label = "Train 3DGS Baseline"

    def make_job(self, context) -> BackendJob:
        props = context.scene.igs
        ws = existing_workspace(props.workspace)
        refuse_over_memory(ws, "train-3dgs")
        args = commands.train_3dgs(ws, iterations=props.iterations, restart=props.restart)
        return backend_job(context, args, "Train 3DGS", expected_stages=1)

    def finish(self, context, job: BackendJob) -> str:
        return "3DGS baseline trained (shown); layers: " + _load_results(context, ("radiance",), show="radiance")


class IGS_OT_native_tune(BackendOperator, bpy.types.Operator):
    """Tune copies of the layers for Blender's own drawing of splats (layers/native/), so that F12 gives the images the decomposition was fitted to, then load them (Blender 5.3+)"""

    bl_idname = "igs.native_tune"
    bl_label = "Tune for Blender"

    @classmethod
    def poll(cls, context):
        if not display.use_native():
            cls.poll_message_set("Blender 5.3's own splats are off (Preferences > Native Splats) or this Blender is older")
            return False
        return super().poll(context)

    def make_job(self, context) -> BackendJob:
        ws = existing_workspace(context.scene.igs.workspace)
        return backend_job(context, commands.native_tune(ws), "Tune for Blender", expected_stages=1)

    def finish(self, context, job: BackendJob) -> str:
        return "Tuned for Blender's drawing (layers/native/); layers: " + \
            _load_results(context, ("albedo", "shading", "residual"))


CLASSES = (IGS_OT_decompose, IGS_OT_train_3dgs, IGS_OT_native_tune)
