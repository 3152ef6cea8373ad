"""Sparse points for a capture whose poses are known (a transforms.json without a point cloud).

SIFT features and verified matches come from pycolmap; tracks are the connected components of the
matches; each track is triangulated with the known cameras (linear DLT on undistorted normalised
coordinates) and kept when it is in front of every camera, reprojects within ``max_error_px`` and
has a triangulation angle of at least ``min_angle_deg`` (COLMAP's defaults).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np

from backend.capture.sfm import SfMConfig, token_watching_cancel
from backend.capture.undistort import Intrinsics
from backend.core import events
from backend.core.atomic_io import write_image_file
from backend.core.errors import Cancelled, IGSError


def _dlt(P: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Point (3,) seen at normalised coordinates ``x`` (K, 2) by cameras ``P`` (K, 3, 4)."""
    A = np.concatenate([x[:, :1] * P[:, 2] - P[:, 0], x[:, 1:2] * P[:, 2] - P[:, 1]], axis=0)
    _, _, Vt = np.linalg.svd(A)
    X = Vt[-1]
    return X[:3] / X[3] if abs(X[3]) > 1e-12 else np.full(3, np.nan)


class _UnionFind:
    def __init__(self) -> None:
        self.parent: dict[tuple[int, int], tuple[int, int]] = {}

    def find(self, a):
        self.parent.setdefault(a, a)
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a, b) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[ra] = rb


def triangulate_known_poses(frames, intrinsics: dict[str, Intrinsics], poses: dict, work: Path,
                            config: SfMConfig = SfMConfig(), max_error_px: float = 2.0,
                            min_angle_deg: float = 1.5) -> tuple[np.ndarray, np.ndarray, list[list[str]]]:
    """Points (N, 3), colours (N, 3) uint8 and tracks (frame names) from ``frames`` (name, raw path) with
    known ``intrinsics`` and world-to-camera ``poses`` (name -> (R, t))."""
    import pycolmap

    if work.exists():
        shutil.rmtree(work)
    (work / "images").mkdir(parents=True)
    # Link (or copy) the frames under their workspace names so that COLMAP's image names are ours.
    for f in frames:
        dst = work / "images" / f.name
        img = cv2.imread(str(f.raw), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
        if img is None:
            raise IGSError(f"{f.raw}: unreadable image")
        write_image_file(dst, img)
    db_path = work / "database.db"
    names = [f.name for f in frames]
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 3
    token, stop = token_watching_cancel()
    try:
        with events.stage("triangulate: features and matches", total=2) as bar:
            extraction = pycolmap.FeatureExtractionOptions(num_threads=config.num_threads,
                                                           max_image_size=config.max_image_size)
            extraction.sift.max_num_features = config.max_features
            pycolmap.extract_features(db_path, work / "images", image_names=names,
                                      camera_mode=pycolmap.CameraMode.PER_IMAGE, extraction_options=extraction,
                                      device=pycolmap.Device.cpu, cancellation_token=token)
            bar.update(1)
            mopts = pycolmap.FeatureMatchingOptions(num_threads=config.num_threads)
            if len(names) <= config.exhaustive_max:
                pycolmap.match_exhaustive(db_path, matching_options=mopts, device=pycolmap.Device.cpu,
                                          cancellation_token=token)
            else:
                pycolmap.match_sequential(db_path, matching_options=mopts, device=pycolmap.Device.cpu,
                                          pairing_options=pycolmap.SequentialPairingOptions(
                                              overlap=config.sequential_overlap), cancellation_token=token)
            bar.update(1)
    except InterruptedError as e:  # pycolmap's answer to a cancelled token
        raise Cancelled("cancelled by user during feature matching") from e
    finally:
        stop.set()
        pycolmap.logging.minloglevel = level

    db = pycolmap.Database.open(str(db_path))
    try:
        id_to_name = {im.image_id: im.name for im in db.read_all_images()}
        keypoints = {iid: np.asarray(db.read_keypoints(iid))[:, :2].astype(np.float64) for iid in id_to_name}
        pair_ids, geoms = db.read_two_view_geometries()
    finally:
        db.close()
    uf = _UnionFind()
    for pid, g in zip(pair_ids, geoms):
        i1, i2 = pycolmap.pair_id_to_image_pair(pid)
        for a, b in np.asarray(g.inlier_matches).reshape(-1, 2):
            uf.union((int(i1), int(a)), (int(i2), int(b)))
    groups: dict = {}
    for node in list(uf.parent):
        groups.setdefault(uf.find(node), []).append(node)

    cams = {iid: intrinsics[n].to_pycolmap() for iid, n in id_to_name.items()}
    P = {iid: np.hstack([poses[n][0], poses[n][1][:, None]]) for iid, n in id_to_name.items()}
    normalised = {iid: np.asarray(cams[iid].cam_from_img(keypoints[iid]), dtype=np.float64)
                  for iid in id_to_name}
    focal = {iid: float(np.mean([intrinsics[n].params[0], intrinsics[n].params[1]]))
             if intrinsics[n].model not in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")
             else float(intrinsics[n].params[0]) for iid, n in id_to_name.items()}
    images = {}
    pts, cols, tracks = [], [], []
    cos_min = np.cos(np.radians(min_angle_deg))
    with events.stage("triangulate: tracks", total=len(groups), unit="track") as bar:
        for nodes in groups.values():
            bar.update(1)
            ids = [n[0] for n in nodes]
            if len(nodes) < 2 or len(set(ids)) != len(ids):  # ambiguous track: two points of one image
                continue
            Ps = np.stack([P[i] for i, _ in nodes])
            xs = np.stack([normalised[i][k] for i, k in nodes])
            X = _dlt(Ps, xs)
            if not np.isfinite(X).all():
                continue
            pc = np.einsum("kij,j->ki", Ps[:, :, :3], X) + Ps[:, :, 3]
            if (pc[:, 2] <= 1e-9).any():
                continue
            err = np.linalg.norm(pc[:, :2] / pc[:, 2:] - xs, axis=1) * np.array([focal[i] for i, _ in nodes])
            if err.max() > max_error_px:
                continue
            centers = np.stack([-P[i][:, :3].T @ P[i][:, 3] for i, _ in nodes])
            rays = X - centers
            rays /= np.linalg.norm(rays, axis=1, keepdims=True)
            if (rays @ rays.T).min() > cos_min:
                continue
            i0, k0 = nodes[0]
            if i0 not in images:
                images[i0] = cv2.imread(str(work / "images" / id_to_name[i0]))
            u, v = keypoints[i0][k0]
            im = images[i0]
            b, g, r = im[min(max(int(v), 0), im.shape[0] - 1), min(max(int(u), 0), im.shape[1] - 1)]
            pts.append(X)
            cols.append((r, g, b))
            tracks.append(sorted(id_to_name[i] for i, _ in nodes))
    if not pts:
        raise IGSError("no sparse point could be triangulated from the known poses (no verified matches between "
                       "the images, or poses that do not agree with the images)")
    events.log(f"triangulate: {len(pts)} points from {len(groups)} tracks")
    return np.array(pts), np.array(cols, dtype=np.uint8), tracks
