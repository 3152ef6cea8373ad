"""Structure from motion with pycolmap: SIFT features, sequential or exhaustive matching, incremental mapping.

Runs on the CPU. The result is the largest reconstructed model; images it does not register are
reported by name. Undistortion to PINHOLE is done afterwards by :mod:`backend.capture.undistort`.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal, get_args

import numpy as np

from backend.core import events
from backend.core.atomic_io import write_json
from backend.core.errors import Cancelled, IGSError

if TYPE_CHECKING:
    import pycolmap

Matching = Literal["auto", "sequential", "exhaustive"]
MATCHING: tuple[Matching, ...] = get_args(Matching)


@dataclass(frozen=True)
class SfMConfig:
    """Settings of the SfM run."""

    matching: Matching = "auto"
    """'sequential' (video frames), 'exhaustive' (unordered photos) or 'auto' (sequential for video,
    exhaustive for photo sets of at most ``exhaustive_max`` images, else sequential)."""
    exhaustive_max: int = 100
    """'auto' matches photo sets up to this size exhaustively."""
    sequential_overlap: int = 10
    """Sequential matching pairs each image with this many following images (and quadratic steps beyond)."""
    camera_model: str = "SIMPLE_RADIAL"
    """COLMAP camera model estimated for the capture (SIMPLE_RADIAL, RADIAL, OPENCV, PINHOLE, ...)."""
    single_camera: bool = True
    """All images share one camera (one phone/camera, fixed zoom); else one camera per image."""
    max_features: int = 8192
    """Maximum SIFT features per image."""
    max_image_size: int = 2000
    """Images are downscaled to this longer side for feature extraction (poses are unaffected)."""
    min_registered: int = 3
    """Fail when fewer images than this are registered."""
    min_registered_fraction: float = 0.5
    """Fail when less than this fraction of the images is registered."""
    max_reproj_error: float = 4.0
    """Pixels: 3D points whose reprojection error exceeds this are not created, merged or kept (COLMAP's
    filter/merge/complete thresholds and the initial pair's; 4 is COLMAP's default). On small images with
    repeated texture 2 halves the rotation error of a short sweep, but it can break long loops whose
    middle has little texture (measured on the synthetic room, see the README), so it is not the default."""
    seed: int = 0
    """Random seed of COLMAP's RANSAC and mapper (repeatable runs)."""
    num_threads: int = -1
    """CPU threads (-1: all)."""
    verbose: bool = False
    """Show COLMAP's own log lines."""


@dataclass
class SfMResult:
    """The largest model and what happened to each image."""

    reconstruction: object = field(repr=False)
    """The pycolmap.Reconstruction (distorted cameras)."""
    registered: list[str]
    dropped: list[str]
    num_models: int
    matching: str


class _Watch:
    """Stops the watcher thread and gives the signal wake-up fd back."""

    def __init__(self, stop: threading.Event, thread: threading.Thread, fds: tuple[int, int] | None,
                 old_fd: int | None):
        self.stop, self.thread, self.fds, self.old_fd = stop, thread, fds, old_fd

    def set(self) -> None:
        self.stop.set()
        self.thread.join(timeout=1.0)  # it wakes up within 0.2 s; only then are its fds closed
        if self.fds is not None:
            signal.set_wakeup_fd(self.old_fd)
            for fd in self.fds:
                os.close(fd)
            self.fds = None


def token_watching_cancel():
    """A pycolmap CancellationToken cancelled when the user cancels (SIGINT/SIGTERM).

    Python runs signal handlers only when the main thread is back in Python, which it is not during
    a long pycolmap call; a wake-up fd written by the C-level handler lets a watcher thread see the
    signal at once. Returns (token, watch); call ``watch.set()`` when the pycolmap calls are done.
    """
    import pycolmap

    token = pycolmap.CancellationToken()
    stop = threading.Event()
    fds, old_fd = None, None
    if threading.current_thread() is threading.main_thread():
        r, w = os.pipe()
        os.set_blocking(w, False)
        old_fd = signal.set_wakeup_fd(w, warn_on_full_buffer=False)
        fds = (r, w)

    def watch() -> None:
        while not stop.is_set():
            if events.cancelled():
                token.cancel()
                return
            if fds is None:
                stop.wait(0.2)
                continue
            try:
                ready, _, _ = select.select([fds[0]], [], [], 0.2)
                data = os.read(fds[0], 64) if ready else b""
            except (OSError, ValueError):
                return
            if any(b in (signal.SIGINT, signal.SIGTERM) for b in data):
                token.cancel()  # the Python handler will still set the cancel flag later
                return

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    return token, _Watch(stop, thread, fds, old_fd)


