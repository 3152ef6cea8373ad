"""The ground floor every other room stands on: no torch, nothing of the rooms above.

``errors`` (user errors), ``atomic_io`` (atomic writes), ``staging`` (build next to the old, swap
in), ``events`` and ``signals`` (progress, cancel), ``paths`` (names that stay inside their folder),
``cameras`` and ``rotations`` (pinhole cameras, quaternions), ``imageio`` (image files and colour),
``workspace`` (the workspace's paths and records), ``workspace_lock`` (one writer per workspace),
``output_paths`` (user-named outputs stay out of a workspace's own files).
"""
