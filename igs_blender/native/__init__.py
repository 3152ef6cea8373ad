"""Blender 5.3's own Gaussian splats: the layer objects (``splats``, ``colors``), the render's view layers and
compositor (``compositing``), the added lights (``lighting``), the render outputs and the turntable."""
