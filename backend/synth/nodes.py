"""Shader node trees a few nodes at a time: what :class:`backend.synth.builder.Builder` makes its
materials and the world with (it passes bpy's node trees in; nothing here imports bpy)."""

from __future__ import annotations

from typing import Any

import numpy as np

from backend.synth.scene import CylinderSurface


def linear_rgb(srgb) -> tuple[float, float, float]:
    """The sRGB-encoded colour ``srgb`` as linear RGB."""
    c = np.asarray(srgb, dtype=np.float64)
    return tuple(float(x) for x in np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4))


class Nodes:
    """Thin helpers over a shader node tree; ``float`` arguments become socket default values."""

    def __init__(self, tree):
        self.tree = tree

    def node(self, kind: str):
        return self.tree.nodes.new(kind)

    def link(self, out, inp) -> None:
        self.tree.links.new(out, inp)

    def set(self, inp, value) -> None:
        if isinstance(value, (int, float)):
            inp.default_value = float(value)
        else:
            self.link(value, inp)

    def math(self, op: str, a, b):
        node = self.node("ShaderNodeMath")
        node.operation = op
        self.set(node.inputs[0], a)
        self.set(node.inputs[1], b)
        return node.outputs[0]

    def dot(self, vec, const) -> Any:
        node = self.node("ShaderNodeVectorMath")
        node.operation = "DOT_PRODUCT"
        self.link(vec, node.inputs[0])
        node.inputs[1].default_value = tuple(float(c) for c in const)
        return node.outputs["Value"]

    def position_minus(self, origin) -> Any:
        geo = self.node("ShaderNodeNewGeometry")
        sub = self.node("ShaderNodeVectorMath")
        sub.operation = "SUBTRACT"
        self.link(geo.outputs["Position"], sub.inputs[0])
        sub.inputs[1].default_value = tuple(float(c) for c in origin)
        return sub.outputs["Vector"]

    def planar_uv(self, origin, u_axis, v_axis, size):
        rel = self.position_minus(origin)
        return (self.math("DIVIDE", self.dot(rel, u_axis), size[0]),
                self.math("DIVIDE", self.dot(rel, v_axis), size[1]))

    def cylinder_coords(self, s: CylinderSurface):
        """(theta in (-pi, pi], height along the axis) of the shading point."""
        rel = self.position_minus(s.base_center)
        side = np.cross(s.axis, s.ref_axis)
        theta = self.math("ARCTAN2", self.dot(rel, side), self.dot(rel, s.ref_axis))
        return theta, self.dot(rel, s.axis)

    def image(self, img, u, v, extension: str):
        combine = self.node("ShaderNodeCombineXYZ")
        self.set(combine.inputs["X"], u)
        self.set(combine.inputs["Y"], v)
        node = self.node("ShaderNodeTexImage")
        node.image = img
        node.interpolation = "Linear"
        node.extension = extension
        self.link(combine.outputs[0], node.inputs["Vector"])
        return node.outputs["Color"]

    def rgb(self, srgb):
        """A constant colour given sRGB-encoded (as a colour picker shows it)."""
        return self.rgb_linear(linear_rgb(srgb))

    def rgb_linear(self, lin):
        node = self.node("ShaderNodeRGB")
        node.outputs[0].default_value = (*[float(c) for c in lin], 1.0)
        return node.outputs[0]

    def mix(self, fac, a, b):
        node = self.node("ShaderNodeMix")
        node.data_type = "RGBA"
        self.set(node.inputs[0], fac)
        self.link(a, node.inputs[6])
        self.link(b, node.inputs[7])
        return node.outputs[2]

    def diffuse_out(self, color) -> None:
        """Lambertian (roughness 0): its "Diffuse Color" pass is exactly ``color``."""
        bsdf = self.node("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Roughness"].default_value = 0.0
        self.set(bsdf.inputs["Color"], color)
        out = self.node("ShaderNodeOutputMaterial")
        self.link(bsdf.outputs[0], out.inputs["Surface"])
