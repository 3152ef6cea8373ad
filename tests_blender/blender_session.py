"""The Debian root with Blender 5.2 and Xvfb, shared by the real-window tests and the viewport benchmark.

``scripts/blender_root.sh`` builds the root once (cached outside the repository); :func:`in_root`
runs a shell script inside it with a clean environment, :class:`Mounts` gives it /proc and
/dev/shm while a session runs, :func:`copy_sources` copies the files git would ship and
:func:`copy_driver` the script Blender runs, with the module it imports.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
ROOT_SCRIPT = REPO / "scripts" / "blender_root.sh"
DISPLAY = ":91"


def why_not() -> str | None:
    if os.name != "posix" or os.geteuid() != 0:
        return "the real-window tests need root (debootstrap and chroot build Debian's Blender 5.2)"
    if shutil.which("debootstrap") is None:
        return "the real-window tests need debootstrap (apt-get install debootstrap)"
    if shutil.which("chroot") is None:
        return "the real-window tests need chroot"
    return None


def in_root(root: Path, script: str, timeout: float, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run a shell script inside the root with a clean environment."""
    base = {"PATH": "/usr/sbin:/usr/bin:/sbin:/bin", "HOME": "/root", "LANG": "C.UTF-8",
            "PIP_CERT": "/etc/igs-host-ca.pem", "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    argv = ["chroot", str(root), "/usr/bin/env", "-i", *(f"{k}={v}" for k, v in {**base, **(env or {})}.items()),
            "/bin/sh", "-c", script]
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout)


class Mounts:
    """/proc and a tmpfs /dev/shm inside the root, for as long as the session runs."""

    def __init__(self, root: Path):
        self.root, self.done = root, []

    def __enter__(self):
        for target, args in (("proc", ["-t", "proc", "proc"]), ("dev/shm", ["-t", "tmpfs", "tmpfs"])):
            path = self.root / target
            path.mkdir(parents=True, exist_ok=True)
            if subprocess.run(["mountpoint", "-q", str(path)]).returncode != 0:
                subprocess.run(["mount", *args, str(path)], check=True)
                self.done.append(path)
        return self

    def __exit__(self, *exc):
        for path in reversed(self.done):
            subprocess.run(["umount", "-l", str(path)], check=False)


def build_root() -> Path:
    """The root's path, built first when missing (needs root and debootstrap)."""
    res = subprocess.run([str(ROOT_SCRIPT)], capture_output=True, text=True, timeout=1800)
    if res.returncode != 0:
        raise RuntimeError(f"building the Blender root failed:\n{res.stderr[-3000:]}")
    return Path(res.stdout.strip().splitlines()[-1])


def copy_driver(driver: str, run: Path) -> None:
    """``tests_blender/<driver>`` as ``run/driver.py``, with the modules drivers import beside it
    (``window_driver.py`` and the window suite's ``driver_*.py``)."""
    shutil.copy2(REPO / "tests_blender" / driver, run / "driver.py")
    for module in ("window_driver.py", *sorted(p.name for p in (REPO / "tests_blender").glob("driver_*.py"))):
        shutil.copy2(REPO / "tests_blender" / module, run / module)


def copy_sources(dst: Path) -> None:
    """The files git would ship (tracked plus untracked-not-ignored), as the extension build sees them."""
    names = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=REPO, check=True,
                           capture_output=True).stdout.decode().split("\0")
    for name in filter(None, names):
        src = REPO / name
        if src.is_file():
            (dst / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / name)
