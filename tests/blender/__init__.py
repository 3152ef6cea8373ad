"""Tests of the add-on (igs_blender, operators, panels) under bpy, and of its backend environment."""
