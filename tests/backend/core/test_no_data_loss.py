"""Nothing is deleted before its replacement is complete: re-imports and priors build their results
next to the old ones and swap them in only when every file is written; a failure leaves the
workspace byte-identical, and a process killed during the swap is finished on the next load."""

import json
import os
from pathlib import Path

import pytest

from backend.capture.importer import ImportConfig, import_capture
from backend.capture.load import load_capture
from backend.commands.cli import main
from backend.core.errors import IGSError
from backend.core.staging import Staging, recover
from tests.support.import_scene import write_capture


def snapshot(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (hidden work folders aside) and its bytes."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and not any(part.startswith(".") for part in p.relative_to(root).parts)}


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """A COLMAP project (images/, sparse/0, gt/albedo, gt/depth) of 8 views, 64x48: imports without SfM."""
    root = tmp_path_factory.mktemp("proj")
    write_capture(root, n=8, width=64, height=48)
    return root


@pytest.fixture
def imported(project, tmp_path):
    ws = tmp_path / "ws"
    assert main(["import", str(project), str(ws), "--albedo", "gt", "--depth", "gt"]) == 0
    return ws


def test_rerunning_the_same_import_keeps_the_priors(project, imported, capsys):
    before = snapshot(imported)
    assert len([k for k in before if k.startswith("albedo/")]) == 8
    assert len([k for k in before if k.startswith("depth/")]) == 8
    assert main(["import", str(project), str(imported)]) == 0
    after = snapshot(imported)
    for k in before:
        if k.startswith(("albedo/", "depth/", "images/", "sparse/")):
            assert after.get(k) == before[k], k
    meta = json.loads((imported / "capture.json").read_text())
    assert meta["priors"] == {"albedo": "gt", "depth": "gt"}
    load_capture(imported, need_albedo=True, need_depth=True)


def test_a_failed_reimport_leaves_the_workspace_as_it_was(project, imported, tmp_path, capsys):
    bad = tmp_path / "bad_project"
    os.system(f"cp -r {project} {bad}")
    frames = sorted((bad / "images").iterdir())
    frames[5].write_bytes(frames[5].read_bytes()[:100])  # one corrupt image, after 5 good ones
    before = snapshot(imported)
    assert main(["import", str(bad), str(imported), "--force"]) == 2
    assert frames[5].name in capsys.readouterr().err
    assert snapshot(imported) == before
    assert not (imported / ".staging").exists() or not any((imported / ".staging").iterdir())
    load_capture(imported, need_albedo=True, need_depth=True)


def test_a_different_reimport_drops_the_priors_that_no_longer_match(project, imported):
    import_capture(project, imported, ImportConfig(selection=ImportConfig().selection.__class__(max_side=32)))
    assert not (imported / "albedo").exists() and not (imported / "depth").exists()
    assert json.loads((imported / "capture.json").read_text())["priors"] == {"albedo": "none", "depth": "none"}
    assert load_capture(imported).size == (32, 24)


def test_failed_priors_keep_the_good_maps(imported, tmp_path, capsys):
    maps = tmp_path / "maps"
    maps.mkdir()
    for k, name in enumerate(sorted(p.name for p in (imported / "albedo").iterdir())):
        src = imported / "albedo" / name
        (maps / name).write_bytes(src.read_bytes()[:60] if k == 6 else src.read_bytes())  # the 7th is corrupt
    before = snapshot(imported)
    assert main(["priors", str(imported), "--albedo", f"folder:{maps}"]) == 2
    assert "unreadable" in capsys.readouterr().err
    assert snapshot(imported) == before
    # with good maps the new set replaces the old one as a whole
    (maps / sorted(os.listdir(maps))[6]).write_bytes((imported / "albedo" / sorted(os.listdir(maps))[6]).read_bytes())
    assert main(["priors", str(imported), "--albedo", f"folder:{maps}"]) == 0
    assert json.loads((imported / "capture.json").read_text())["priors"]["albedo"] == "folder"


def test_a_source_inside_the_workspace_is_refused_before_anything_is_touched(imported, capsys):
    before = snapshot(imported)
    for source in (imported / "sparse" / "0", imported / "images"):
        assert main(["import", str(source), str(imported), "--force"]) == 2
        assert "inside the workspace" in capsys.readouterr().err
        assert snapshot(imported) == before


def test_a_swap_killed_halfway_is_finished_on_the_next_load(tmp_path):
    root = tmp_path / "ws"
    (root / "images").mkdir(parents=True)
    (root / "images" / "a.png").write_text("old")
    (root / "capture.json").write_text("old")
    (root / "albedo").mkdir()
    staging = Staging(root, "test")
    (staging.path(root / "images") / "a.png").parent.mkdir(parents=True, exist_ok=True)
    (staging.path(root / "images") / "a.png").write_text("new")
    staging.path(root / "capture.json").write_text("new")
    staging.remove(root / "albedo")
    # the journal is written, the first move done, then the process dies
    (staging.dir / "journal.json").write_text(json.dumps({"moves": ["images", "capture.json"], "remove": ["albedo"]}))
    os.replace(root / "albedo", staging.dir / "old-albedo")
    recover(root)
    assert (root / "images" / "a.png").read_text() == "new" and (root / "capture.json").read_text() == "new"
    assert not (root / "albedo").exists() and not (root / ".staging" / "test").exists()


def test_staging_outside_its_root_is_refused(tmp_path):
    staging = Staging(tmp_path, "x")
    with pytest.raises(ValueError):
        staging.path(tmp_path.parent / "elsewhere")
    with pytest.raises(IGSError, match="missing"):
        staging.path(tmp_path / "never_written")
        staging.commit()
