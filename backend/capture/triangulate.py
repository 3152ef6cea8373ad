"""Sparse points for a capture whose poses are known (a transforms.json without a point cloud).

SIFT features and verified matches come from pycolmap, and so does the triangulation: COLMAP's point
triangulator (``pycolmap.triangulate_points``) with the known cameras and poses held fixed. It keeps a
point when it is in front of its cameras, reprojects within ``max_error_px`` and has a triangulation
angle of at least ``min_angle_deg`` (COLMAP's default), and refines the points by bundle adjustment.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from backend.capture.sfm import SfMConfig, extract_features, match_features, pycolmap_calls, sparse_points
from backend.capture.undistort import Intrinsics
from backend.core import events
from backend.core.atomic_io import write_image_file
from backend.core.errors import IGSError

# Cameras the features are extracted with (COLMAP's default model) until the known ones replace them.
PLACEHOLDER_MODEL = "SIMPLE_RADIAL"
NO_POINTS = ("no sparse point could be triangulated from the known poses (no verified matches between "
             "the images, or poses that do not agree with the images)")


def triangulate_known_poses(frames, intrinsics: dict[str, Intrinsics], poses: dict, work: Path,
                            config: SfMConfig = SfMConfig(), max_error_px: float = 2.0,
                            min_angle_deg: float = 1.5) -> tuple[np.ndarray, np.ndarray, list[list[str]]]:
    """Points (N, 3), colours (N, 3) uint8 and tracks (frame names) from ``frames`` (name, raw path) with
    known ``intrinsics`` and world-to-camera ``poses`` (name -> (R, t))."""
    import pycolmap

    if len(frames) < 2:  # nothing to match (and COLMAP's triangulator refuses to start)
        raise IGSError(NO_POINTS)
    if work.exists():
        shutil.rmtree(work)
    (work / "images").mkdir(parents=True)
    # Copy the frames under their workspace names so that COLMAP's image names are ours.
    for f in frames:
        img = cv2.imread(str(f.raw), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        if img is None:
            raise IGSError(f"{f.raw}: unreadable image")
        write_image_file(work / "images" / f.name, img)
    db_path = work / "database.db"
    names = [f.name for f in frames]
    matching = "exhaustive" if len(names) <= config.exhaustive_max else "sequential"
    with pycolmap_calls("feature matching", config.verbose) as token:
        with events.stage("triangulate: features and matches", total=2) as bar:
            extract_features(db_path, work / "images", names, config, token, single_camera=False,
                             camera_model=PLACEHOLDER_MODEL)
            bar.update(1)
            match_features(db_path, matching, config, token)
            bar.update(1)
    with pycolmap_calls("triangulation", config.verbose) as token:
        with events.stage("triangulate: tracks", total=1) as bar:
            known = _known_reconstruction(db_path, intrinsics, poses)
            rec = pycolmap.triangulate_points(known, db_path, work / "images", work / "model",
                                              options=_options(config, max_error_px, min_angle_deg),
                                              cancellation_token=token)
            bar.update(1)
    if rec.num_points3D() == 0:
        raise IGSError(NO_POINTS)
    events.log(f"triangulate: {rec.num_points3D()} points, mean track length {rec.compute_mean_track_length():.1f}, "
               f"mean reprojection error {rec.compute_mean_reprojection_error():.3f} px")
    return sparse_points(rec)


def _known_reconstruction(db_path: Path, intrinsics: dict[str, Intrinsics], poses: dict):
    """A pycolmap.Reconstruction of the database's images with their known cameras and poses, and no
    points. The database's placeholder cameras are overwritten with the known ones (the triangulator
    requires the two to agree)."""
    import pycolmap

    rec = pycolmap.Reconstruction()
    db = pycolmap.Database.open(str(db_path))
    try:
        for image in db.read_all_images():
            cam = intrinsics[image.name].to_pycolmap()
            cam.camera_id = image.camera_id
            db.update_camera(cam)
            rec.add_camera_with_trivial_rig(cam)
            R, t = poses[image.name]
            rec.add_image_with_trivial_frame(
                pycolmap.Image(name=image.name, camera_id=image.camera_id, image_id=image.image_id),
                pycolmap.Rigid3d(np.hstack([R, np.reshape(t, (3, 1))])))
    finally:
        db.close()
    return rec


def _options(config: SfMConfig, max_error_px: float, min_angle_deg: float):
    """COLMAP's triangulation, filter and merge thresholds set to ours; points seen by two images only
    are kept (COLMAP's mapper skips them, a tracks-only triangulation needs them)."""
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions(num_threads=config.num_threads, random_seed=config.seed)
    opts.mapper.filter_max_reproj_error = max_error_px
    opts.mapper.filter_min_tri_angle = min_angle_deg
    opts.triangulation.merge_max_reproj_error = max_error_px
    opts.triangulation.complete_max_reproj_error = max_error_px
    opts.triangulation.min_angle = min_angle_deg
    opts.triangulation.ignore_two_view_tracks = False
    return opts
