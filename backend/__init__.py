"""Intrinsic Splats backend: capture -> priors -> fields -> edit -> render.

Run ``python -m backend --help`` (or ``igs --help``) for the commands.
"""

__version__ = "0.1.0"
