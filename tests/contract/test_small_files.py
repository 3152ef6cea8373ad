"""Small files named on the command line are read one way (issue #59, D's file reads and the folder at a
manifest): not UTF-8, a device, a FIFO or a folder is one error naming the file, at once."""

from __future__ import annotations

import os
import resource
import sys
import threading
import time

import pytest

from backend.commands.cli import main
from igs_contract import small_file
from igs_contract.errors import ContractError
from tests.support.train_scene import make_layered_workspace

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="FIFOs and /dev/zero are POSIX")


@pytest.fixture(scope="module")
def layered(tmp_path_factory):
    return make_layered_workspace(tmp_path_factory.mktemp("smallfiles") / "ws", n_per_face=30)


def one_error(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    (line,) = [ln for ln in err.splitlines() if ": error:" in ln]
    return line


@pytest.mark.parametrize("option", ["--cameras", "--path", "--plane"])
def test_a_file_that_is_not_utf8_is_one_error_naming_it(layered, tmp_path, capsys, option):
    """Reproducer D: non-UTF-8 files given to --cameras, --path or --plane raised UnicodeDecodeError."""
    f = tmp_path / "in.json"
    f.write_bytes(b'{"cameras": [], "name": "caf\xe9"}')
    argv = (["edit", "bake", str(layered), "--plane", str(f), "--color", "1,0,0"] if option == "--plane" else
            ["render", str(layered), option, str(f), "--layers", "A", "--out", str(tmp_path / "r")])
    assert main(argv) == 2
    assert f"{f}: the " in (line := one_error(capsys)) and "is not UTF-8 text (byte 0xe9 at offset 28)" in line


def test_light_dev_zero_is_refused_at_once(layered, tmp_path, capsys):
    """Reproducer D: `--light /dev/zero` took 4.7 GB of memory before it failed."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t0 = time.monotonic()
    assert main(["light-bake", str(layered), "--light", "/dev/zero", "--backend", "cpu"]) == 2
    assert time.monotonic() - t0 < 20
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak < 200_000  # KiB: under 200 MB more
    assert "/dev/zero: the lights file is a character device, not a regular file" in one_error(capsys)


def test_light_fifo_does_not_hang(layered, tmp_path, capsys):
    """Reproducer D: a FIFO given to --light hung (and one SIGTERM did not end it)."""
    fifo = tmp_path / "lights.json"
    os.mkfifo(fifo)
    done: list[int] = []
    worker = threading.Thread(target=lambda: done.append(main(["light-bake", str(layered), "--light", str(fifo),
                                                                "--backend", "cpu"])), daemon=True)
    worker.start()
    worker.join(30)
    if not done:  # unblock the reader so the thread ends, then fail
        with open(fifo, "w") as f:
            f.write("{}")
        worker.join(30)
        pytest.fail("light-bake waited on a FIFO")
    assert done == [2] and f"{fifo}: the lights file is a FIFO" in one_error(capsys)


def test_a_folder_at_a_files_manifest_is_an_error_naming_it(layered, tmp_path, capsys):
    """The silent accept: a folder at `<file>.igs.json` was ignored, though an unreadable manifest is an error."""
    src = tmp_path / "s.spz"  # an export to SPZ: what it holds is said only by its manifest
    assert main(["export", str(layered), "--layer", "albedo", "--out", str(src)]) == 0
    (tmp_path / "s.spz.igs.json").unlink()
    (tmp_path / "s.spz.igs.json").mkdir()
    capsys.readouterr()
    assert main(["convert", str(src), str(tmp_path / "out.ply")]) == 2
    assert f"{tmp_path / 's.spz.igs.json'}: the manifest is a folder" in one_error(capsys)
    assert not (tmp_path / "out.ply").exists()


def test_the_reader_caps_and_refuses_at_the_open_file(tmp_path):
    big = tmp_path / "big.json"
    with open(big, "wb") as f:
        f.truncate(small_file.MAX_BYTES + 1)
    with pytest.raises(ContractError, match="larger than 64 MiB"):
        small_file.read_bytes(big, "cameras file")
    assert small_file.read_bytes(big, "x", limit=small_file.MAX_BYTES + 1) == b"\0" * (small_file.MAX_BYTES + 1)
    link = tmp_path / "link.json"
    link.symlink_to(big)
    with pytest.raises(ContractError, match="is a symbolic link"):
        small_file.read_bytes(link, "lock", follow=False)
    with pytest.raises(FileNotFoundError):
        small_file.read_bytes(tmp_path / "missing.json")
