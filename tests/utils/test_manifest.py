"""A command deletes only what it wrote, and proves it: manifest entries are confined to their
folder and carry the size and SHA-256 of what was written (``slimseg.utils.manifest``)."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pytest

from slimseg.cli.main import main
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import staged_dir
from slimseg.utils.manifest import MANIFEST, Record, confined_name, read_entries, record
from slimseg.utils.outputs import claim_folder

SYNTH = ["data", "synth", "--train", "1", "--val", "1", "--imgsz", "64"]


def _run(out: Path) -> None:
    with staged_dir(out, command="test") as stage:
        (stage / "masks").mkdir()
        (stage / "masks" / "1.png").write_bytes(b"mask 1")
        (stage / "frames.csv").write_text("a,b\n")


def _forge(out: Path, **entries: object) -> None:
    data = json.loads((out / MANIFEST).read_text())
    data["entries"].update(entries)
    (out / MANIFEST).write_text(json.dumps(data))


def test_records_name_kind_size_and_digest(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run(out)
    entries = read_entries(out)
    assert entries is not None and set(entries) == {"masks", "frames.csv"}
    assert entries["frames.csv"] == Record("file", 4, hashlib.sha256(b"a,b\n").hexdigest())
    masks = record(out / "masks")
    assert masks is not None and entries["masks"] == Record("dir", 6, masks.sha256)
    (out / "masks" / "1.png").write_bytes(b"mask 2")  # same size, other content
    assert record(out / "masks") != entries["masks"]


@pytest.mark.parametrize("name", ["../victim", "/etc/passwd", "a/b", "..", ".", "", "x\0y"])
def test_names_outside_the_folder_are_refused(tmp_path: Path, name: str) -> None:
    assert not confined_name(name)
    out = tmp_path / "out"
    _run(out)
    (tmp_path / "victim").write_text("mine")
    _forge(out, **{name: None})
    with pytest.raises(SlimsegError, match="not a name inside the folder"):
        claim_folder(out)
    with pytest.raises(SlimsegError, match="not a name inside the folder"), staged_dir(out):
        pass
    assert (tmp_path / "victim").read_text() == "mine"


def test_a_changed_entry_is_refused_before_and_during_the_run(tmp_path: Path) -> None:
    out = tmp_path / "out"
    _run(out)
    (out / "frames.csv").write_text("edited by the user\n")
    with pytest.raises(SlimsegError, match=r"frames\.csv \(changed since slimseg wrote it\)"):
        claim_folder(out, "--out")
    (out / "frames.csv").write_text("a,b\n")  # put back: slimseg's again
    claim_folder(out, "--out")
    with pytest.raises(SlimsegError, match=r"masks \(changed"), staged_dir(out) as stage:
        (stage / "frames.csv").write_text("run 2")
        (out / "masks" / "notes.txt").write_text("the user, meanwhile")
    assert (out / "masks" / "notes.txt").is_file() and (out / "frames.csv").read_text() == "a,b\n"


def test_an_entry_swapped_for_a_symlink_is_refused_and_never_followed(tmp_path: Path) -> None:
    out, user = tmp_path / "out", tmp_path / "user"
    _run(out)
    user.mkdir()
    (user / "thesis.tex").write_text("mine")
    os.rename(out / "masks", tmp_path / "old_masks")
    (out / "masks").symlink_to(user, target_is_directory=True)
    with pytest.raises(SlimsegError, match=r"masks \(changed"):
        claim_folder(out)
    link = record(out / "masks")
    assert link == Record(
        "link", len(os.fsencode(user)), hashlib.sha256(os.fsencode(user)).hexdigest()
    )
    assert (user / "thesis.tex").read_text() == "mine"


def test_older_manifests_without_records(tmp_path: Path) -> None:
    """Names without records (an older slimseg, a resumable sweep's announced entries) are
    taken over only by a command that writes those very names."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / MANIFEST).write_text(json.dumps({"entries": ["notes.txt"]}))
    with pytest.raises(SlimsegError, match=r"notes\.txt \(listed without a record"):
        claim_folder(out)
    claim_folder(out, own={"notes.txt"})  # e.g. ablate's results.csv on resume
    (out / "notes.txt").unlink()
    claim_folder(out)  # an announced entry that was never written is nothing to remove


@pytest.mark.parametrize(
    "text",
    ["", "[]", '{"entries": 3}', '{"entries": {"a": {"kind": "file"}}}', '{"entries": [1]}',
     '{"entries": {"a": {"kind": "file", "size": -1, "sha256": "x"}}}', "[" * 100000],
)  # fmt: skip
def test_unreadable_manifests_list_nothing(tmp_path: Path, text: str) -> None:
    (tmp_path / MANIFEST).write_text(text)
    (tmp_path / "a").write_text("x")
    assert read_entries(tmp_path) is None
    with pytest.raises(SlimsegError, match=r"did not write \(a\)"):
        claim_folder(tmp_path)


def test_synth_overwrite_deletes_only_what_it_wrote(tmp_path: Path, capfd) -> None:
    out, victim = tmp_path / "ds", tmp_path / "victim"
    assert main([*SYNTH, "--out", str(out)]) == 0
    victim.write_text("mine")
    capfd.readouterr()
    _forge(out, **{"../victim": None, str(victim): None})
    assert main([*SYNTH, "--out", str(out), "--overwrite"]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'../victim' (not a name inside the folder)" in err[0], err
    assert victim.read_text() == "mine"
    _forge(out, **{"../victim": "gone"})  # unreadable: nothing listed, so all foreign
    assert main([*SYNTH, "--out", str(out), "--overwrite"]) == 2
    (out / MANIFEST).unlink()
    assert main([*SYNTH, "--out", str(out), "--overwrite"]) == 2
    assert victim.read_text() == "mine" and (out / "data.yaml").is_file()


def test_data_show_never_writes_over_an_input_nor_reads_outside(tmp_path: Path, capfd) -> None:
    ds = tmp_path / "ds"
    assert main([*SYNTH, "--out", str(ds)]) == 0
    image = ds / "train" / "images" / "000000.png"
    before = image.read_bytes()
    show = ["data", "show", "--data", str(ds / "data.yaml"), "--count", "1", "--imgsz", "64"]
    capfd.readouterr()
    assert main([*show, "--out", str(image)]) == 2
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "would overwrite the input image" in err[0], err
    assert image.read_bytes() == before
    (tmp_path / "notes.txt").write_text("mine")
    assert main([*show, "--out", str(tmp_path / "notes.txt")]) == 2  # not a PNG it wrote
    assert (tmp_path / "notes.txt").read_text() == "mine"
    outside = tmp_path / "outside.png"
    outside.write_bytes(before)
    ann = ds / "train" / "annotations.json"
    data = json.loads(ann.read_text())
    data["images"][0]["file_name"] = "../../outside.png"
    ann.write_text(json.dumps(data))
    (ds / MANIFEST).unlink()  # the dataset is the user's now
    capfd.readouterr()
    assert main([*show, "--out", str(tmp_path / "grid.png")]) == 2  # its one image was outside
    err = capfd.readouterr().err
    assert "path_outside_root" in err and "outside the images folder" in err, err


def test_a_folder_nested_1200_deep_is_recorded_without_recursion(tmp_path: Path) -> None:
    """Python 3.11's os.walk recursed once per level: RecursionError past ~1,000 (issue #62).
    The tree is built and removed one level at a time (os.makedirs and shutil.rmtree, pytest's
    clean-up of tmp_path included, recurse too), removed whatever the test's outcome."""
    deep = tmp_path / "deep"
    levels = [str(deep)]
    for _ in range(1200):
        levels.append(os.path.join(levels[-1], "a"))
    try:
        for level in levels:
            os.mkdir(level)
        (deep / "a" / "f.txt").write_text("x")
        first = record(deep)
        assert first is not None and first.kind == "dir" and first.size == 1
        (deep / "a" / "f.txt").write_text("y")
        assert record(deep).sha256 != first.sha256
    finally:
        (deep / "a" / "f.txt").unlink(missing_ok=True)
        for level in reversed(levels):
            if os.path.isdir(level):
                os.rmdir(level)
