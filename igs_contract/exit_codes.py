"""Exit codes of ``python -m backend`` / ``igs``; the add-on reads a job's outcome from them."""

EXIT_OK = 0
"""The command finished."""
EXIT_INTERNAL = 1
"""A bug: the traceback is on stderr, the ``error`` event's message starts with "internal error"."""
EXIT_USER = 2
"""Bad input, bad options or a machine that refused (full disk): one message naming the cause."""
EXIT_BUSY = 75
"""Another command is writing to the workspace (it holds the workspace's lock,
:mod:`igs_contract.workspace_lock`); nothing was done. The ``error`` event's message names the holder.
75 is sysexits' EX_TEMPFAIL: the same command succeeds later."""
EXIT_CANCELLED = 130
"""Stopped on request (128 + SIGINT); the workspace keeps its last checkpoint."""
EXIT_PIPE = 141
"""The reader of stdout went away (``igs info | head``): stopped quietly, as a shell reports a
process ended by SIGPIPE (128 + 13). What was written is kept, as after a cancel."""
