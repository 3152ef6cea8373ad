"""The add-on's backend client (pure Python, no bpy): events, progress, cancel, errors, environment checks.

A fake backend (a script standing in for the interpreter) speaks the events protocol so that
progress, cancel and crashes are tested deterministically; the real backend is used for what it
already offers (argument errors, ``info``, the environment check).
"""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

from intrinsic_splats.igs_blender import jobs  # noqa: E402
from intrinsic_splats.igs_blender.env import backend_env  # noqa: E402
from intrinsic_splats.igs_blender.errors import UserError  # noqa: E402
from intrinsic_splats.igs_blender.jobs.client import (  # noqa: E402
    BackendError,
    BackendJob,
    JobState,
    backend_command,
    parse_event,
)

from tests.support import addon_package  # noqa: E402, F401 (the extension as a package: the add-on imports relatively)
from tests.support.fake_backend import FAKE_BACKEND  # noqa: E402

PYTHON = sys.executable



@pytest.fixture(scope="module")
def fake_backend(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("fake") / "python"
    path.write_text(FAKE_BACKEND.format(python=PYTHON))
    path.chmod(path.stat().st_mode | stat.S_IXUSR)
    return path


def run_fake(fake: Path, mode: str, monkeypatch, **kw) -> BackendJob:
    monkeypatch.setenv("IGS_FAKE_MODE", mode)
    argv, env = backend_command(fake, ["decompose", "/ws"])
    return BackendJob(argv, "Decompose", env=env, **kw).start()


def test_parse_event_keeps_only_json_objects_with_an_event_key():
    assert parse_event('{"event": "log", "message": "hi"}') == {"event": "log", "message": "hi"}
    for line in ("", "plain text", "[1, 2]", '{"no_event": 1}', '{"event": 3}', "{broken json"):
        assert parse_event(line) is None


def test_job_state_progress_spans_expected_stages():
    st = JobState("Decompose", expected_stages=3)
    st.apply({"event": "stage", "stage": "albedo", "total": 10})
    st.apply({"event": "progress", "stage": "albedo", "step": 5, "total": 10, "eta_s": 65.0, "loss": 0.123456})
    assert st.fraction == pytest.approx(0.5 / 3)
    assert "albedo 5/10" in st.status_text() and "loss 0.1235" in st.status_text() and "1:05 left" in st.status_text()
    st.apply({"event": "stage", "stage": "shading", "total": 10})
    assert st.stages["albedo"].state == "done"
    assert st.fraction == pytest.approx(1 / 3)


def test_job_follows_stages_progress_and_outputs(fake_backend, monkeypatch):
    job = run_fake(fake_backend, "ok", monkeypatch)
    assert job.wait(timeout=20) == 0
    assert job.outcome == "ok"
    st = job.state
    assert [s.name for s in st.stages.values()] == ["albedo", "shading"]
    assert all(s.state == "done" and s.step == 4 for s in st.stages.values())
    assert st.metrics["gaussians"] == 400
    assert st.outputs == [("ply", "/tmp/albedo.ply")]
    assert st.fraction == 1.0
    assert "a plain line that is not an event" in job.stdout_tail
    assert job.report() == "Decompose finished in 0.2 s"


def test_poll_never_blocks_while_the_backend_is_silent(fake_backend, monkeypatch):
    job = run_fake(fake_backend, "stubborn", monkeypatch)  # one stage event, then 60 s of silence
    try:
        t0 = time.monotonic()
        while not job.state.stages:
            job.poll()
            assert time.monotonic() - t0 < 30
            time.sleep(0.02)
        worst = 0.0
        for _ in range(20):
            t = time.perf_counter()
            assert job.poll() == []
            worst = max(worst, time.perf_counter() - t)
            time.sleep(0.02)
        assert job.running and worst < 0.1, f"poll took {worst:.3f} s"
    finally:
        job.kill()
        job.wait(timeout=10)


def test_cancel_stops_the_backend_and_reports_a_resumable_cancel(fake_backend, monkeypatch):
    job = run_fake(fake_backend, "slow", monkeypatch)
    t0 = time.monotonic()
    while job.state.stages.get("albedo") is None or job.state.stages["albedo"].step < 3:
        job.poll()
        assert time.monotonic() - t0 < 15, "no progress from the fake backend"
        time.sleep(0.02)
    job.cancel()
    assert job.wait(timeout=10) == 130
    assert job.outcome == "cancelled"
    assert "cancelled" in job.report() and "checkpoint" in job.report()


def test_cancel_escalates_to_a_kill_when_the_backend_ignores_it(fake_backend, monkeypatch):
    job = run_fake(fake_backend, "stubborn", monkeypatch, grace_s=0.3)
    while not job.state.stages:
        job.poll()
        time.sleep(0.02)
    job.cancel()
    rc = job.wait(timeout=10)
    assert rc == -signal.SIGKILL
    assert job.outcome == "cancelled"
    assert "had to be stopped" in job.report()


def test_a_crash_is_one_readable_report(fake_backend, monkeypatch):
    job = run_fake(fake_backend, "crash", monkeypatch)
    assert job.wait(timeout=20) == 1
    assert job.outcome == "failed"
    report = job.report()
    assert "RuntimeError: boom in the rasteriser" in report and "\n" not in report
    assert job.state.stages["albedo"].state == "running"  # never completed


def test_a_user_error_reports_the_backend_message(fake_backend, monkeypatch):
    job = run_fake(fake_backend, "user", monkeypatch)
    assert job.wait(timeout=20) == 2
    assert job.report() == "Decompose failed: /ws/images: missing images folder"


def test_missing_or_unset_interpreter_is_a_clear_error(tmp_path):
    with pytest.raises(BackendError, match="Backend interpreter not found.*Preferences"):
        BackendJob([str(tmp_path / "nope" / "python"), "-m", "backend"], "Import").start()
    with pytest.raises(BackendError, match="No backend interpreter is set"):
        BackendJob(["", "-m", "backend"], "Import").start()
    not_exe = tmp_path / "python"
    not_exe.write_text("")
    with pytest.raises(BackendError, match="not an executable"):
        BackendJob([str(not_exe), "-m", "backend"], "Import").start()


def test_real_backend_unknown_command_is_readable():
    argv, env = backend_command(PYTHON, ["no-such-command", "x"], ROOT)
    job = BackendJob(argv, "Frobnicate", env=env).start()
    assert job.wait(timeout=60) == 2
    assert "has no such command yet" in job.report() and "no-such-command" in job.report()


def test_real_backend_user_error_is_its_one_line_message(tmp_path):
    argv, env = backend_command(PYTHON, ["info", tmp_path / "nothing"], ROOT)
    job = BackendJob(argv, "Info", env=env).start()
    assert job.wait(timeout=90) == 2
    assert job.state.error is not None and str(tmp_path / "nothing") in job.state.error
    assert job.report() == f"Info failed: {job.state.error}"


def test_environment_check_lists_packages_and_backend_commands():
    job = backend_env.check_job(PYTHON, str(ROOT)).start()
    assert job.wait(timeout=90) == 0, job.report()
    ok, lines = backend_env.env_report_lines(job)
    assert ok, lines
    assert lines[0].startswith(f"Python {sys.version_info.major}.{sys.version_info.minor}.")
    assert any(line.startswith("All ") and "pinned packages present" in line for line in lines)
    assert any(line.startswith("Backend commands:") for line in lines)


def _tiny_wheel(folder: Path) -> Path:
    """A pure-Python wheel 'igs-probe 1.0' built by hand, so pip can install it offline."""
    whl = folder / "igs_probe-1.0-py3-none-any.whl"
    files = {"igs_probe.py": "VALUE = 42\n",
             "igs_probe-1.0.dist-info/METADATA": "Metadata-Version: 2.1\nName: igs-probe\nVersion: 1.0\n",
             "igs_probe-1.0.dist-info/WHEEL": "Wheel-Version: 1.0\nGenerator: test\nRoot-Is-Purelib: true\nTag: py3-none-any\n"}
    record = "".join(f"{name},,\n" for name in files) + "igs_probe-1.0.dist-info/RECORD,,\n"
    with zipfile.ZipFile(whl, "w") as z:
        for name, text in files.items():
            z.writestr(name, text)
        z.writestr("igs_probe-1.0.dist-info/RECORD", record)
    return whl


def test_create_environment_installs_pins_offline_and_check_reports_what_is_missing(tmp_path):
    """The 'Create Backend Environment' script end to end, offline: a venv, pip installing a pinned
    wheel from a local folder; then the check on that venv names the backend packages it lacks."""
    _tiny_wheel(tmp_path)
    env_dir = tmp_path / "venv"
    argv = backend_env.script_argv(PYTHON, "setup_env.py", [
        "--venv", str(env_dir), "--requirements-json", json.dumps(["igs-probe==1.0"]),
        "--pip-arg=--no-index", f"--pip-arg=--find-links={tmp_path}"])
    job = BackendJob(argv, "Create backend environment", expected_stages=1).start()
    assert job.wait(timeout=120) == 0, job.report()
    python = backend_env.venv_python(env_dir)
    assert job.state.outputs == [("interpreter", str(python))]
    out = subprocess.run([str(python), "-c", "import igs_probe; print(igs_probe.VALUE)"], capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "42"

    check = backend_env.check_job(str(python), str(ROOT)).start()
    assert check.wait(timeout=60) == 0, check.report()
    ok, lines = backend_env.env_report_lines(check)
    assert not ok
    missing = next(line for line in lines if line.startswith("Missing:"))
    assert "torch==" in missing and "numpy==" in missing
    assert any(line.startswith("Backend does not import") for line in lines)


def test_pinned_requirements_come_from_the_shipped_pyproject():
    reqs = backend_env.pinned_requirements(ROOT)
    assert any(r.startswith("torch==") for r in reqs) and any(r.startswith("bpy==") for r in reqs)
    assert not any(r.startswith("bpy") for r in backend_env.pinned_requirements(ROOT, include_bpy=False))
    assert os.path.isfile(ROOT / "backend" / "__main__.py")


def test_backend_sources_need_the_contract_beside_the_backend(tmp_path):
    """The backend imports igs_contract from the same folder: a Backend Sources folder without it is refused."""
    assert backend_env.backend_root(str(ROOT)) == ROOT
    (tmp_path / "backend").mkdir()
    (tmp_path / "backend" / "__main__.py").write_text("")
    with pytest.raises(UserError, match="igs_contract/__init__.py is missing"):
        backend_env.backend_root(str(tmp_path))


class _Props:
    """What ``Scene.igs`` holds of a job, for the job's life without Blender."""

    job_label = job_status = job_stages = ""
    job_running = False
    job_progress = 0.0


def _followed(fake: Path, mode: str, monkeypatch, load) -> tuple[bool, str, _Props, int]:
    """Start, follow and finish a stand-in job as every operator and the light bake do; (ok, message, the
    props the panel shows, how many ticks it took)."""
    monkeypatch.setenv("IGS_FAKE_MODE", mode)
    argv, env = backend_command(fake, ["decompose", "/ws"])
    job, props, ticks = BackendJob(argv, "Decompose", env=env), _Props(), 0
    jobs.start(job, props)
    assert jobs.current() is job and props.job_label == "Decompose" and props.job_running
    ended = []
    while not jobs.follow(job, props, ended.append):
        ticks += 1
        time.sleep(0.05)
        assert ticks < 400, "the stand-in job never ended"
    assert ended == [job] and not props.job_running
    return (*jobs.finish(job, load), props, ticks)


def test_one_job_life_starts_follows_and_finishes(fake_backend, monkeypatch):
    ok, msg, props, _ = _followed(fake_backend, "ok", monkeypatch, lambda: "loaded")
    assert (ok, msg) == (True, "loaded") and props.job_progress == pytest.approx(1.0)

    def broken_load() -> str:
        raise OSError("layers/albedo.ply: no such file")

    ok, msg, _, _ = _followed(fake_backend, "ok", monkeypatch, broken_load)
    assert not ok and msg == "Decompose finished, but loading its results failed: layers/albedo.ply: no such file"
    ok, msg, props, _ = _followed(fake_backend, "user", monkeypatch, lambda: "never called")
    assert not ok and msg == props.job_status and "never called" not in msg


def test_a_second_job_does_not_start_while_one_runs(fake_backend, monkeypatch):
    monkeypatch.setenv("IGS_FAKE_MODE", "slow")
    argv, env = backend_command(fake_backend, ["decompose", "/ws"])
    first, props = BackendJob(argv, "Decompose", env=env), _Props()
    jobs.start(first, props)
    try:
        with pytest.raises(jobs.START_ERRORS):
            jobs.start(BackendJob(argv, "Decompose", env=env), props)
        assert jobs.current() is first
    finally:
        jobs.stop_all()
