"""The frame-source protocol: a TUM folder and a ROS recording give the same interface from
one shared base, and every command that opens a recording closes it, whether it succeeds or is
refused (the readers are kept alive by the test, so garbage collection cannot close them)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from conftest import class_map_weights

from slimseg.cli.main import main
from slimseg.data.bags.from_tum import tum_to_bag
from slimseg.data.bags.reader import BagFile
from slimseg.data.bags.sequence import BagOptions, BagSequence
from slimseg.data.frame_source import FrameSource, PairedFrames
from slimseg.data.sequence_source import open_sequence, opens_sequence
from slimseg.data.synth import generate
from slimseg.data.tum import TumSequence
from slimseg.errors import SlimsegError

pytest.importorskip("rosbags")


@pytest.fixture(scope="module")
def made(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A 3-frame synthetic folder, it as a ROS 1 bag and a bare MCAP, and weights."""
    root = tmp_path_factory.mktemp("sources")
    generate(root / "d", 0, 0, 64, 0, sequences=1, frames=3, seq_size=(160, 128),
             progress=False)  # fmt: skip
    seq = root / "d" / "sequences" / "seq_000"
    paths = {"folder": seq, "bag": root / "s.bag", "mcap": root / "s.mcap"}
    tum_to_bag(seq, paths["bag"])
    tum_to_bag(seq, paths["mcap"], depth="16UC1")
    paths["weights"] = class_map_weights(seq, root / "w.pt")
    return paths


@pytest.fixture
def opened(monkeypatch) -> list[BagFile]:
    """Every recording a command opens, held by the test until it checks them."""
    held: list[BagFile] = []
    real = BagFile.__init__

    def record(self: BagFile, *args, **kwargs) -> None:
        real(self, *args, **kwargs)
        held.append(self)

    monkeypatch.setattr(BagFile, "__init__", record)
    return held


def _open_fds_into(paths: list[Path]) -> list[str]:
    """The process's file descriptors that point at one of ``paths`` (Linux)."""
    fd_dir = Path("/proc/self/fd")
    if not fd_dir.is_dir():
        return []
    wanted = {str(p.resolve()) for p in paths}
    out = []
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:  # closed while listing
            continue
        if target in wanted:
            out.append(target)
    return out


@pytest.mark.parametrize("kind", ["bag", "mcap"])
def test_a_folder_and_a_recording_give_one_interface(made: dict[str, Path], kind: str) -> None:
    members = [m for m in dir(FrameSource) if not m.startswith("_") or m in ("__len__",)]
    with open_sequence(made["folder"]) as tum, open_sequence(made[kind]) as bag:
        assert isinstance(tum, TumSequence) and isinstance(bag, BagSequence)
        for source in (tum, bag):
            assert isinstance(source, PairedFrames)
            assert all(hasattr(source, m) for m in [*members, "root", "frames", "camera"])
        assert len(tum) == len(bag) == 3 and tum.fps == pytest.approx(bag.fps)
        assert tum.load(-1)[2] == bag.load(-1)[2] == tum.frames[2][0][0]
        for source in (tum, bag):
            with pytest.raises(IndexError, match="frame 3 out of range"):
                source.load(3)
        assert tum.describe_camera().startswith("intrinsics: fx ")
        assert bag.describe_camera().startswith("intrinsics: fx ")
        assert not bag.closed
    assert bag.closed
    with pytest.raises(SlimsegError, match="was closed; open it again"):
        bag.load(0)


def test_a_refused_recording_is_closed(made: dict[str, Path], opened: list[BagFile]) -> None:
    with pytest.raises(SlimsegError, match="/nope"):
        BagSequence(made["mcap"], BagOptions(rgb_topic="/nope"))
    assert len(opened) == 1 and opened[0].closed
    assert _open_fds_into([made["mcap"]]) == []


def test_commands_close_every_recording_they_open(
    made: dict[str, Path], opened: list[BagFile], tmp_path: Path, capsys
) -> None:
    model = ["--model", str(made["weights"]), "--threads", "1", "--quiet"]
    for kind in ("bag", "mcap"):
        source = str(made[kind])
        assert main(["dynamic", *model, "--sequence", source, "--out",
                     str(tmp_path / f"dyn_{kind}"), "--set", "conf=0"]) == 0  # fmt: skip
        # refused after the recording was opened: a bag has no ground-truth instances
        assert main(["dynamic", "--gt-instances", "--sequence", source, "--out",
                     str(tmp_path / f"gt_{kind}")]) == 2  # fmt: skip
        assert main(["data", "bag2tum", "--bag", source, "--out", str(tmp_path / kind)]) == 0
        assert main(["predict", *model, "--source", source, "--out",
                     str(tmp_path / f"pred_{kind}")]) == 0  # fmt: skip
    assert "has none: give --model" in capsys.readouterr().err
    assert len(opened) >= 8
    assert [b.path.name for b in opened if not b.closed] == []
    assert _open_fds_into([made["bag"], made["mcap"]]) == []


def test_opens_sequence_closes_only_what_it_opened(made: dict[str, Path]) -> None:
    seen: list[FrameSource] = []

    @opens_sequence
    def frames(sequence: Path | FrameSource, first: int = 0) -> int:
        assert not isinstance(sequence, str | Path)
        seen.append(sequence)
        return len(sequence) - first

    assert frames(made["mcap"], first=1) == 2 and seen[-1].closed  # opened here, closed here
    with open_sequence(made["mcap"]) as mine:
        assert frames(sequence=mine) == 3 and not mine.closed  # the caller's: left open
    assert mine.closed
    with pytest.raises(TypeError, match="no 'sequence' parameter"):
        opens_sequence(lambda path: path)
