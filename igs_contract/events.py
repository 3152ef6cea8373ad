"""The JSON-lines events ``python -m backend --events <command>`` writes on stdout.

Every stdout line is one JSON object whose ``event`` key names the event; its other keys are the
fields below. Human text (tqdm bars, messages) goes to stderr. Readers ignore a line that is not a
JSON object with a string ``event`` (:func:`parse_event`), and events and fields they do not know.

- ``start``      ``command`` (str), ``argv`` (list of str): the command began.
- ``stage``      ``stage`` (str), ``total`` (int), ``unit`` (str: ``it`` for steps, ``B`` for bytes):
  a stage of ``total`` steps begins.
- ``progress``   ``stage``, ``step`` (int), ``total`` (int), ``eta_s`` (float or null: seconds left in
  the stage); every other key is a metric (``loss``, ``psnr``, ``gaussians``...).
- ``log``        ``message`` (str): a line for the user.
- ``output``     ``kind`` (str), ``path`` (str): a file or folder the user may want to open.
- ``result``     ``command`` (str), ``data`` (object): the command's summary (without ``--events``
  the command prints it as JSON instead).
- ``done``       ``command`` (str), ``seconds`` (float): the command finished (exit code 0).
- ``error``      ``message`` (str): the command failed; one message naming the cause (exit code 2;
  75 when another command is writing to the workspace, the message naming it; or 1 with a message
  starting "internal error").
- ``cancelled``  ``message`` (str): stopped on request (exit code 130); the workspace keeps its last
  checkpoint.
- ``env``        the environment report of the add-on's ``check_env.py`` (its docstring lists the fields).
"""

from __future__ import annotations

import json
from typing import Any

EVENT = "event"
"""The key that names the event."""

START = "start"
STAGE = "stage"
PROGRESS = "progress"
LOG = "log"
OUTPUT = "output"
RESULT = "result"
DONE = "done"
ERROR = "error"
CANCELLED = "cancelled"
ENV = "env"

FIELDS = {
    START: ("command", "argv"),
    STAGE: ("stage", "total", "unit"),
    PROGRESS: ("stage", "step", "total", "eta_s"),
    LOG: ("message",),
    OUTPUT: ("kind", "path"),
    RESULT: ("command", "data"),
    DONE: ("command", "seconds"),
    ERROR: ("message",),
    CANCELLED: ("message",),
}
"""The fields of each event (a ``progress`` event's other keys are metrics; ``env`` has its own)."""


def parse_event(line: str) -> dict[str, Any] | None:
    """The event on one stdout line, or None when the line is not a JSON object with an ``event`` key."""
    line = line.strip()
    if not line.startswith("{"):
        return None
    try:
        obj = json.loads(line)
    except ValueError:
        return None
    if not isinstance(obj, dict) or not isinstance(obj.get(EVENT), str):
        return None
    return obj
