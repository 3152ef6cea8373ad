"""Captures: synthetic Cycles scenes, imports (video, photos, COLMAP), the workspace on disk."""
