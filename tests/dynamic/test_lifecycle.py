"""Races, text and lifecycle (issue 47, classes 4 and 5): outputs never replace what appeared
meanwhile, a masker's lifecycle is explicit (closed: refused; fps checked; one step at a
time), bag topics are escaped on every path to the terminal, ``--out .`` is refused."""

from __future__ import annotations

import re
import threading
from pathlib import Path

import numpy as np
import pytest

from slimseg.cli.main import main
from slimseg.data.synth.sequence import write_sequence
from slimseg.data.tum import TumSequence
from slimseg.dynamic.annotations import AnnotationInstances
from slimseg.dynamic.chain_config import ChainConfig, TrackPlan
from slimseg.dynamic.frame_masker import FrameMasker, segmenter_for
from slimseg.dynamic.model_rate import EVERY_FRAME, ModelRate
from slimseg.dynamic.semantic import objects_of
from slimseg.dynamic.track_settings import COAST
from slimseg.errors import SlimsegError
from slimseg.utils.atomic import publish_new

USER = b"the user's own file"


@pytest.fixture(scope="module")
def seq(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("life") / "seq"
    write_sequence(folder, 0, 0, 3, (64, 48))
    return folder


def _masker(seq: Path, segmenter=None, track=None, rate=EVERY_FRAME, **kw) -> FrameMasker:
    """The chain on ``seq``'s instances (or ``segmenter``); ``kw``: :class:`ChainConfig`'s."""
    inst = AnnotationInstances(seq)
    config = ChainConfig(track=TrackPlan(track, rate), **kw)
    return FrameMasker(segmenter or segmenter_for(inst), inst.mobility, config)


def test_a_closed_masker_refuses_to_step(seq: Path) -> None:
    frames = TumSequence(seq)
    rgb, depth, t = frames.load(0)
    masker = _masker(seq, track=COAST, rate=ModelRate.parse("thread"))
    masker.step(rgb, depth, t)
    masker.close()
    masker.close()  # twice: harmless
    with pytest.raises(SlimsegError, match=r"step\(\) after close\(\)"):
        masker.step(rgb, depth, t)


@pytest.mark.parametrize("fps", [0, -30.0, float("nan"), float("inf"), True])
def test_frame_rates_out_of_range_are_refused_at_construction(seq: Path, fps: float) -> None:
    for track in (None, COAST):
        with pytest.raises(SlimsegError, match=r"fps .*frames per second, > 0"):
            _masker(seq, track=track, fps=fps)


def test_overlapping_steps_are_refused_and_indices_never_repeat(seq: Path) -> None:
    inst = AnnotationInstances(seq)
    inside, release = threading.Event(), threading.Event()

    def slow(rgb: np.ndarray, stamp: float, conf: float):
        inside.set()
        assert release.wait(10)
        return objects_of(inst.for_stamp(stamp), rgb.shape[:2])

    frames = TumSequence(seq)
    rgb, depth, t = frames.load(0)
    masker = _masker(seq, slow)
    results: list[int] = []
    worker = threading.Thread(target=lambda: results.append(masker.step(rgb, depth, t).index))
    worker.start()
    assert inside.wait(10)
    with pytest.raises(SlimsegError, match="another step"):
        masker.step(rgb, depth, t)
    release.set()
    worker.join(10)
    assert results == [0] and masker.step(rgb, depth, t).index == 1  # in turn: fine
    masker.close()


def test_an_output_that_appears_meanwhile_is_never_replaced(tmp_path: Path) -> None:
    for kind in ("file", "folder"):
        src, dst = tmp_path / f"stage_{kind}", tmp_path / f"out_{kind}"
        if kind == "file":
            src.write_bytes(b"ours")
        else:
            src.mkdir()
            (src / "a").write_bytes(b"ours")
        dst.write_bytes(USER)  # the user's, created while the command ran
        with pytest.raises(SlimsegError, match="appeared while the command ran"):
            publish_new(src, dst)
        assert dst.read_bytes() == USER
        dst.unlink()
        publish_new(src, dst)
        assert not src.exists() and dst.exists()


def test_tum2bag_keeps_a_bag_created_while_it_writes(
    seq: Path, tmp_path: Path, monkeypatch, capfd
) -> None:
    pytest.importorskip("rosbags")
    import slimseg.data.bags.writer as bw

    out = tmp_path / "x.bag"
    real = bw.publish_new

    def late(src: Path, dst: Path, option: str = "--out") -> None:
        dst.write_bytes(USER)  # the user's x.bag appears just before the rename
        real(src, dst, option)

    monkeypatch.setattr(bw, "publish_new", late)
    assert main(["data", "tum2bag", "--sequence", str(seq), "--out", str(out)]) == 2
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "x.bag appeared while the command ran" in err[0], err
    assert out.read_bytes() == USER and list(tmp_path.iterdir()) == [out]  # no staging left


@pytest.mark.parametrize("out", [".", "", "..", "/"])
def test_out_naming_the_current_or_a_parent_folder(seq: Path, out: str, capfd) -> None:
    assert main(["dynamic", "--sequence", str(seq), "--gt-instances", "--out", out]) == 2
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "give a named folder" in err[0], err


def test_bag_topics_are_escaped_on_the_way_to_the_terminal(
    seq: Path, tmp_path: Path, monkeypatch
) -> None:
    pytest.importorskip("rosbags")
    import slimseg.data.bags.from_tum as t2b
    from slimseg.data.bags.sequence import BagSequence

    monkeypatch.setattr(t2b, "RGB_TOPIC", "/cam\x1b[2J\x1b[31mFAKE/rgb")
    monkeypatch.setattr(t2b, "INFO_TOPIC", "/cam\u202e/info")
    bag = tmp_path / "esc.mcap"
    t2b.tum_to_bag(seq, bag)
    with BagSequence(bag) as s:
        lines = s.describe() + "\n" + s.describe_camera()
    assert "\x1b" not in lines and "\u202e" not in lines
    assert "/cam\\x1b[2J\\x1b[31mFAKE/rgb" in lines and "/cam\\u202e/info" in lines


@pytest.mark.skipif(
    "forkserver" not in __import__("multiprocessing").get_all_start_methods(),
    reason="the fork server exists only where multiprocessing offers forkserver",
)
def test_the_fork_server_survives_its_own_death() -> None:
    """A run whose fork server was killed (the OOM killer's pick) fails alone; the next run
    starts a fresh server (before: every later run raised, and the batch ended in exit 2)."""
    import os
    import signal
    import time
    from multiprocessing import forkserver

    from slimseg.slam.engine_process import ServerDied, _context, start_child

    ctx = _context()
    child = start_child(ctx, time.sleep, (0.01,), "first")
    child.join(30)
    assert child.exitcode == 0
    os.kill(forkserver._forkserver._forkserver_pid, signal.SIGKILL)
    outcomes = []
    for k in range(2):
        try:
            child = start_child(ctx, time.sleep, (0.01,), f"after{k}")
        except ServerDied as e:
            outcomes.append(str(e))
            continue
        child.join(30)
        outcomes.append(child.exitcode)
    assert outcomes[-1] == 0, outcomes  # the batch goes on with a fresh server
    assert all(o == 0 or "fork server died" in str(o) for o in outcomes), outcomes


@pytest.mark.parametrize(
    ("option", "value", "needle"),
    [("keypoints", 0, "keypoints 0"), ("keypoints", 10**9, "keypoints 1000000000"),
     ("keypoints", 2.5, "keypoints 2.5"), ("camera", (500.0, 500.0, 320.0), "camera"),
     ("camera", (1e-300, 500.0, 320.0, 240.0), "fx = 1e-300")],
)  # fmt: skip
def test_settings_out_of_range_are_refused_at_construction(
    seq: Path, option: str, value: object, needle: str
) -> None:
    with pytest.raises(SlimsegError, match=re.escape(needle)):
        _masker(seq, **{option: value})


@pytest.mark.parametrize("out", [".", ".."])
def test_export_out_naming_a_folder(out: str, capfd) -> None:
    argv = ["export", "--weights", "yolov8n-seg", "--imgsz", "64", "--out", out]
    assert main(argv) == 2
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "give a file name ending in .onnx" in err[0], err
