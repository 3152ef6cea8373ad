"""Which workspace a command writes to, and the lock it holds on it while it runs
(:mod:`backend.core.workspace_lock`).

A command that writes declares it when it registers (:func:`writes`): a function of the parsed
options that gives the workspace written to (None when this run writes to none, e.g. ``igs render``
to a folder outside the workspace), and whether the command may create that folder. The CLI then
runs it under :func:`run_locked`. Commands that only read (``igs info``) take no lock and are never
refused.
"""

from __future__ import annotations

import argparse
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from backend.core import workspace_lock
from backend.core.errors import Cancelled
from backend.core.output_paths import CAPTURE_JSON, workspace_of

Target = Callable[[argparse.Namespace], "str | Path | None"]

WAIT_HELP = ("if another igs command is writing to the workspace, wait until it has finished instead of "
             "stopping with exit code 75 (Ctrl-C cancels the wait)")


def writes(parser: argparse.ArgumentParser, target: Target, create: bool = False, drop_new: bool = False) -> None:
    """Declare that the command of ``parser`` writes to the workspace ``target(args)`` and give it
    ``--wait``. ``create``: it may create that folder; ``drop_new``: a folder it created is removed
    again when it fails (not when cancelled: running it again resumes)."""
    parser.add_argument("--wait", action="store_true", help=WAIT_HELP)
    parser.set_defaults(lock_target=target, lock_create=create, lock_drop_new=drop_new)


def workspace_arg(args: argparse.Namespace) -> str | None:
    """The usual target: the command's WORKSPACE argument."""
    return args.workspace


def output_workspace(path: str | Path | None) -> Path | None:
    """The workspace a user-named output lies in (None: none, or no output named)."""
    return workspace_of(path) if path else None


def label(args: argparse.Namespace) -> str:
    """The command as typed after ``igs``: ``decompose``, ``edit bake``."""
    sub = getattr(args, "edit_command", None)
    return f"{args.command} {sub}" if sub else str(args.command)


def run_locked(args: argparse.Namespace) -> Any:
    """Run ``args.func(args)``, under the lock of the workspace it writes to when it writes to one."""
    workspace_lock.set_command(label(args))
    target_of = getattr(args, "lock_target", None)
    target = target_of(args) if target_of is not None else None
    if target is None:
        return args.func(args)
    root = Path(target).expanduser()
    created = False
    try:
        with workspace_lock.hold(root, label(args), wait=args.wait, create=args.lock_create) as created:
            return args.func(args)
    except (Cancelled, KeyboardInterrupt):
        _drop_if_empty(root, created)
        raise
    except Exception:
        if created and args.lock_drop_new and not (root / CAPTURE_JSON).exists():
            shutil.rmtree(root, ignore_errors=True)  # a failed import leaves no folder behind
        _drop_if_empty(root, created)
        raise


def _drop_if_empty(root: Path, created: bool) -> None:
    """Remove the folder the lock created when the command wrote nothing into it (e.g. an option refused
    before any work): a refused command leaves no trace, and nothing written is ever removed."""
    try:
        if created and root.is_dir() and not any(root.iterdir()):
            root.rmdir()
    except OSError:
        pass
