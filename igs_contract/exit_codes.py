"""Exit codes of ``python -m backend`` / ``igs``; the add-on reads a job's outcome from them."""

EXIT_OK = 0
"""The command finished."""
EXIT_INTERNAL = 1
"""A bug: the traceback is on stderr, the ``error`` event's message starts with "internal error"."""
EXIT_USER = 2
"""Bad input, bad options or a machine that refused (full disk): one message naming the cause."""
EXIT_CANCELLED = 130
"""Stopped on request (128 + SIGINT); the workspace keeps its last checkpoint."""
