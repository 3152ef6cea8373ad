"""Model checkpoints named by a local folder or a Hugging Face model id.

A prior's argument (``marigold:<arg>``, ``depth-anything:<arg>``) is, in this order: empty (the
family's default id), an existing folder (used as it is, never downloaded), one of the family's named
choices, or a model id ``org/name``. Ids go through huggingface_hub's standard cache
(``HF_HOME`` / ``HF_HUB_CACHE``; ``HF_HUB_OFFLINE=1`` never touches the network): files already
cached are reused, missing ones are downloaded with progress as an :mod:`backend.core.events` stage
(bytes as steps), cancellable between files and, for plain HTTP downloads, within one.
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from backend.core import events
from backend.core.errors import Cancelled, IGSError

_REPO_ID = re.compile(r"[A-Za-z0-9][\w.-]*/[\w.-]+")
# Weight formats diffusers/transformers can read; one of them per folder is enough.
_WEIGHTS = (".safetensors", ".bin", ".pt", ".pth", ".ckpt", ".msgpack", ".h5", ".onnx", ".ot")
_SKIP = (".md", ".png", ".jpg", ".jpeg", ".gif", ".mp4", ".gitattributes")


@dataclass(frozen=True)
class ModelSource:
    """Where a checkpoint is: ``folder`` (on disk, as given) or ``repo_id`` (the Hub's cache)."""

    folder: Path | None = None
    repo_id: str | None = None


def parse_model_arg(option: str, arg: str, default_id: str, named: dict[str, str] | None = None) -> ModelSource:
    """The checkpoint ``arg`` names (see the module doc); ``option`` (e.g. ``--albedo marigold``) names errors."""
    named = named or {}
    if arg == "":
        return ModelSource(repo_id=default_id)
    folder = Path(arg).expanduser()
    if folder.is_dir():  # an existing folder is always a folder, as before ids were accepted
        return ModelSource(folder=folder)
    if arg in named:
        return ModelSource(repo_id=named[arg])
    if _REPO_ID.fullmatch(arg) and ".." not in arg:
        return ModelSource(repo_id=arg)
    choices = ", ".join(named)
    raise IGSError(f"{option}:{arg}: no such folder, and not a Hugging Face model id (org/name)"
                   + (f" or one of {choices}" if choices else ""))


def offline_message(repo_id: str, folder_spec: str) -> str:
    return (f"model {repo_id} is not in the cache and the network is unreachable: download it with "
            f"`huggingface-cli download {repo_id}` (or `hf download {repo_id}`), or point at a folder with "
            f"{folder_spec}")


def select_files(files: dict[str, int | None]) -> list[str]:
    """The repository files a pipeline needs: configs and tokenizers, and per folder one weight format
    (safetensors first) without precision variants (``*.fp16.safetensors``) when a full one exists."""
    keep, weights = [], {}
    for name in files:
        p = PurePosixPath(name)
        if p.name.startswith(".") or p.suffix.lower() in _SKIP:
            continue
        if p.suffix.lower() in _WEIGHTS:
            weights.setdefault(str(p.parent), []).append(p)
        else:
            keep.append(name)
    for paths in weights.values():
        for fmt in _WEIGHTS:
            of_fmt = [p for p in paths if p.suffix.lower() == fmt]
            if not of_fmt:
                continue
            plain = [p for p in of_fmt if "." not in p.stem]  # model.fp16.safetensors has stem model.fp16
            keep.extend(str(p) for p in (plain or of_fmt))
            break
    return sorted(keep)


_resolved: dict[tuple[str, str], Path] = {}  # one look-up per model and cache per process


def _cache_dir() -> str:
    from huggingface_hub import constants

    return constants.HF_HUB_CACHE  # read at call time: HF_HOME / HF_HUB_CACHE as the library resolved them


def fetch_model(repo_id: str, folder_spec: str) -> Path:
    """The local snapshot folder of ``repo_id``, downloading what the cache lacks (unless offline).

    ``folder_spec`` is what the offline error suggests instead (e.g. ``marigold:<dir>``).
    """
    from huggingface_hub import constants

    key = (_cache_dir(), repo_id)
    if key in _resolved and _resolved[key].is_dir():
        return _resolved[key]
    reason = "HF_HUB_OFFLINE is set"
    if not constants.is_offline_mode():
        try:
            folder = _download(repo_id)
        except _Unreachable as e:
            reason = str(e)
        else:
            _resolved[key] = folder
            return folder
    folder = _cached(repo_id)
    if folder is None:
        raise IGSError(f"{offline_message(repo_id, folder_spec)} ({reason})")
    _resolved[key] = folder
    return folder


class _Unreachable(Exception):
    """The Hub could not be asked (no network, timeout, server error): the cache may still have the model."""


def _cached(repo_id: str) -> Path | None:
    from huggingface_hub import snapshot_download
    from huggingface_hub.errors import LocalEntryNotFoundError

    try:
        return Path(snapshot_download(repo_id, cache_dir=_cache_dir(), local_files_only=True))
    except LocalEntryNotFoundError:
        return None


def _download(repo_id: str) -> Path:
    import httpx2
    from huggingface_hub import HfApi, hf_hub_download
    from huggingface_hub import errors as hub

    try:
        info = HfApi().model_info(repo_id, files_metadata=True)
    except hub.GatedRepoError as e:
        raise IGSError(f"model {repo_id} is gated: accept its terms on huggingface.co and log in with "
                       "`hf auth login`") from e
    except hub.RepositoryNotFoundError as e:
        raise IGSError(f"model {repo_id} does not exist on the Hugging Face Hub (or is private)") from e
    except (hub.OfflineModeIsEnabled, httpx2.ConnectError, httpx2.TimeoutException, hub.HfHubHTTPError, OSError) as e:
        raise _Unreachable(f"{type(e).__name__}: {e}") from e
    sizes = {s.rfilename: s.size for s in (info.siblings or [])}
    files = select_files(sizes)
    if not files:
        raise IGSError(f"model {repo_id}: the repository holds no model files")
    total = sum(sizes[f] or 0 for f in files)
    snapshot = None
    with events.stage(f"download {repo_id}", total=max(total, 1), unit="B") as bar:
        for name in files:
            events.check_cancel()
            counted = _FileBytes(bar, sizes[name] or 0)
            try:
                path = hf_hub_download(repo_id, name, revision=info.sha, cache_dir=_cache_dir(),
                                       tqdm_class=counted.bar_class())
            except (hub.OfflineModeIsEnabled, httpx2.ConnectError, httpx2.TimeoutException) as e:
                raise _Unreachable(f"{type(e).__name__}: {e}") from e
            except hub.HfHubHTTPError as e:
                raise IGSError(f"model {repo_id}: downloading {name} failed ({e})") from e
            counted.finish()
            snapshot = Path(path).parents[len(PurePosixPath(name).parts) - 1]
    _write_ref(repo_id, info.sha)
    return snapshot


def _write_ref(repo_id: str, commit: str) -> None:
    """refs/main -> commit, as snapshot_download writes it, so that offline runs find this snapshot."""
    from huggingface_hub.file_download import repo_folder_name

    from backend.core.atomic_io import write_text

    ref = Path(_cache_dir()) / repo_folder_name(repo_id=repo_id, repo_type="model") / "refs" / "main"
    ref.parent.mkdir(parents=True, exist_ok=True)
    write_text(ref, commit)


class _FileBytes:
    """One file's share of the download stage: the library's progress updates, capped at the file's
    size (a file may report through two bars), topped up when the file is done (cached files)."""

    def __init__(self, bar: events.Progress, size: int):
        self.stage, self.size, self.done = bar, size, 0
        self.lock = threading.Lock()

    def add(self, n: float) -> None:
        with self.lock:
            step = max(0, min(int(n or 0), self.size - self.done))
            self.done += step
            try:
                self.stage.update(step)  # emits progress, raises Cancelled when asked to stop
            except Cancelled:
                # Only where the download loop runs: a callback thread of the transfer library would lose
                # it; the check between files stops the download then.
                if threading.current_thread() is threading.main_thread():
                    raise

    def finish(self) -> None:
        self.stage.update(self.size - self.done)
        self.done = self.size

    def bar_class(self) -> type:
        owner = self

        class Bar:
            """Just enough of tqdm for huggingface_hub's download loops."""

            def __init__(self, *args, **kwargs):
                self.total = kwargs.get("total")
                self.n = 0

            def update(self, n: float = 1) -> None:
                owner.add(n)

            def update_transfer(self, n: float = 1) -> None:
                pass

            def __getattr__(self, name: str):  # set_postfix_str, refresh, close, ...: nothing to show
                return lambda *a, **k: None

            def __enter__(self):
                return self

            def __exit__(self, *exc) -> None:
                pass

        return Bar
