"""The ``igs`` / ``python -m backend`` command line: the parser, ``main`` and its error handling.

Each command lives in a module of :mod:`backend.commands` which exposes ``register(subparsers)``;
a command is listed here only once it works end to end.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import re
import sys
import time
import traceback
from typing import NoReturn

from backend import __version__
from backend.commands.locking import run_locked
from backend.core import events, signals
from backend.core.atomic_io import os_error
from backend.core.errors import Cancelled, IGSError
from backend.core.workspace_lock import WorkspaceBusy
from igs_contract.events import CANCELLED, DONE, ERROR, START
from igs_contract.exit_codes import EXIT_BUSY, EXIT_CANCELLED, EXIT_INTERNAL, EXIT_OK, EXIT_PIPE, EXIT_USER

# Errors of the machine rather than of the program (full disk, read-only or missing folder,
# permissions): one line naming the file, like bad input.
DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO, errno.EFBIG,
               errno.ENOENT, errno.ENOTDIR, errno.EISDIR}

CANCELLED_MESSAGE = "cancelled; the workspace keeps the last checkpoint, run the same command again to resume"
RESTART_MESSAGE = "cancelled; nothing was written, and the same command starts over when run again"

# Modules with a ``register(subparsers)`` function, in the order of the pipeline (and of --help).
# Imported by build_parser, not here: torch loads with them, after the signal handlers are in.
COMMAND_MODULES: list[str] = [
    "backend.commands.demo",
    "backend.commands.info",
    "backend.commands.import_capture",
    "backend.commands.priors",
    "backend.commands.synth",
    "backend.commands.train",
    "backend.commands.decompose",
    "backend.commands.edit",
    "backend.commands.render",
    "backend.commands.light_bake",
    "backend.commands.normals",
    "backend.commands.native_tune",
    "backend.commands.distil",
    "backend.commands.export",
    "backend.commands.convert",
]


class _Parser(argparse.ArgumentParser):
    """argparse with the project's one-line errors: ``igs CMD: error: --option must be ...``."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        message = re.sub(r"^argument (\S+?)(/\S+)?: ", r"\1 ", message)
        self.exit(EXIT_USER, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="igs",
        description="Intrinsic Splats: decompose a capture into albedo, shading and residual Gaussians, "
        "edit the albedo, render.",
    )
    parser.add_argument("--version", action="version", version=f"igs {__version__}")
    parser.add_argument("--events", action="store_true",
                        help="also write JSON-lines progress events to stdout (used by the Blender add-on)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command; the exit code (:mod:`igs_contract.exit_codes`): 0 done, 2 user error, 75
    workspace busy, 130 cancelled, 1 internal error.

    Without ``argv`` (a process of its own: ``igs``, ``python -m backend``) signals arriving after
    the command has finished are ignored, so that the exit code stays the command's.
    """
    if argv is not None:
        return _main(argv)
    try:
        return _main(sys.argv[1:])
    finally:
        # Python's shutdown puts back the default SIGINT action (killed, -2) while threads are
        # joined; a late Ctrl-C must not turn a finished 0 or 130 into that.
        signals.ignore()


def _main(argv: list[str]) -> int:
    try:
        return _run(argv)
    except BrokenPipeError:  # the reader of stdout went away (`igs info | head`): not an error to report
        _drop_stdout()
        return EXIT_PIPE


def _run(argv: list[str]) -> int:
    signals.install()  # first: a Ctrl-C while torch and the commands load is a cancel, not a traceback
    # --events is known before the commands load, so a second Ctrl-C meanwhile still ends in an event
    events.enable_json("--events" in argv[:next((i for i, a in enumerate(argv) if not a.startswith("-")), len(argv))])
    signals.on_stop_now(events.stop_now_event)
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except KeyboardInterrupt:  # only if a library put Python's default handler back while loading
        print(f"igs: {CANCELLED_MESSAGE}", file=sys.stderr)
        return EXIT_CANCELLED
    except SystemExit as e:  # --help, --version, or a bad option (argparse printed it): its exit code
        return e.code if isinstance(e.code, int) else EXIT_USER
    events.enable_json(args.events)
    events.install_signal_handlers()
    t0 = time.perf_counter()
    events.emit(START, command=args.command, argv=argv)
    try:
        events.check_cancel()  # a signal that came while loading
        run_locked(args)  # under the workspace's lock when the command writes to one
    except WorkspaceBusy as e:  # another command is writing to the workspace: nothing was done
        events.emit(ERROR, message=str(e))
        print(f"igs {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BUSY
    except IGSError as e:
        events.emit(ERROR, message=str(e))
        print(f"igs {args.command}: error: {e}", file=sys.stderr)
        return EXIT_USER
    except BrokenPipeError:  # not a disk error: _main's own
        raise
    except OSError as e:
        if e.errno not in DISK_ERRORS:  # a bug, not the machine: the traceback below
            return _internal_error(e)
        msg = str(os_error(e.filename or "?", e, "could not read or write"))
        events.emit(ERROR, message=msg)
        print(f"igs {args.command}: error: {msg}", file=sys.stderr)
        return EXIT_USER
    except (Cancelled, KeyboardInterrupt) as e:
        message = RESTART_MESSAGE if isinstance(e, Cancelled) and not e.resumable else CANCELLED_MESSAGE
        events.emit(CANCELLED, message=message)
        print(f"igs {args.command}: {message}", file=sys.stderr)
        return EXIT_CANCELLED
    except Exception as e:  # a bug, not bad input: keep the traceback but still report one line
        return _internal_error(e)
    events.emit(DONE, command=args.command, seconds=time.perf_counter() - t0)
    return EXIT_OK


def _drop_stdout() -> None:
    """Point stdout at the null device, so that Python's flush at exit does not meet the closed pipe
    again (it would print "Exception ignored ... BrokenPipeError")."""
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), sys.stdout.fileno())
    except (OSError, ValueError):  # stdout has no file descriptor (replaced in-process): nothing to flush
        pass


def _internal_error(e: Exception) -> int:
    events.emit(ERROR, message=f"internal error: {type(e).__name__}: {e}")
    traceback.print_exc()
    return EXIT_INTERNAL
