"""Cycles set up for ``igs synth`` and the render of one view into a multi-layer EXR.

This is the part of a synthetic render that talks to Blender. It runs in the backend's process when
that has the bpy module (``--renderer module``) and inside a Blender binary's own Python otherwise
(:mod:`backend.synth.blender_worker`), so it imports only numpy, bpy/mathutils and
:mod:`backend.core.cameras`. Both renderers then read the EXR with
:func:`backend.synth.exr_layers.read_multilayer_exr`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from backend.core.cameras import Camera, blender_matrix_world


@dataclass(frozen=True)
class CyclesParams:
    """What the Cycles setup depends on (the subset of the synth settings a Blender worker needs)."""

    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    samples: int
    """Samples per pixel."""
    seed: int
    """Cycles' sampling seed."""
    bounces: int
    """Maximum light bounces."""
    threads: int
    """Render threads."""


class CyclesView:
    """Cycles configured once on the current Blender scene (already built); renders a camera to an EXR.

    The EXR holds Combined, the diffuse/glossy/transmission passes, Emission, Environment, Depth,
    Position and one ``mask_<edit>`` AOV per edit, in the view layer named :attr:`layer`.
    """

    LIGHT_PASSES = ("diffuse_color", "diffuse_direct", "diffuse_indirect", "glossy_color", "glossy_direct",
                    "glossy_indirect", "transmission_color", "transmission_direct", "transmission_indirect",
                    "emit", "environment", "z", "position")

    def __init__(self, params: CyclesParams, mask_aovs: list[str]):
        import bpy

        self.bpy = bpy
        self.params = params
        sc = bpy.context.scene
        self.sc = sc
        r = sc.render
        r.engine = "CYCLES"
        c = sc.cycles
        c.device = "CPU"
        c.samples = params.samples
        c.use_adaptive_sampling = False  # a fixed sample count keeps renders deterministic
        c.use_denoising = False  # denoising would break albedo * shading + residual = combined
        c.seed = params.seed
        c.use_animated_seed = False
        c.pixel_filter_type = "BOX"
        c.filter_width = 1.0  # each sample lands in exactly one pixel
        c.sample_clamp_direct = 0.0  # no clamping: the passes must add up to Combined
        c.sample_clamp_indirect = 0.0
        c.max_bounces = params.bounces
        c.diffuse_bounces = params.bounces
        c.glossy_bounces = params.bounces
        c.transmission_bounces = params.bounces
        c.transparent_max_bounces = 2
        c.volume_bounces = 0
        c.caustics_reflective = False
        c.caustics_refractive = False
        c.use_light_tree = False  # three lights: the tree only costs time here (measured ~30 %)
        c.film_exposure = 1.0
        r.film_transparent = False
        r.threads_mode = "FIXED"
        r.threads = params.threads
        r.use_persistent_data = True  # keep the BVH between views: only the camera moves
        r.resolution_x = params.width
        r.resolution_y = params.height
        r.resolution_percentage = 100
        r.pixel_aspect_x = r.pixel_aspect_y = 1.0
        r.use_border = False
        r.use_crop_to_border = False
        sc.view_settings.view_transform = "Standard"  # only matters for Blender's own display
        sc.view_settings.look = "None"
        sc.view_settings.exposure = 0.0
        sc.view_settings.gamma = 1.0
        img = r.image_settings
        img.media_type = "MULTI_LAYER_IMAGE"
        img.exr_codec = "NONE"  # exr_layers reads uncompressed files only
        img.color_depth = "32"
        vl = sc.view_layers[0]
        self.layer: str = vl.name
        vl.use_pass_combined = True
        for p in self.LIGHT_PASSES:
            setattr(vl, f"use_pass_{p}", True)
        for name in mask_aovs:
            aov = vl.aovs.add()
            aov.name = name
            aov.type = "VALUE"

        cam_data = bpy.data.cameras.new("synth_camera")
        cam_data.sensor_fit = "HORIZONTAL"
        cam_data.sensor_width = 36.0
        cam_data.clip_start = 0.02
        cam_data.clip_end = 100.0
        self.camera = bpy.data.objects.new("synth_camera", cam_data)
        sc.collection.objects.link(self.camera)
        sc.camera = self.camera

    def render(self, cam: Camera, exr: Path, border: tuple[int, int, int, int] | None = None) -> None:
        """Render ``cam`` (optionally only pixels x0 <= x < x1, y0 <= y < y1) into the EXR ``exr``.

        Raises RuntimeError when Cycles fails or writes no file (Blender's output says why).
        """
        from mathutils import Matrix

        p = self.params
        if (cam.width, cam.height) != (p.width, p.height) or \
                abs(cam.cx - cam.width / 2) > 1e-9 or abs(cam.cy - cam.height / 2) > 1e-9 or abs(cam.fx - cam.fy) > 1e-9:
            raise ValueError("the synthetic renderer takes centred, square-pixel cameras of the capture size")
        self.camera.data.lens = cam.fx * 36.0 / cam.width  # horizontal sensor fit: fx = lens / 36 * width
        self.camera.matrix_world = Matrix(blender_matrix_world(cam).tolist())
        r = self.sc.render
        r.use_border = border is not None
        if border is not None:
            x0, y0, x1, y1 = border
            w, h = cam.width, cam.height
            r.border_min_x, r.border_max_x = x0 / w, x1 / w
            r.border_min_y, r.border_max_y = 1.0 - y1 / h, 1.0 - y0 / h  # Blender counts rows from the bottom
        r.filepath = str(exr)
        self.bpy.ops.render.render(write_still=True)
        if not exr.exists():
            raise RuntimeError(f"Cycles wrote no image (expected {exr})")
