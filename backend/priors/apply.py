"""The priors stage: albedo and depth maps for every view of a workspace, aligned with images/.

Maps that came with the capture (``gt``, ``folder:``) are in the geometry of the frames as captured
and get the frames' own warp (undistortion, resize), rebuilt from what the import recorded per frame
in capture.json (``import_frames``: raw file, distorted intrinsics). Model predictions are made on
the undistorted workspace images and are only resized. Depth is aligned to the SfM scale on the
sparse points each view sees (:mod:`backend.priors.align`).

Works on imported workspaces and on any other valid workspace (e.g. a synthetic one): frames with
no import record are taken as already undistorted.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np

from backend.capture.colmap_io import SparseModel, check_camera, read_model
from backend.capture.load import load_capture
from backend.capture.undistort import FrameWarp, Intrinsics, make_undistorter
from backend.core import events
from backend.core.atomic_io import atomic_path, write_image_file, write_json
from backend.core.cameras import Camera
from backend.core.errors import IGSError
from backend.core.imageio import check_image_file
from backend.core.staging import Staging
from backend.core.workspace import CAPTURE_SCHEMA, Workspace
from backend.priors.albedo import AlbedoOptions, AlbedoPredictor, make_albedo_predictor
from backend.priors.align import AlignConfig, align_depth, points_in_view
from backend.priors.consistency import TrackSamples, apply_gain, fit_gains, sample_view, spread
from backend.priors.depth import DepthOptions, DepthPredictor, make_depth_predictor
from backend.priors.folder import PriorFrame


@dataclass(frozen=True)
class PriorsConfig:
    """Which priors to compute and how."""

    albedo: str = "none"
    """Albedo prior spec: none, gt, folder:<path>, marigold:<model dir> (none keeps what is there)."""
    depth: str = "none"
    """Depth prior spec: none, gt, folder:<path>, depth-anything:<model dir> (none keeps what is there)."""
    albedo_options: AlbedoOptions = field(default_factory=AlbedoOptions)
    """Settings of albedo predictors."""
    depth_options: DepthOptions = field(default_factory=DepthOptions)
    """Settings of depth predictors."""
    align: AlignConfig = field(default_factory=AlignConfig)
    """Robust fit of depth maps to the SfM points."""
    albedo_consistency: Literal["auto", "none", "tracks"] = "auto"
    """Per-frame colour gains fitted on SfM tracks so a point has the same albedo in every view:
    'tracks', 'none', or 'auto' = tracks for model predictions, none for gt and folder maps."""


@dataclass
class _View:
    """One view: what priors know of its frame, its warp, its camera and its workspace image."""

    frame: PriorFrame
    warp: FrameWarp
    camera: Camera
    image: Path


def _views(ws: Workspace, capture) -> list[_View]:
    records = {r["name"]: r for r in capture.meta.get("import_frames", []) if isinstance(r, dict) and "name" in r}
    views = []
    for i, f in enumerate(capture.frames):
        rec = records.get(f.name)
        if rec is None:
            views.append(_View(PriorFrame(i, f.name, f.name, f.image, size=(f.camera.width, f.camera.height)),
                               FrameWarp.identity(f.camera), f.camera, f.image))
            continue
        try:
            ri = rec["intrinsics"]
            intr = Intrinsics(str(ri["model"]), int(ri["width"]), int(ri["height"]),
                              tuple(float(p) for p in ri["params"]))
            frame = PriorFrame(int(rec["index"]), f.name, str(rec.get("source", f.name)), Path(rec["raw"]),
                               None if rec.get("video_index") is None else int(rec["video_index"]),
                               size=(intr.width, intr.height))
        except (KeyError, TypeError, ValueError, OverflowError) as e:
            raise IGSError(f"{ws.capture_json}: the import record of {f.name} is malformed ({type(e).__name__}: {e}); "
                           "re-run `igs import`") from e
        check_camera(intr.model, intr.width, intr.height, intr.params, f"{ws.capture_json}: import record of {f.name}")
        warp = FrameWarp(make_undistorter(intr), f.camera.width, f.camera.height)
        views.append(_View(frame, warp, f.camera, f.image))
    return views


def _gt_dirs(ws: Workspace, meta: dict) -> dict[str, Path | None]:
    recorded = (meta.get("source") or {}).get("gt") or {}
    out = {}
    for kind in ("albedo", "depth"):
        if kind in recorded:
            out[kind] = Path(recorded[kind])
        else:
            out[kind] = ws.gt_pass(kind) if ws.gt_pass(kind).is_dir() else None
    return out


def make_predictors(config: PriorsConfig, gt: dict[str, Path | None], num_frames: int,
                    num_video_frames: int | None) -> tuple[AlbedoPredictor | None, DepthPredictor | None]:
    """Both predictors (None for 'none'); every bad spec is an IGSError before any work is done."""
    albedo = make_albedo_predictor(config.albedo, gt.get("albedo"), num_frames, num_video_frames,
                                   config.albedo_options)
    depth = make_depth_predictor(config.depth, gt.get("depth"), num_frames, num_video_frames, config.depth_options)
    return albedo, depth


def _rgb(path: Path) -> np.ndarray:
    check_image_file(path)
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise IGSError(f"{path}: unreadable image")
    return np.ascontiguousarray(img[:, :, ::-1])


class _Cache:
    """Model predictions per frame, kept while the predictor's stamp and the frame's image are unchanged,
    so that a cancelled or repeated run does not predict again."""

    def __init__(self, folder: Path, stamp: dict, enabled: bool):
        self.folder, self.enabled = folder, enabled
        if not enabled:
            return
        stamp_file = folder / "stamp.json"
        stamp = json.loads(json.dumps(stamp))
        if not stamp_file.exists() or json.loads(stamp_file.read_text()) != stamp:
            if folder.exists():
                shutil.rmtree(folder)
            folder.mkdir(parents=True)
            write_json(stamp_file, stamp)

    def get(self, name: str, image: Path, compute) -> np.ndarray:
        if not self.enabled:
            return compute()
        digest = hashlib.sha1(image.read_bytes()).hexdigest()[:16]
        path = self.folder / f"{Path(name).stem}-{digest}.npy"
        if path.exists():
            return np.load(path)
        for stale in self.folder.glob(f"{Path(name).stem}-*.npy"):
            stale.unlink()
        value = np.asarray(compute(), dtype=np.float32)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            np.save(fh, value)
        return value


def _raw_check(view: _View) -> None:
    if not view.frame.raw.exists():
        raise IGSError(f"{view.frame.raw}: the frame as captured is gone; maps that come with the capture are "
                       "undistorted like it (re-run `igs import`)")


def compute_priors(workspace: str | Path, config: PriorsConfig) -> dict:
    """Write albedo/ and/or depth/ for every view; update capture.json; return (and write) the report."""
    t0 = time.perf_counter()
    ws = Workspace(Path(workspace).expanduser())
    capture = load_capture(ws.root)
    meta = capture.meta
    views = _views(ws, capture)
    source = meta.get("source") or {}
    albedo_pred, depth_pred = make_predictors(config, _gt_dirs(ws, meta), int(source.get("frames_in", len(views))),
                                              source.get("video_frames"))
    report: dict = {"workspace": str(ws.root), "albedo": None, "depth": None}
    if albedo_pred is None and depth_pred is None:
        return report
    # New maps are built beside the old ones and swapped in together once every view has both.
    with Staging(ws.root, "priors") as staging:
        _compute(ws, meta, views, config, albedo_pred, depth_pred, staging, report)
        report["seconds"] = round(time.perf_counter() - t0, 3)
        write_json(staging.path(ws.root / "priors_report.json"), report)
        staging.commit()
    if albedo_pred is not None:
        events.output("albedo", ws.albedo)
    if depth_pred is not None:
        events.output("depth", ws.depth)
    events.output("report", ws.root / "priors_report.json")
    return report


def _compute(ws: Workspace, meta: dict, views: list[_View], config: PriorsConfig, albedo_pred: AlbedoPredictor | None,
             depth_pred: DepthPredictor | None, staging: Staging, report: dict) -> None:
    """Write the albedo/depth maps and the new capture.json into ``staging``; fill ``report``."""

    if albedo_pred is not None:
        t = time.perf_counter()
        cache = _Cache(ws.root / ".priors" / "albedo", albedo_pred.stamp(), enabled=not albedo_pred.warp)
        albedo_dir = staging.path(ws.albedo)
        albedo_dir.mkdir()
        with events.stage(f"albedo ({albedo_pred.label})", total=len(views), unit="image") as bar:
            for v in views:
                if albedo_pred.warp:
                    _raw_check(v)
                amap = cache.get(v.frame.name, v.image, lambda v=v: albedo_pred.predict(v.frame, _rgb(v.image)))
                amap = v.warp.image(amap) if albedo_pred.warp else v.warp.resize(amap)
                _write_albedo(albedo_dir / v.frame.name, amap)
                bar.update(1)
        report["albedo"] = {"prior": albedo_pred.label, "views": len(views),
                            "consistency": albedo_consistency(config, albedo_pred),
                            "seconds": round(time.perf_counter() - t, 3)}
        if report["albedo"]["consistency"] == "tracks":
            report["albedo"]["gains"] = _even_out_albedo(albedo_dir, views, read_model(ws.sparse))

    if depth_pred is not None:
        t = time.perf_counter()
        model = read_model(ws.sparse)
        seen: dict[str, list[int]] = {v.frame.name: [] for v in views}
        for j, tr in enumerate(model.tracks):
            for n in tr:
                if n in seen:
                    seen[n].append(j)
        has_tracks = any(model.tracks)
        align = AlignConfig(**{**asdict(config.align), "model": depth_pred.fit})
        cache = _Cache(ws.root / ".priors" / "depth", depth_pred.stamp(), enabled=not depth_pred.warp)
        depth_dir = staging.path(ws.depth)
        depth_dir.mkdir()
        alignments = []
        with events.stage(f"depth ({depth_pred.label})", total=len(views), unit="image") as bar:
            for v in views:
                if depth_pred.warp:
                    _raw_check(v)
                dmap = cache.get(v.frame.name, v.image, lambda v=v: depth_pred.predict(v.frame, _rgb(v.image)))
                dmap = v.warp.depth(dmap) if depth_pred.warp else v.warp.resize(dmap)
                pts = model.points[seen[v.frame.name]] if has_tracks else points_in_view(v.camera, model.points)
                depth, rep = align_depth(dmap, depth_pred.kind, v.camera, pts, align)
                with atomic_path(depth_dir / f"{Path(v.frame.name).stem}.npy") as tmp, open(tmp, "wb") as fh:
                    np.save(fh, depth)
                alignments.append(asdict(rep) if rep is not None else
                                  {"name": v.frame.name, "points": int(len(pts)), "aligned": False})
                bar.update(1, **({"rel_err": rep.median_abs_rel} if rep is not None else {}))
        unaligned = [a["name"] for a in alignments if a.get("aligned") is False]
        if unaligned:
            events.log(f"depth: {len(unaligned)} view(s) see too few sparse points to align; their depth is empty: "
                       + ", ".join(unaligned[:10]))
        report["depth"] = {"prior": depth_pred.label, "kind": depth_pred.kind, "fit": depth_pred.fit,
                           "summary": align_summary(alignments), "views": alignments,
                           "seconds": round(time.perf_counter() - t, 3)}
        s = report["depth"]["summary"]
        if s:
            events.log(f"depth: aligned {s['views_aligned']} views to the SfM scale, median relative error "
                       f"{s['median_abs_rel_median']:.3f} (worst view {s['median_abs_rel_max']:.3f})")

    priors = dict(meta.get("priors") or {})
    settings = dict(meta.get("prior_settings") or {})
    for kind, pred, spec, opts in (("albedo", albedo_pred, config.albedo, config.albedo_options),
                                   ("depth", depth_pred, config.depth, config.depth_options)):
        if pred is not None:
            priors[kind] = pred.label
            settings[kind] = {"spec": spec, **pred.stamp(), "options": asdict(opts)}
    if albedo_pred is not None:
        settings["albedo"]["consistency"] = report["albedo"]["consistency"]
    if depth_pred is not None:
        settings["depth"]["align"] = asdict(config.align)
    new_meta = {k: v for k, v in meta.items() if k != "schema"}
    new_meta.update(priors=priors, prior_settings=settings)
    write_json(staging.path(ws.capture_json), {"schema": CAPTURE_SCHEMA, **new_meta})


def albedo_consistency(config: PriorsConfig, pred: AlbedoPredictor) -> str:
    """'tracks' or 'none'. Left to 'auto', only model predictions (made on the workspace images, not
    warped) are evened out: ground truth is consistent by construction, and folder maps are usually
    from a video model whose frames already agree; ``--albedo-consistency tracks`` asks for it anyway."""
    if config.albedo_consistency == "auto":
        return "none" if pred.warp else "tracks"
    return config.albedo_consistency


def _write_albedo(path: Path, srgb: np.ndarray) -> None:
    write_image_file(path, (np.clip(srgb, 0, 1) * 65535 + 0.5).astype(np.uint16)[:, :, ::-1])


def _read_albedo(path: Path) -> np.ndarray:
    data = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise IGSError(f"{path}: unreadable albedo map")
    return data[:, :, ::-1].astype(np.float32) / 65535.0


def albedo_track_samples(albedo_dir: Path, cameras: list[Camera], model: SparseModel) -> TrackSamples:
    """Linear albedo of the maps ``albedo_dir/<camera name>`` at each view's SfM observations; frame
    indices are positions in ``cameras``."""
    index = {cam.name: i for i, cam in enumerate(cameras)}
    seen: list[list[int]] = [[] for _ in cameras]
    for j, track in enumerate(model.tracks):
        for name in track:
            if name in index:
                seen[index[name]].append(j)
    parts = []
    for i, cam in enumerate(cameras):
        ids = np.asarray(seen[i], dtype=int)
        parts.append(sample_view(_read_albedo(albedo_dir / cam.name), cam, model.points[ids], ids, i))
    return TrackSamples.concat(parts)


def _even_out_albedo(albedo_dir: Path, views: list[_View], model: SparseModel) -> dict:
    """Fit per-frame gains on the SfM tracks and rewrite the maps with them; what was done."""
    if not any(model.tracks):
        events.log("albedo: the SfM model lists no tracks (which images see a point), so the frames' colour "
                   "gains cannot be evened out; the maps are kept as predicted")
        return {"fitted": 0, "reason": "no tracks in the SfM model"}
    samples = albedo_track_samples(albedo_dir, [v.camera for v in views], model)
    fit = fit_gains(samples, len(views))
    before = spread(samples)
    with events.stage("albedo consistency", total=len(views), unit="image") as bar:
        for i, v in enumerate(views):
            if fit.fitted[i]:
                _write_albedo(albedo_dir / v.frame.name, apply_gain(_read_albedo(albedo_dir / v.frame.name),
                                                                    fit.gains[i]))
            bar.update(1)
    corrected = TrackSamples(samples.frame, samples.point,
                             samples.value * fit.gains[samples.frame].astype(np.float32))
    after = spread(corrected)
    out = {"fitted": int(fit.fitted.sum()), "points": fit.points, "observations": fit.observations,
           "gain_min": [round(float(x), 4) for x in fit.gains.min(axis=0)],
           "gain_max": [round(float(x), 4) for x in fit.gains.max(axis=0)],
           "spread_before": before, "spread_after": after,
           "per_view": {v.frame.name: [round(float(x), 4) for x in fit.gains[i]] for i, v in enumerate(views)}}
    if before["mean_std"] is not None:
        events.log(f"albedo: per-frame gains fitted on {fit.points} SfM points in {out['fitted']} views "
                   f"(gains {min(out['gain_min']):.3f} to {max(out['gain_max']):.3f}); spread of a point's albedo "
                   f"across views {before['mean_std']:.4f} -> {after['mean_std']:.4f}")
    return out


def align_summary(alignments: list[dict]) -> dict:
    """Median and worst per-view relative depth residual over the aligned views."""
    rel = [a["median_abs_rel"] for a in alignments if "median_abs_rel" in a]
    if not rel:
        return {}
    return {"views_aligned": len(rel), "views_unaligned": len(alignments) - len(rel),
            "median_abs_rel_median": float(np.median(rel)), "median_abs_rel_max": float(np.max(rel))}
