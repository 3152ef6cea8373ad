"""Ctrl-C at any moment is a clean cancel with exit code 130 (a second one stops at once, still 130),
and in ``--events`` mode every stdout line is a typed event the Blender add-on's client parses."""

import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from intrinsic_splats.igs_blender.jobs.client import JobState, parse_event  # noqa: E402

from backend.commands.cli import main
from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)
from tests.support.train_scene import make_layered_workspace

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    root = tmp_path_factory.mktemp("sig") / "box"
    make_layered_workspace(root)
    return root


def _interpreter_start() -> float:
    """Seconds this machine takes now to start Python up to the first line of a program (site and the
    editable install's path hook imported). A SIGINT before that lands in the interpreter's own start-up,
    which no program can catch (Python dies with "Failed to import the site module"): on a loaded
    machine that took more than the 0.1 s the first test waits, so the delays count from here."""
    t0 = time.monotonic()
    subprocess.run([sys.executable, "-c", "pass"], cwd=REPO, check=True)
    return time.monotonic() - t0


def _run_and_signal(box, delays, events=False):
    """Start a long training, send SIGINT after each delay (seconds from the interpreter's start-up)."""
    cmd = [sys.executable, "-m", "backend", *(["--events"] if events else []), "train-3dgs", str(box),
           "--iterations", "100000", "--restart", "--checkpoint-every", "100000"]
    start = _interpreter_start()
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    t0 = time.monotonic() + start
    for d in delays:
        time.sleep(max(0.0, d - (time.monotonic() - t0)))
        proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out.decode(), err.decode()


@pytest.mark.parametrize("delay", [0.1, 0.6, 1.4])
def test_ctrl_c_while_the_command_loads_is_a_clean_cancel(box, delay):
    code, _, err = _run_and_signal(box, [delay])
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    assert "cancelled" in err.strip().splitlines()[-1]


def test_a_second_ctrl_c_stops_at_once_with_130(box):
    code, out, err = _run_and_signal(box, [0.3, 0.9], events=True)
    assert code == 130, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err
    evs = [json.loads(line) for line in out.splitlines() if line.strip()]
    assert evs and evs[-1]["event"] == "cancelled"


def test_a_second_ctrl_c_during_training_stops_with_130(box):
    cmd = [sys.executable, "-m", "backend", "--events", "train-3dgs", str(box), "--iterations", "100000",
           "--restart", "--checkpoint-every", "100000"]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    for line in proc.stdout:  # wait until the loop runs
        if parse_event(line.decode()) and json.loads(line)["event"] == "progress":
            break
    proc.send_signal(signal.SIGINT)
    time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    rest = proc.stdout.read().decode()
    assert proc.wait(timeout=60) == 130
    evs = [parse_event(line) for line in rest.splitlines() if line.strip()]
    assert all(evs) and evs[-1]["event"] == "cancelled"


@pytest.mark.parametrize("events", [False, True])
def test_a_reader_that_goes_away_stops_the_command_quietly_with_141(box, events):
    """`igs info WS | head`: the pipe is closed before the command writes, as head does after its lines."""
    cmd = [sys.executable, "-m", "backend", *(["--events"] if events else []), "info", str(box)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader is gone before the interpreter has even started
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141, err
    assert err == ""  # no traceback, not even Python's "Exception ignored" at exit


def _events_of(argv, capsys):
    capsys.readouterr()
    code = main(["--events", *argv])
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines() if line.strip()]
    untyped = [line for line in lines if parse_event(line) is None]
    assert untyped == [], f"{argv[0]}: stdout lines that are not events: {untyped[:3]}"
    state = JobState(argv[0])
    for line in lines:
        state.apply(parse_event(line))
    return code, [parse_event(line) for line in lines], state


def test_every_events_line_is_a_typed_event(box, tmp_path, capsys):
    commands = [
        ["info", str(box)],
        ["info", str(box), "--json"],
        ["train-3dgs", str(box), "--iterations", "4", "--restart"],
        ["render", str(box), "--turntable", "--frames", "2", "--size", "16", "12", "--out", str(tmp_path / "r")],
        ["decompose", str(box), "--iterations", "8", "--restart"],
    ]
    for argv in commands:
        code, evs, state = _events_of(argv, capsys)
        assert code == 0, (argv, state.error)
        assert state.done and evs[-1]["event"] == "done"
        results = [e for e in evs if e["event"] == "result"]
        assert len(results) == 1 and results[0]["command"] == argv[0] and isinstance(results[0]["data"], dict)
        assert results[0] in state.other  # the client keeps events it has no special use for
    # the same commands without --events still print their summary on stdout
    capsys.readouterr()
    assert main(["info", str(box), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["views"] == 8


def test_no_command_module_prints_to_stdout_behind_the_events_back():
    """Command output goes through events.result/log; bench scripts (not igs commands) may print."""
    offenders = []
    for path in sorted((REPO / "backend").rglob("*.py")):
        if path.parent.name == "bench" or path.name == "events.py":  # the benchmarks stand above the commands
            continue
        for n, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#")[0]
            if re.search(r"\bprint\(", code) and "file=" not in code:
                offenders.append(f"{path.relative_to(REPO)}:{n}")
    assert offenders == []
