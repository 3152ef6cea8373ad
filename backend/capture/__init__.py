"""Captures: imports (video, photos, COLMAP, transforms.json), SfM, undistortion, loading a workspace."""