@contextmanager
def pycolmap_calls(during: str, verbose: bool = False) -> Iterator[pycolmap.CancellationToken]:
    """Run pycolmap calls: yields a CancellationToken that the user's cancel trips, keeps COLMAP's own
    log quiet unless ``verbose`` (its lines would drown the progress bars; its errors are reported as
    one message of ours) and turns a cancelled call into :class:`Cancelled` ("... during ``during``")."""
    import pycolmap

    token, watch = token_watching_cancel()
    level = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = 0 if verbose else 3
    try:
        yield token
    except InterruptedError as e:  # pycolmap's answer to a cancelled token
        raise Cancelled(f"cancelled by user during {during}") from e
    finally:
        watch.set()
        pycolmap.logging.minloglevel = level
    if token.is_cancelled:
        raise Cancelled(f"cancelled by user during {during}")


def extract_features(db: Path, image_dir: Path, names: list[str], config: SfMConfig,
                     token: pycolmap.CancellationToken, *,
                     single_camera: bool, camera_model: str) -> None:
    """SIFT features of ``names`` (files in ``image_dir``) into the database ``db``, on the CPU; one
    ``camera_model`` camera shared by all images or one per image."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions(camera_model=camera_model)
    extraction = pycolmap.FeatureExtractionOptions(num_threads=config.num_threads,
                                                   max_image_size=config.max_image_size)
    extraction.sift.max_num_features = config.max_features
    pycolmap.extract_features(db, image_dir, image_names=names,
                              camera_mode=pycolmap.CameraMode.SINGLE if single_camera
                              else pycolmap.CameraMode.PER_IMAGE,
                              reader_options=reader, extraction_options=extraction,
                              device=pycolmap.Device.cpu, cancellation_token=token)


def match_features(db: Path, matching: Literal["sequential", "exhaustive"], config: SfMConfig,
                   token: pycolmap.CancellationToken) -> None:
    """Match and geometrically verify the features in ``db``: every pair, or each image with its
    ``config.sequential_overlap`` followers (and quadratic steps beyond)."""
    import pycolmap

    mopts = pycolmap.FeatureMatchingOptions(num_threads=config.num_threads)
    if matching == "sequential":
        pair = pycolmap.SequentialPairingOptions(overlap=config.sequential_overlap)
        pycolmap.match_sequential(db, matching_options=mopts, pairing_options=pair,
                                  device=pycolmap.Device.cpu, cancellation_token=token)
    else:
        pycolmap.match_exhaustive(db, matching_options=mopts, device=pycolmap.Device.cpu,
                                  cancellation_token=token)


def _stamp(image_dir: Path, names: list[str], config: SfMConfig, matching: str) -> dict:
    files = [(n, (image_dir / n).stat().st_size, (image_dir / n).stat().st_mtime) for n in names]
    return {"files": files, "config": asdict(config), "matching": matching}


def run_sfm(image_dir: str | Path, names: list[str], work_dir: str | Path, config: SfMConfig = SfMConfig(),
            ordered: bool = False, label: str | None = None) -> SfMResult:
    """Reconstruct cameras and sparse points for ``names`` (files in ``image_dir``).

    ``ordered``: the images are consecutive video frames (sequential matching under 'auto').
    ``work_dir`` keeps the feature database and the model; a repeated call with the same images and
    settings reuses the model instead of recomputing it. ``label`` names the capture in messages.
    """
    import pycolmap

    image_dir, work_dir = Path(image_dir), Path(work_dir)
    label = label or str(image_dir)
    if config.matching not in MATCHING:
        raise IGSError(f"--matching must be one of {', '.join(MATCHING)} (got '{config.matching}')")
    if len(names) < max(2, config.min_registered):
        raise IGSError(f"{label}: {len(names)} image(s); SfM needs at least {max(2, config.min_registered)}")
    matching = config.matching
    if matching == "auto":
        matching = "sequential" if ordered or len(names) > config.exhaustive_max else "exhaustive"

    stamp = _stamp(image_dir, names, config, matching)
    model_dir = work_dir / "model"
    stamp_path = work_dir / "sfm.json"
    reused = _reused_model(stamp_path, model_dir, stamp)
    if reused is not None:
        return _result(*reused, names=names, matching=matching, config=config, label=label)

    if work_dir.exists():
        shutil.rmtree(work_dir)
    work_dir.mkdir(parents=True)
    db = work_dir / "database.db"
    pycolmap.set_random_seed(config.seed)
    with pycolmap_calls("SfM", config.verbose) as token:
        with events.stage("sfm features", total=1) as bar:
            extract_features(db, image_dir, names, config, token, single_camera=config.single_camera,
                             camera_model=config.camera_model)
            bar.update(1)
        with events.stage(f"sfm matching ({matching})", total=1) as bar:
            match_features(db, matching, config, token)
            bar.update(1)
        events.check_cancel()
        bar = events.Progress("sfm mapping", total=len(names), unit="image")
        try:
            def on_image() -> None:
                # Called from COLMAP's thread: only advance the bar; cancel goes through the token.
                if bar.step < bar.total:
                    bar.step += 1
                    bar.bar.update(1)
                    events.emit("progress", stage=bar.stage, step=bar.step, total=bar.total)

            models = pycolmap.incremental_mapping(db, image_dir, work_dir / "models", options=_mapping_options(config),
                                                  next_image_callback=on_image, cancellation_token=token)
        finally:
            bar.close()
    if not models:
        raise IGSError(f"{label}: SfM could not reconstruct any model from {len(names)} images "
                       "(too little texture or overlap between the frames?)")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    model_dir.mkdir(parents=True, exist_ok=True)
    rec.write(str(model_dir))
    write_json(stamp_path, {"stamp": stamp, "num_models": len(models)})
    return _result(rec, len(models), names=names, matching=matching, config=config, label=label)


def _reused_model(stamp_path: Path, model_dir: Path, stamp: dict):
    """(pycolmap.Reconstruction, number of models) of an earlier run with the same ``stamp``, or None."""
    import pycolmap

    if not (stamp_path.exists() and (model_dir / "images.bin").exists()):
        return None
    try:
        old = json.loads(stamp_path.read_text())
    except json.JSONDecodeError:
        return None
    if old.get("stamp") != json.loads(json.dumps(stamp)):
        return None
    rec = pycolmap.Reconstruction(str(model_dir))
    events.log(f"sfm: reusing the model in {model_dir} ({rec.num_reg_images()} images registered)")
    return rec, old.get("num_models", 1)


def _mapping_options(config: SfMConfig):
    """COLMAP's incremental mapping options: ``config``'s threads, seed, minimum model size and
    reprojection threshold (for creating, merging, completing and keeping points, and the initial pair)."""
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions(num_threads=config.num_threads, random_seed=config.seed,
                                               min_model_size=max(3, config.min_registered))
    err = float(config.max_reproj_error)
    opts.mapper.filter_max_reproj_error = err
    opts.mapper.init_max_error = err
    opts.triangulation.merge_max_reproj_error = err
    opts.triangulation.complete_max_reproj_error = err
    return opts


def _result(rec, num_models: int, *, names: list[str], matching: str, config: SfMConfig | None = None,
            label: str = "") -> SfMResult:
    registered = sorted(img.name for img in rec.images.values() if img.has_pose)
    reg = set(registered)
    dropped = [n for n in names if n not in reg]
    if config is not None:
        need = max(config.min_registered, int(np.ceil(config.min_registered_fraction * len(names))))
        if len(registered) < need:
            raise IGSError(f"{label}: SfM registered only {len(registered)} of {len(names)} images (need {need}); "
                           "the capture needs more overlap between frames, more texture, or less motion blur "
                           "(try a smaller --every or --matching exhaustive)")
    if dropped:
        shown = ", ".join(dropped[:10]) + (" ..." if len(dropped) > 10 else "")
        events.log(f"sfm: {len(dropped)} of {len(names)} images not registered and dropped: {shown}")
    events.log(f"sfm: {len(registered)} images registered, {rec.num_points3D()} points, "
               f"{num_models} model(s), mean reprojection error {rec.compute_mean_reprojection_error():.3f} px")
    return SfMResult(rec, registered, dropped, num_models, matching)


def sparse_points(rec) -> tuple[np.ndarray, np.ndarray, list[list[str]]]:
    """Points (N, 3) float64, colours (N, 3) uint8 and, per point, the names of the images that see it."""
    id_to_name = {iid: img.name for iid, img in rec.images.items() if img.has_pose}
    ids = sorted(rec.points3D)
    pts = [rec.points3D[i] for i in ids]
    xyz = np.array([p.xyz for p in pts], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts], dtype=np.uint8).reshape(-1, 3)
    tracks = [sorted({id_to_name[e.image_id] for e in p.track.elements if e.image_id in id_to_name}) for p in pts]
    return xyz, rgb, tracks
