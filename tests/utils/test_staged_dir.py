"""Folder outputs appear complete or not at all (``slimseg.utils.atomic.staged_dir``), and the
CLI's one-line errors give way to the traceback under ``--debug`` / ``SLIMSEG_DEBUG``."""

from __future__ import annotations

from pathlib import Path

import pytest

from slimseg.cli.main import main
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import staged_dir
from slimseg.utils.outputs import MANIFEST


def _tree(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): p.read_text() if p.is_file() else "/"
        for p in sorted(folder.rglob("*"))
    }


def _earlier_run(out: Path) -> None:
    with staged_dir(out, command="test") as stage:
        (stage / "masks").mkdir(parents=True)
        (stage / "masks" / "1.png").write_text("old 1")
        (stage / "masks" / "9.png").write_text("old 9, a frame the new run does not have")
        (stage / "frames.csv").write_text("old csv")
        (stage / "trajectories").mkdir()
        (stage / "trajectories" / "run1.txt").write_text("old")


def test_a_finished_run_replaces_its_entries_whole(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _earlier_run(out)
    with staged_dir(out, command="test") as stage:
        assert stage.parent == tmp_path and stage.name.startswith(".out.")
        (stage / "masks").mkdir()
        (stage / "masks" / "1.png").write_text("new 1")
        (stage / "frames.csv").write_text("new csv")
    tree = _tree(out)
    assert MANIFEST in tree
    del tree[MANIFEST]
    assert tree == {
        "frames.csv": "new csv",
        "masks": "/",
        "masks/1.png": "new 1",  # the old 9.png went with the old masks/
    }  # trajectories/ of the earlier run must not mix in with this one's
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no temporary left


def test_a_folder_with_a_users_file_is_refused_before_anything(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _earlier_run(out)
    (out / "notes.txt").write_text("the user's own file")
    before = _tree(out)
    with (
        pytest.raises(SlimsegError, match=r"--out .*out holds files slimseg did not write "
                                          r"\(notes.txt\)"),
        staged_dir(out),
    ):  # fmt: skip
        pytest.fail("the body must not run")
    assert _tree(out) == before


def test_a_failed_run_leaves_the_folder_as_it_was(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _earlier_run(out)
    before = _tree(out)
    with pytest.raises(SlimsegError, match="frame 5"), staged_dir(out) as stage:
        (stage / "masks").mkdir()
        (stage / "masks" / "1.png").write_text("new 1")
        raise SlimsegError("frame 5 is corrupt")
    assert _tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_failed_run_into_a_new_path_leaves_nothing(tmp_path: Path) -> None:
    with pytest.raises(RuntimeError), staged_dir(tmp_path / "a" / "b" / "out") as stage:
        (stage / "frames.csv").write_text("partial")
        raise RuntimeError("midway")
    assert list(tmp_path.iterdir()) == []  # the parents it made are gone too
    with staged_dir(tmp_path / "empty"):
        pass
    assert list(tmp_path.iterdir()) == []  # a run that wrote nothing makes no folder


def test_a_file_in_the_way_is_refused_before_anything(tmp_path: Path) -> None:
    (tmp_path / "taken").write_text("x")
    with (
        pytest.raises(SlimsegError, match=r"--out .*taken is a file"),
        staged_dir(tmp_path / "taken"),
    ):
        pytest.fail("the body must not run")
    assert _tree(tmp_path) == {"taken": "x"}


def test_debug_shows_the_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    argv = ["dynamic", "--gt-instances", "--sequence", str(tmp_path / "none"), "--out", "x"]
    monkeypatch.delenv("SLIMSEG_DEBUG", raising=False)
    assert main(argv) == 2
    assert capsys.readouterr().err.count("\n") == 1
    with pytest.raises(SlimsegError, match="does not exist"):
        main(["--debug", *argv])
    monkeypatch.setenv("SLIMSEG_DEBUG", "1")
    with pytest.raises(SlimsegError, match="does not exist"):
        main(argv)
