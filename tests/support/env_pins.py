"""The backend environment's pinned set as the add-on reads it, and the fix its check names, for the environment tests."""

from __future__ import annotations

from pathlib import Path

from intrinsic_splats.igs_blender.env import backend_env, check_env

ROOT = Path(__file__).resolve().parents[2]


PINS = backend_env.pinned_requirements(ROOT)


FIX = "click Create Backend Environment"


def wanted_reqs(python: str, device: str = "cpu") -> list[str]:
    return check_env.requirements_for(PINS, python, device)[0]
