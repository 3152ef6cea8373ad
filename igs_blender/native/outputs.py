"""Every output of the composite group from one F12 (Blender 5.3+), as float images.

Render > Layer picks one output of "IGS Composite" for the render result; a check of the composite
against ``igs render`` (the benchmark, the tests) needs all four from the same samples. A File Output
node is wired to the group's outputs for one render and removed again, and the 32-bit EXRs it wrote
are read back linear.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from .. import images
from . import compositing

GROUP_OUTPUTS = ("Image", "Albedo", "Shading", "Residual")


def render_outputs(folder: Path, outputs: tuple[str, ...] = GROUP_OUTPUTS) -> dict[str, np.ndarray]:
    """F12 of the current scene with the group's ``outputs`` written to EXR in ``folder``.

    Returns linear (H, W, 3) float64 images by output name. The scene must have been set up by
    :func:`.compositing.setup` (the node group exists)."""
    tree = bpy.data.node_groups[compositing.TREE]
    node = tree.nodes.new("CompositorNodeOutputFile")
    node.directory = str(folder) + "/"
    node.file_name = ""
    node.format.media_type = "IMAGE"
    node.format.file_format = "OPEN_EXR"
    node.format.color_depth = "32"
    group = tree.nodes[compositing.GROUP]
    for name in outputs:
        node.file_output_items.new("RGBA", name)
        tree.links.new(group.outputs[name], node.inputs[name])
    try:
        bpy.ops.render.render(write_still=False)
    finally:
        tree.nodes.remove(node)
    out = {}
    for name in outputs:
        image = bpy.data.images.load(str(next(Path(folder).glob(f"{name}*.exr"))))
        try:
            out[name] = images.pixels(image)[..., :3].astype(np.float64)
        finally:
            bpy.data.images.remove(image)
    return out
