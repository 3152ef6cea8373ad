"""Rendering a workspace's scene for ``igs render``: the cameras and paths read, turntables, the layers drawn to images and mp4."""
