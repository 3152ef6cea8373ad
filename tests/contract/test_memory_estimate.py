"""The memory estimate both sides compute: the machine's room from /proc/meminfo and the cgroup, the defaults the
backend trains with, and the workspace's line that the Blender panel shows before a job starts."""

import pytest

from backend.capture.transforms_io import write_transforms
from backend.commands.train import DEFAULT_MAX_GAUSSIANS
from backend.core.cameras import Camera
from backend.train.intrinsic.config import DecomposeConfig
from igs_contract import memory_estimate as me
from igs_contract.errors import ContractError


def test_the_defaults_are_the_backends():
    assert me.DEFAULT_GAUSSIANS == {"decompose": DecomposeConfig().albedo.densify.max_gaussians,
                                    "train-3dgs": DEFAULT_MAX_GAUSSIANS}


def test_room_comes_from_meminfo_and_the_cgroup(tmp_path, monkeypatch):
    info = tmp_path / "meminfo"
    info.write_text("MemTotal:       24000000 kB\nMemFree:  100 kB\nMemAvailable:   8000000 kB\n")
    assert me.meminfo_available(info) == 8000000 * 1024
    assert me.meminfo_available(tmp_path / "none") is None
    cg = tmp_path / "cg"
    cg.mkdir()
    (cg / "memory.max").write_text("max\n")
    assert me.cgroup_room(cg) is None  # no limit
    (cg / "memory.max").write_text("4294967296\n")
    (cg / "memory.current").write_text("1073741824\n")
    assert me.cgroup_room(cg) == 3 << 30
    monkeypatch.setenv(me.LIMIT_ENV, "6G")
    assert me.memory_limit(held=123) == (6 << 30, me.LIMIT_ENV)
    monkeypatch.setenv(me.LIMIT_ENV, "lots")
    with pytest.raises(ContractError, match="IGS_MEMORY_LIMIT must be a size"):
        me.memory_limit()


def test_the_workspace_line_reads_the_views_from_transforms_json(tmp_path, monkeypatch):
    cams = [Camera.look_at(f"f{i}.png", [2, i, 1], [0, 0, 0], [0, 0, 1], 1920, 1080, 60) for i in range(300)]
    write_transforms(tmp_path / "transforms.json", cams)
    monkeypatch.setenv(me.LIMIT_ENV, "3G")
    line = me.workspace_line(tmp_path, "decompose")
    expected = me.over_limit_line("decompose", me.DECOMPOSE, 300, 1920, 1080, me.DEFAULT_GAUSSIANS["decompose"],
                                  3 << 30, me.LIMIT_ENV)
    assert line == expected and line.startswith("decompose: estimated peak memory") and "for 300 views at 1920x1080" in line
    monkeypatch.setenv(me.LIMIT_ENV, "1T")
    assert me.workspace_line(tmp_path, "decompose") is None  # it fits
    assert me.workspace_line(tmp_path / "no_workspace", "decompose") is None  # the command checks for itself
