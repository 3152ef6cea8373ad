"""The memory limit known before the work: the estimate against a measured run, the one-line stop over
the limit with a --downscale that fits, and a run killed from outside reported by the next command."""

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from backend.bench.bench_memory import measure
from backend.bench.scaled_capture import make_scaled_workspace
from backend.core.errors import IGSError
from backend.core.run_record import killed_run, record_path
from backend.train.memory_limit import DECOMPOSE, check_memory, parse_bytes
from tests.support.synth_capture import needs_synth_renderer

ROOT = Path(__file__).resolve().parents[3]
ARGS = ["--iterations", "12", "--max-gaussians", "3000", "--residual-points", "300", "--backend", "cpu",
        "--device", "cpu"]
GIB = 1 << 30


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    needs_synth_renderer()
    synth = pytest.importorskip("backend.synth.run")
    ws = tmp_path_factory.mktemp("memory") / "test_ws"
    synth.synthesize(ws, preset="test", seed=0)
    return ws


def _igs(*argv: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "backend", *argv], cwd=ROOT, capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=600)


def test_estimate_is_within_a_quarter_of_a_measured_run(source, tmp_path):
    ws = make_scaled_workspace(source, tmp_path / "ws", 24, 256, 192)
    r = measure(["decompose", str(ws), *ARGS], 12 * GIB, "albedo")
    assert r["exit"] == 0 and not r["killed_at_cap"]
    line = next(m for m in r["logs"] if "estimated peak memory" in m)
    estimate = float(re.search(r"estimated peak memory ([0-9.]+) GiB", line).group(1))
    measured = r["peak_rss_mib"] / 1024
    # the child's own peak (measure reads its VmHWM: its ru_maxrss would start from this test process's peak)
    assert measured <= 1.25 * estimate, (estimate, measured, line)  # never short by more than a quarter
    if sys.version_info[:2] == (3, 13):
        # the model is fitted on Python 3.13's stack (Blender 5.1-5.3's); on 3.11 the same run holds less
        # (0.76 GiB in CI against 1.06 here), so there the estimate is only checked on the safe side
        assert abs(estimate - measured) <= 0.25 * measured, (estimate, measured, line)


def test_the_measured_peak_is_the_childs_own():
    # a parent that once held 2 GiB: the child's ru_maxrss starts from that (it is spawned from the parent's
    # address space), its own high-water mark does not (igs --version: torch imported, about 0.7 GiB)
    held = np.ones(1 << 28)  # 2 GiB, touched
    del held
    r = measure(["--version"], 12 * GIB, "albedo")
    assert r["exit"] == 0 and 10 < r["peak_rss_mib"] < 1500, r


def test_over_the_limit_stops_at_once_with_one_line(source, tmp_path, monkeypatch):
    ws = make_scaled_workspace(source, tmp_path / "big", 16, 1024, 768)
    gaussians = 3000  # --max-gaussians: the albedo's budget, the largest set a stage trains
    fixed = DECOMPOSE.base + DECOMPOSE.per_gaussian * gaussians
    whole = DECOMPOSE.estimate(16, 1024 * 768, gaussians)
    limit = int(fixed + 0.4 * (whole - fixed))
    t = time.perf_counter()
    p = _igs("decompose", str(ws), *ARGS, env={"IGS_MEMORY_LIMIT": str(limit)})
    assert p.returncode == 2 and time.perf_counter() - t < 60
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "Traceback" not in p.stderr
    assert re.search(r"estimated peak memory [0-9.]+ GiB for 16 views at 1024x768 is over the limit [0-9.]+ GiB "
                     r"\(IGS_MEMORY_LIMIT\); use --downscale [0-9.]+ \(or import with --max-side \d+\)", lines[0])
    assert not (ws / "layers").exists()  # nothing was trained
    factor = float(re.search(r"--downscale ([0-9.]+)", lines[0]).group(1))
    side = int(re.search(r"--max-side (\d+)", lines[0]).group(1))
    assert factor > 1 and side == int(1024 / factor)
    monkeypatch.setenv("IGS_MEMORY_LIMIT", str(limit))
    w, h = round(1024 / factor), round(768 / factor)
    check_memory("decompose", DECOMPOSE, 16, w, h, gaussians, factor)  # the suggestion fits
    with pytest.raises(IGSError, match="over the limit"):
        check_memory("decompose", DECOMPOSE, 16, 1024, 768, gaussians)


def test_limit_sizes_parse_or_fail_in_one_line():
    assert parse_bytes("8G") == 8 * GIB and parse_bytes("512M") == 512 << 20 and parse_bytes("1000") == 1000
    for bad in ("", "lots", "-1G", "nanG"):
        with pytest.raises(IGSError, match="IGS_MEMORY_LIMIT must be a size"):
            parse_bytes(bad)


def test_a_killed_run_is_reported_by_the_next_command(source, tmp_path):
    ws = make_scaled_workspace(source, tmp_path / "ws", 16, 128, 96)
    proc = subprocess.Popen([sys.executable, "-m", "backend", "decompose", str(ws), *ARGS[:1], "400", *ARGS[2:]],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    rec = {}
    while time.time() < deadline and proc.poll() is None:
        try:
            rec = json.loads(record_path(ws).read_text())
        except (OSError, ValueError):
            rec = {}
        if (rec.get("progress") or {}).get("stage") == "albedo":  # recorded every few seconds while it trains
            break
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)  # as the kernel's out-of-memory killer does
    proc.wait()
    assert rec.get("state") == "running" and rec["progress"]["stage"] == "albedo"
    line = killed_run(ws)
    assert line is not None and "was killed at albedo" in line and "memory" in line
    # the next command says so first, then does its own work (here: stops over a tiny limit)
    p = _igs("decompose", str(ws), *ARGS, env={"IGS_MEMORY_LIMIT": "1M"})
    assert p.returncode == 2
    assert re.search(r"decompose: note: the last run \(decompose, started [^)]+\) was killed at albedo \d+/400 "
                     r"without finishing, most likely for memory", p.stderr)
    # a command stopped by its checks (here: the memory limit) leaves the record as it was
    assert json.loads(record_path(ws).read_text())["state"] == "running"
    p = _igs("decompose", str(ws), *ARGS, "--restart")  # a run that finishes closes it (other settings: --restart)
    assert p.returncode == 0 and "was killed" in p.stderr
    assert json.loads(record_path(ws).read_text())["state"] == "finished"
    assert killed_run(ws) is None
